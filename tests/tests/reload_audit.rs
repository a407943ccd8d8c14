//! Reloads as clients found them: a link dropped under a device declared at run time, the
//! watch switched by the API, a save after another trigger's reload, a profiles directory
//! replaced by rename again and again, a device moved to another slave id.

use iogate_tests::TestGateway;
use iogate_tests::devices::{ModbusDevice, RtuBus, modbus_tcp_server, pty_at, temp_dir};
use reqwest::Method;
use serde_json::json;

const REG: &str = "name: Reg\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n";
const SIM: &str = "name: SimOne\nprotocol: simulated\nfields:\n  - { name: X, type: INT, direction: inout, register: { address: 0, kind: virtual } }\n";
const HEAD: &str = "listen: { http: 127.0.0.1:0, grpc: 127.0.0.1:0 }\nprofiles: profiles\n";

use iogate_tests::{config_files as files, start_file as start};

async fn reload(gw: &TestGateway) -> (u16, serde_json::Value) {
    gw.send(Method::POST, "/api/v1/config/reload", "")
        .await
        .expect("reload")
}

#[tokio::test]
async fn a_reload_that_drops_the_link_of_a_declared_device_is_refused() {
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").input[0] = 42;
    let (port, server) = modbus_tcp_server(device).await;
    let with_link =
        format!("{HEAD}links:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n");
    let (_, path) = files("reload-orphan", &[("reg.yaml", REG)], &with_link);
    let gw = start(&path).await;
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/meter",
            json!({"profile": "Reg", "link": "plant", "slave_id": 1, "refresh_rate_ms": 50})
                .to_string(),
        )
        .await
        .expect("declare");
    assert_eq!(status, 201, "{body}");
    gw.until("/api/v1/devices/meter/fields/N", "read", |f| {
        f["value"] == 42
    })
    .await
    .expect("polled");
    std::fs::write(&path, HEAD).expect("config without the link");
    let (status, body) = reload(&gw).await;
    assert!((400..500).contains(&status), "{status} {body}");
    assert!(
        body.to_string()
            .contains("device(s) meter declared at run time are on it"),
        "{body}"
    );
    // Nothing changed: the device is polled on.
    let (_, link) = gw.get("/api/v1/links/plant").await.expect("link");
    assert_eq!(link["name"], "plant", "{link}");
    gw.until("/api/v1/devices/meter/fields/N", "read again", |f| {
        f["quality"] == "good"
    })
    .await
    .expect("polled on");
    gw.shutdown().await;
    server.abort();
}

fn sim_config(rate: &str, watch: bool) -> String {
    format!(
        "{HEAD}devices:\n  - {{ name: sim, profile: SimOne, refresh_rate: {rate} }}\nreload: {{ watch: {watch}, debounce: 100ms }}\n"
    )
}

async fn rate_is(gw: &TestGateway, ms: u64) {
    gw.until("/api/v1/devices/sim", "the refresh rate", |d| {
        d["refresh_rate_ms"] == ms
    })
    .await
    .unwrap_or_else(|e| panic!("refresh rate {ms}: {e}"));
}

#[tokio::test]
async fn a_watch_switched_on_by_the_api_watches_at_once_and_no_save_is_skipped() {
    let (_, path) = files(
        "reload-watch-api",
        &[("sim.yaml", SIM)],
        &sim_config("100ms", false),
    );
    let gw = start(&path).await;
    // Switched on by a reload from the API: in force at once, no SIGHUP.
    std::fs::write(&path, sim_config("90ms", true)).expect("config");
    let (status, body) = reload(&gw).await;
    assert_eq!(status, 200, "{body}");
    std::fs::write(&path, sim_config("80ms", true)).expect("config");
    rate_is(&gw, 80).await;
    // Another trigger reloads a different save in between...
    std::fs::write(&path, sim_config("70ms", true)).expect("config");
    let (status, body) = reload(&gw).await;
    assert_eq!(status, 200, "{body}");
    rate_is(&gw, 70).await;
    // ...and the save the watch applied before comes back: it is applied again.
    std::fs::write(&path, sim_config("80ms", true)).expect("config");
    rate_is(&gw, 80).await;
    gw.shutdown().await;
}

