//! Configuration reload against a running gateway: a device added on a line that keeps
//! polling, a bad profile that changes nothing, and file replacements seen once.

use std::path::Path;
use std::time::Duration;

use futures_util::StreamExt;
use iogate_tests::devices::{RtuBus, pty_at, temp_dir};
use iogate_tests::mqtt::{Broker, Message, Peer};
use iogate_tests::{SseReader, eventually};
use reqwest::Method;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

const REG: &str = "name: Reg\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n";
const SIM: &str = "name: SimOne\nprotocol: simulated\nfields:\n  - { name: X, type: INT, direction: inout, register: { address: 0, kind: virtual } }\n";

use iogate_tests::{config_files as files, start_file as start};

fn line_config(port: &Path, devices: &str) -> String {
    format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: profiles\nlinks:\n  - {{ name: bus, serial: {{ port: {}, baud: 115200 }} }}\ndevices:\n{devices}",
        port.display()
    )
}

fn has_change(report: &serde_json::Value, kind: &str, name: &str, action: &str) -> bool {
    report["changes"].as_array().is_some_and(|changes| {
        changes
            .iter()
            .any(|c| c["kind"] == kind && c["name"] == name && c["action"] == action)
    })
}

#[tokio::test]
async fn a_device_added_on_a_running_line_leaves_the_port_open_and_the_streams_whole() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.input[0] = 1);
    bus.slave(2, |s| s.tables.input[0] = 20);
    let dir = temp_dir("reload-line");
    let port = dir.join("ttyBUS");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let serving = bus.serve(device_end);
    let first = "  - { name: first, profile: Reg, link: bus, slave_id: 1, refresh_rate: 10ms }\n";
    let (_, path) = files(
        "reload-line-files",
        &[("reg.yaml", REG), ("sim.yaml", SIM)],
        &line_config(
            &port,
            &format!("{first}  - {{ name: other, profile: SimOne, refresh_rate: 100ms }}\n"),
        ),
    );
    let gw = start(&path).await;
    gw.until("/api/v1/devices/first/fields/N", "first read", |v| {
        v["value"] == 1 && v["quality"] == "good"
    })
    .await
    .expect("polled");
    let mut sse = SseReader::open(&gw, "/api/v1/events?device=first")
        .await
        .expect("sse");
    sse.until(|name, v| name == "value" && v["value"] == 1)
        .await
        .expect("current value");
    let mut client = gw.client().await.expect("grpc");
    let selection = iogate_client::Selection {
        devices: vec!["first".into()],
        fields: Vec::new(),
    };
    let mut updates = Box::pin(
        client
            .subscribe(&selection, false)
            .await
            .expect("subscribe"),
    );
    match updates.next().await {
        Some(Ok(iogate_client::Update::Value(v))) => assert_eq!(v.field, "N"),
        other => panic!("first update: {other:?}"),
    }

    // Add a device on the same line and change one elsewhere.
    bus.clear_seen();
    std::fs::write(
        &path,
        line_config(
            &port,
            &format!(
                "{first}  - {{ name: other, profile: SimOne, refresh_rate: 50ms }}\n  - {{ name: second, profile: Reg, link: bus, slave_id: 2, refresh_rate: 10ms }}\n"
            ),
        ),
    )
    .expect("config");
    let (status, answer) = gw
        .send(Method::POST, "/api/v1/config/reload", "")
        .await
        .expect("reload");
    assert_eq!(status, 200, "{answer}");
    assert_eq!(answer["applied"], true);
    let report = &answer["report"];
    assert!(has_change(report, "device", "second", "added"), "{report}");
    assert!(has_change(report, "device", "other", "changed"), "{report}");
    assert!(
        !has_change(report, "device", "first", "changed"),
        "{report}"
    );
    assert_eq!(report["reopened"], serde_json::json!([]), "{report}");
    gw.until("/api/v1/devices/second/fields/N", "second polled", |v| {
        v["value"] == 20
    })
    .await
    .expect("second polled");

    // The next change of the first device is the next event on both streams: nothing
    // repeated, nothing lost.
    bus.slave(1, |s| s.tables.input[0] = 2);
    let (name, data) = loop {
        let (name, data) = sse.next().await.expect("event").expect("open");
        if name != "diagnostics" {
            break (name, data);
        }
    };
    assert_eq!(
        (name.as_str(), &data["value"]),
        ("value", &serde_json::json!(2)),
        "{data}"
    );
    match updates.next().await {
        Some(Ok(iogate_client::Update::Value(v))) => {
            assert_eq!(v.field, "N");
            assert_eq!(v.value, Some(iogate_client::Value::UInt(2)));
        }
        other => panic!("next update: {other:?}"),
    }

    // The port was never closed, and the first device's polls went on without a gap.
    assert!(
        !serving.is_finished(),
        "the device's end of the line closed"
    );
    eventually("30 polls of the first device since the reload", || {
        let bus = &bus;
        async move { bus.seen().iter().filter(|s| s.slave == 1).count() >= 30 }
    })
    .await
    .expect("polling");
    let polls: Vec<_> = bus.seen().into_iter().filter(|s| s.slave == 1).collect();
    let gap = polls
        .windows(2)
        .map(|w| w[1].at.duration_since(w[0].at))
        .max()
        .unwrap_or_default();
    println!(
        "first device: {} polls, longest gap {gap:?} across the reload (period 10 ms)",
        polls.len()
    );
    assert!(
        gap < Duration::from_millis(250),
        "the first device's polls stopped for {gap:?}"
    );
    let (_, config) = gw.get("/api/v1/config").await.expect("config");
    assert!(has_change(
        &config["last_report"],
        "device",
        "second",
        "added"
    ));
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_config_reloads_total{result=\"applied\"} 1"),
        "{metrics}"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn a_bad_profile_changes_nothing_and_the_next_good_save_applies() {
    let config = "listen: { http: 127.0.0.1:0, grpc: 127.0.0.1:0 }\nprofiles: profiles\ndevices:\n  - { name: sim, profile: SimOne, refresh_rate: 50ms }\nreload: { watch: true, debounce: 100ms }\n";
    let (dir, path) = files("reload-bad-profile", &[("sim.yaml", SIM)], config);
    let gw = start(&path).await;
    let profile = dir.join("profiles").join("sim.yaml");
    // A type that does not exist, on line 3.
    std::fs::write(&profile, SIM.replace("type: INT", "type: INTEGER")).expect("save");
    eventually("the problem reported", || {
        let gw = &gw;
        async move {
            gw.get("/api/v1/config").await.is_ok_and(|(_, c)| {
                c["last_problems"].as_array().is_some_and(|p| {
                    p.iter()
                        .any(|p| p.as_str().is_some_and(|p| p.contains("sim.yaml:4")))
                })
            })
        }
    })
    .await
    .expect("reported with its line");
    let (_, c) = gw.get("/api/v1/config").await.expect("config");
    println!("{}", c["last_problems"]);
    let (_, device) = gw.get("/api/v1/devices/sim").await.expect("device");
    assert!(device.to_string().contains("\"X\""), "unchanged: {device}");
    // The REST call says the same, with file and line.
    let (status, answer) = gw
        .send(Method::POST, "/api/v1/config/reload", "")
        .await
        .expect("reload");
    assert_eq!(status, 400, "{answer}");
    assert_eq!(answer["error"]["code"], "invalid_config");
    let problem = &answer["error"]["problems"][0];
    assert!(
        problem["file"]
            .as_str()
            .is_some_and(|f| f.ends_with("sim.yaml")),
        "{answer}"
    );
    assert_eq!(problem["line"], 4, "{answer}");
    // The next good save applies: the field renamed.
    std::fs::write(&profile, SIM.replace("name: X", "name: Y")).expect("save");
    gw.until("/api/v1/devices/sim/fields/Y", "the new field", |v| {
        v["quality"] == "good"
    })
    .await
    .expect("applied");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_config_reloads_total{result=\"applied\"} 1"),
        "{metrics}"
    );
    gw.shutdown().await;
}

#[cfg(unix)]
#[tokio::test]
async fn a_configmap_symlink_swap_and_an_editor_rename_are_each_seen_once() {
    use std::os::unix::fs::symlink;
    let dir = temp_dir("reload-configmap");
    let config = |rate: &str| {
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: profiles\ndevices:\n  - {{ name: sim, profile: SimOne, refresh_rate: {rate} }}\nreload: {{ watch: true, debounce: 200ms }}\n"
        )
    };
    // The Kubernetes layout: iogate.yaml -> ..data/iogate.yaml, ..data -> ..v1.
    std::fs::create_dir_all(dir.join("..v1")).expect("v1");
    std::fs::create_dir_all(dir.join("profiles")).expect("profiles");
    std::fs::write(dir.join("profiles/sim.yaml"), SIM).expect("profile");
    std::fs::write(dir.join("..v1/iogate.yaml"), config("100ms")).expect("config");
    symlink("..v1", dir.join("..data")).expect("..data");
    symlink("..data/iogate.yaml", dir.join("iogate.yaml")).expect("link");
    let gw = start(&dir.join("iogate.yaml")).await;

    // The swap: a new directory, a new symlink beside, renamed over `..data`.
    std::fs::create_dir_all(dir.join("..v2")).expect("v2");
    std::fs::write(dir.join("..v2/iogate.yaml"), config("50ms")).expect("config");
    symlink("..v2", dir.join("..data_tmp")).expect("tmp");
    std::fs::rename(dir.join("..data_tmp"), dir.join("..data")).expect("swap");
    let applied = |n: u32| {
        let gw = &gw;
        async move {
            gw.metrics().await.is_ok_and(|m| {
                m.contains(&format!(
                    "iogate_config_reloads_total{{result=\"applied\"}} {n}\n"
                ))
            })
        }
    };
    eventually("the swap applied", || applied(1))
        .await
        .expect("swap seen");

    // An editor on the plain file the config names now: the new text written beside,
    // then renamed over it (`..data/iogate.yaml` resolves to `..v2/iogate.yaml`).
    std::fs::write(dir.join("..v2/.iogate.yaml.swp"), config("20ms")).expect("write");
    std::fs::rename(
        dir.join("..v2/.iogate.yaml.swp"),
        dir.join("..v2/iogate.yaml"),
    )
    .expect("rename");
    // `..v2` itself is not watched (Kubernetes never edits it); touch the link as a
    // ConfigMap update would, by swapping `..data` to the same directory again.
    symlink("..v2", dir.join("..data_tmp")).expect("tmp");
    std::fs::rename(dir.join("..data_tmp"), dir.join("..data")).expect("swap");
    eventually("the edit applied", || applied(2))
        .await
        .expect("edit seen");
    let (_, device) = gw.get("/api/v1/devices/sim").await.expect("device");
    assert_eq!(device["refresh_rate_ms"], 20, "{device}");
    let metrics = gw.metrics().await.expect("metrics");
    for result in ["unchanged", "invalid", "failed"] {
        assert!(
            metrics.contains(&format!(
                "iogate_config_reloads_total{{result=\"{result}\"}} 0\n"
            )),
            "each change seen once: {metrics}"
        );
    }
    gw.shutdown().await;
}