#[tokio::test]
async fn a_profiles_directory_replaced_by_rename_is_followed_every_time() {
    let (dir, path) = files(
        "reload-dir-swap",
        &[("sim.yaml", SIM)],
        &sim_config("100ms", true),
    );
    let gw = start(&path).await;
    for (round, name) in ["SimTwo", "SimThree", "SimFour"].iter().enumerate() {
        // As rsync --delay-updates or ansible do it: a full new directory, the old one
        // moved away, the new one renamed into its place.
        let fresh = dir.join(format!("profiles.new{round}"));
        std::fs::create_dir_all(&fresh).expect("new dir");
        std::fs::write(fresh.join("sim.yaml"), SIM).expect("profile");
        std::fs::write(fresh.join("more.yaml"), SIM.replace("SimOne", name)).expect("profile");
        std::fs::rename(
            dir.join("profiles"),
            dir.join(format!("profiles.old{round}")),
        )
        .expect("move away");
        std::fs::rename(&fresh, dir.join("profiles")).expect("rename into place");
        gw.until(
            &format!("/api/v1/profiles/{name}"),
            "the new profile",
            |_| true,
        )
        .await
        .unwrap_or_else(|e| panic!("round {round}: {e}"));
        // The one it replaced (a name gone, another come: the same count) is gone.
        if round > 0 {
            gw.until("/api/v1/profiles", "the old profile gone", |list| {
                !list
                    .to_string()
                    .contains(&format!("\"{}\"", ["SimTwo", "SimThree"][round - 1]))
            })
            .await
            .unwrap_or_else(|e| panic!("round {round}: {e}"));
        }
    }
    gw.shutdown().await;
}

#[tokio::test]
async fn a_device_moved_to_another_slave_id_is_not_good_until_read_there() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.input[0] = 11);
    let dir = temp_dir("reload-moved");
    let port = dir.join("ttyBUS");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let serving = bus.serve(device_end);
    let config = |slave: u8| {
        format!(
            "{HEAD}links:\n  - {{ name: bus, serial: {{ port: {}, baud: 115200 }} }}\ndevices:\n  - {{ name: dev, profile: Reg, link: bus, slave_id: {slave}, refresh_rate: 20ms, timeout: 2s }}\n",
            port.display()
        )
    };
    let (_, path) = files("reload-moved-files", &[("reg.yaml", REG)], &config(1));
    let gw = start(&path).await;
    gw.until("/api/v1/devices/dev/fields/N", "read at slave 1", |f| {
        f["value"] == 11 && f["quality"] == "good"
    })
    .await
    .expect("read");
    // Moved to slave 2, which does not answer (its first request waits 2 s for nothing).
    std::fs::write(&path, config(2)).expect("config");
    let (status, body) = reload(&gw).await;
    assert_eq!(status, 200, "{body}");
    let (_, field) = gw.get("/api/v1/devices/dev/fields/N").await.expect("field");
    assert_ne!(
        field["quality"], "good",
        "slave 1's value is not slave 2's: {field}"
    );
    assert!(field["value"].is_null(), "{field}");
    gw.shutdown().await;
    serving.abort();
}

#[tokio::test]
async fn a_read_of_the_old_place_on_the_way_when_a_device_is_moved_is_not_stored() {
    use iogate_tests::SseReader;
    use iogate_tests::devices::Behaviour;
    let bus = RtuBus::default();
    // Slave 1 takes 300 ms for each answer: a read of it is on the way when the reload lands.
    bus.slave(1, |s| {
        s.tables.input[0] = 11;
        s.behaviour = Behaviour::Slow(std::time::Duration::from_millis(300));
    });
    bus.slave(2, |s| s.tables.input[0] = 22);
    let dir = temp_dir("reload-moved-in-flight");
    let port = dir.join("ttyBUS");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let serving = bus.serve(device_end);
    let config = |slave: u8| {
        format!(
            "{HEAD}links:\n  - {{ name: bus, serial: {{ port: {}, baud: 115200 }} }}\ndevices:\n  - {{ name: dev, profile: Reg, link: bus, slave_id: {slave}, refresh_rate: 20ms, timeout: 2s }}\n",
            port.display()
        )
    };
    let (_, path) = files(
        "reload-moved-in-flight-files",
        &[("reg.yaml", REG)],
        &config(1),
    );
    let gw = start(&path).await;
    let mut sse = SseReader::open(&gw, "/api/v1/events?device=dev")
        .await
        .expect("sse");
    sse.until(|name, v| name == "value" && v["value"] == 11 && v["quality"] == "good")
        .await
        .expect("read at slave 1");
    std::fs::write(&path, config(2)).expect("config");
    let (status, body) = reload(&gw).await;
    assert_eq!(status, 200, "{body}");
    // Every event from the reset on: never slave 1's value as good.
    let mut reset = false;
    loop {
        let (name, v) = sse.next().await.expect("event").expect("stream");
        if name != "value" {
            continue;
        }
        if v["value"].is_null() {
            reset = true;
        } else if v["value"] == 22 && v["quality"] == "good" {
            break;
        } else if reset {
            assert!(
                !(v["value"] == 11 && v["quality"] == "good"),
                "slave 1's value served as slave 2's: {v}"
            );
        }
    }
    assert!(reset, "the moved device starts unread");
    gw.shutdown().await;
    serving.abort();
}