#[tokio::test]
async fn an_editor_write_then_rename_is_seen_once() {
    let config = |rate: &str| {
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: profiles\ndevices:\n  - {{ name: sim, profile: SimOne, refresh_rate: {rate} }}\nreload: {{ watch: true, debounce: 200ms }}\n"
        )
    };
    let (dir, path) = files("reload-editor", &[("sim.yaml", SIM)], &config("100ms"));
    let gw = start(&path).await;
    std::fs::write(dir.join(".iogate.yaml.swp"), config("30ms")).expect("write");
    std::fs::rename(dir.join(".iogate.yaml.swp"), &path).expect("rename");
    gw.until("/api/v1/devices/sim", "the new refresh rate", |d| {
        d["refresh_rate_ms"] == 30
    })
    .await
    .expect("applied");
    // `mv` of a new profile into the profiles directory: a second reload.
    std::fs::write(dir.join("new.yaml"), SIM.replace("SimOne", "SimTwo")).expect("write");
    std::fs::rename(dir.join("new.yaml"), dir.join("profiles/two.yaml")).expect("mv");
    gw.until("/api/v1/profiles/SimTwo", "the new profile", |_| true)
        .await
        .expect("profile loaded");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_config_reloads_total{result=\"applied\"} 2\n"),
        "{metrics}"
    );
    assert!(
        metrics.contains("iogate_config_reloads_total{result=\"unchanged\"} 0\n"),
        "{metrics}"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn a_changed_mqtt_section_restarts_the_edge_node_with_the_next_bd_seq() {
    let broker = Broker::start().await.expect("mosquitto");
    let mut peer = Peer::subscribe(&broker, "spBv1.0/#").await.expect("paho");
    let config = |node: &str| {
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: profiles\ndevices:\n  - {{ name: sim, profile: SimOne, refresh_rate: 50ms }}\nmqtt:\n  url: mqtt://127.0.0.1:{}\n  client_id: iogate-reload-{}\n  sparkplug: {{ group_id: plant1, edge_node_id: {node} }}\n",
            broker.port, broker.port
        )
    };
    let (_, path) = files("reload-mqtt", &[("sim.yaml", SIM)], &config("line1"));
    let gw = start(&path).await;
    let birth = peer
        .until(|m| m.topic == "spBv1.0/plant1/NBIRTH/line1")
        .await
        .expect("NBIRTH");
    let bd_seq = bd_seq_of(&birth);
    std::fs::write(&path, config("line2")).expect("write");
    let (status, body) = gw
        .send(Method::POST, "/api/v1/config/reload", "")
        .await
        .expect("reload");
    assert_eq!(status, 200, "{body}");
    assert!(
        has_change(&body["report"], "mqtt", "mqtt", "changed"),
        "{body}"
    );
    // The old edge node dies with its session's bdSeq; the new one is born with the next.
    let death = peer
        .until(|m| m.topic == "spBv1.0/plant1/NDEATH/line1")
        .await
        .expect("NDEATH");
    assert_eq!(bd_seq_of(&death), bd_seq, "NDEATH of the old session");
    let birth = peer
        .until(|m| m.topic == "spBv1.0/plant1/NBIRTH/line2")
        .await
        .expect("NBIRTH of the new node");
    assert_eq!(bd_seq_of(&birth), (bd_seq + 1) % 256, "the next session");
    peer.until(|m| m.topic == "spBv1.0/plant1/DBIRTH/line2/sim")
        .await
        .expect("DBIRTH");
    let (_, mqtt) = gw.get("/api/v1/mqtt").await.expect("mqtt status");
    assert_eq!(mqtt["sparkplug"]["edge_node_id"], "line2", "{mqtt}");
    // The section removed: the node dies and the front-end is gone.
    std::fs::write(
        &path,
        config("line2").split("mqtt:").next().expect("config"),
    )
    .expect("write");
    let (status, body) = gw
        .send(Method::POST, "/api/v1/config/reload", "")
        .await
        .expect("reload");
    assert_eq!(status, 200, "{body}");
    peer.until(|m| m.topic == "spBv1.0/plant1/NDEATH/line2")
        .await
        .expect("NDEATH of the removed node");
    let (status, _) = gw.get("/api/v1/mqtt").await.expect("mqtt status");
    assert_eq!(status, 404);
    gw.shutdown().await;
    peer.stop().await;
    broker.stop().await;
}

fn bd_seq_of(m: &Message) -> u64 {
    m.sparkplug["metrics"]
        .as_array()
        .and_then(|metrics| metrics.iter().find(|x| x["name"] == "bdSeq"))
        .and_then(|x| x["value"].as_u64())
        .expect("bdSeq")
}

#[tokio::test]
async fn a_reload_moves_the_modbus_servers_serial_ports() {
    let dir = temp_dir("reload-serial");
    let (_a_end, _a_holder) = pty_at(&dir.join("ttyA")).expect("pty");
    let (mut b_end, _b_holder) = pty_at(&dir.join("ttyB")).expect("pty");
    let config = |serial: &str| {
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: profiles\ndevices:\n  - {{ name: one, profile: SimOne }}\nmodbus_server:\n  serial:\n{serial}"
        )
    };
    let a = format!(
        "    - {{ port: {}, baud: 19200, unit_id: 7 }}\n",
        dir.join("ttyA").display()
    );
    let (_, path) = files("reload-serial-files", &[("sim.yaml", SIM)], &config(&a));
    let gw = start(&path).await;
    gw.until("/api/v1/map", "port A open", |m| {
        m["serial"][0]["state"] == "open" && m["serial"][0]["unit_id"] == 7
    })
    .await
    .expect("A");
    // Port A goes, port B comes with unit id 9.
    let b = format!(
        "    - {{ port: {}, baud: 19200, unit_id: 9 }}\n",
        dir.join("ttyB").display()
    );
    std::fs::write(&path, config(&b)).expect("config");
    let (status, report) = gw
        .send(Method::POST, "/api/v1/config/reload", "")
        .await
        .expect("reload");
    assert_eq!(status, 200, "{report}");
    assert!(
        has_change(
            &report["report"],
            "listener",
            "modbus_server.serial",
            "changed"
        ),
        "{report}"
    );
    let map = gw
        .until("/api/v1/map", "port B open alone", |m| {
            m["serial"].as_array().is_some_and(|s| s.len() == 1)
                && m["serial"][0]["state"] == "open"
                && m["serial"][0]["unit_id"] == 9
        })
        .await
        .expect("B");
    assert!(
        map["serial"][0]["port"]
            .as_str()
            .is_some_and(|p| p.ends_with("ttyB")),
        "{map}"
    );
    // B answers unit 9.
    let mut request = vec![9u8, 0x03, 0x04, 0x00, 0x00, 0x01];
    let crc = iogate_tests::devices::crc16(&request);
    request.extend_from_slice(&crc.to_le_bytes());
    b_end.write_all(&request).await.expect("write");
    let mut answer = [0u8; 7];
    tokio::time::timeout(iogate_tests::PATIENCE, b_end.read_exact(&mut answer))
        .await
        .expect("answered")
        .expect("read");
    assert_eq!(&answer[..3], &[9, 0x03, 2]);
    gw.shutdown().await;
}