/// Where each `device.field` is bound, from `GET /api/v1/map`.
async fn bound(gw: &TestGateway) -> std::collections::HashMap<String, String> {
    let (_, map) = gw.get("/api/v1/map").await.expect("map");
    map["bindings"]
        .as_array()
        .into_iter()
        .flatten()
        .map(|b| {
            (
                format!(
                    "{}.{}",
                    b["device"].as_str().unwrap_or(""),
                    b["field"].as_str().unwrap_or("")
                ),
                b["at"].as_str().unwrap_or("").to_owned(),
            )
        })
        .collect()
}

#[tokio::test]
async fn a_reload_keeps_every_auto_located_field_where_masters_read_it() {
    let config = |devices: &[&str]| {
        let mut c = format!("{HEAD}devices:\n");
        for d in devices {
            c.push_str(&format!(
                "  - {{ name: {d}, profile: SimOne, refresh_rate: 100ms }}\n"
            ));
        }
        c.push_str("modbus_server:\n  listen: 127.0.0.1:0\n  auto: true\n");
        c
    };
    let (_, path) = files(
        "reload-auto-map",
        &[("sim.yaml", SIM)],
        &config(&["b", "c"]),
    );
    let gw = start(&path).await;
    let before = bound(&gw).await;
    let (b, c) = (before["b.X"].clone(), before["c.X"].clone());
    // Two devices listed before the others, and one removed.
    std::fs::write(&path, config(&["a1", "a2", "b"])).expect("config");
    let (status, body) = reload(&gw).await;
    assert_eq!(status, 200, "{body}");
    let after = bound(&gw).await;
    assert_eq!(after["b.X"], b, "b.X moved: {after:?}");
    assert!(!after.contains_key("c.X"));
    // c's location stays empty; the new fields take free ones.
    for new in ["a1.X", "a2.X"] {
        assert_ne!(after[new], c, "{new} took c's place");
        assert_ne!(after[new], b);
    }
    let changes = body["report"]["changes"].to_string();
    assert!(
        changes.contains(&c) && changes.contains("kept empty"),
        "{changes}"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn a_device_moved_to_another_link_gets_no_write_it_was_not_asked() {
    const OUT: &str = "name: Out\nfields:\n  - { name: HR0, type: UINT, direction: inout, register: { address: 0, kind: holding_register } }\n";
    let (first, second) = (ModbusDevice::default(), ModbusDevice::default());
    second.tables.lock().expect("tables").holding[0] = 7777;
    let (p1, s1) = modbus_tcp_server(first.clone()).await;
    let (p2, s2) = modbus_tcp_server(second.clone()).await;
    let config = |link: &str| {
        format!(
            "{HEAD}links:\n  - {{ name: one, tcp: {{ host: 127.0.0.1, port: {p1} }} }}\n  - {{ name: two, tcp: {{ host: 127.0.0.1, port: {p2} }} }}\ndevices:\n  - {{ name: d, profile: Out, link: {link}, slave_id: 1, refresh_rate: 50ms }}\n"
        )
    };
    let (_, path) = files("reload-moved-writes", &[("out.yaml", OUT)], &config("one"));
    let gw = start(&path).await;
    let outcome = gw
        .write_outcome("d", "HR0", json!(400))
        .await
        .expect("write")
        .expect("accepted");
    assert_eq!(outcome["status"], "written", "{outcome}");
    std::fs::write(&path, config("two")).expect("config");
    let (status, body) = reload(&gw).await;
    assert_eq!(status, 200, "{body}");
    let field = gw
        .until(
            "/api/v1/devices/d/fields/HR0",
            "read at its new place",
            |f| f["value"] == 7777 && f["quality"] == "good",
        )
        .await
        .expect("read");
    assert_eq!(
        field["last_write"]["generation"], outcome["generation"],
        "{field}"
    );
    assert!(
        second.writes.lock().expect("writes").is_empty(),
        "written at the new place"
    );
    assert_eq!(second.tables.lock().expect("tables").holding[0], 7777);
    gw.shutdown().await;
    s1.abort();
    s2.abort();
}
