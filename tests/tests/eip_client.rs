//! The EtherNet/IP driver against cpppo's Logix simulator (`tests/eip/plc.py`), with pylogix
//! as the independent reader: every atomic type read and written, an array element, a bit
//! of an integer read, each tag's CIP status its own field's error, a type that differs from
//! the profile's named, the controller's identity in the link's state, connected messaging
//! after Large Forward Open, packets within the connection, the controller stopped and
//! started again, and the device through gRPC, the change stream and the Modbus server.

use iogate_tests::TestGateway;
use iogate_tests::devices::temp_dir;
use iogate_tests::eip::LogixPlc;
use serde_json::{Value, json};

const TAGS: &[&str] = &[
    "Speed=REAL",
    "Counts=DINT[10]",
    "Flag=BOOL",
    "Small=SINT",
    "Word=INT",
    "Big=LINT",
    "Us=USINT",
    "Ui=UINT",
    "Ud=UDINT",
    "Ul=ULINT",
    "Lr=LREAL",
    "Flags=DINT",
    "Name=STRING",
    "Short=SSTRING",
];

const PROFILE: &str = r#"name: Line
protocol: ab-eip
fields:
  - { name: Speed, type: REAL, direction: inout, tag: Speed }
  - { name: C3, type: DINT, direction: inout, tag: "Counts[3]" }
  - { name: Flag, type: BOOL, direction: inout, tag: Flag }
  - { name: Small, type: SINT, direction: inout, tag: Small }
  - { name: Wd, type: INT, direction: inout, tag: Word }
  - { name: Big, type: LINT, direction: inout, tag: Big }
  - { name: Us, type: USINT, direction: inout, tag: Us }
  - { name: Ui, type: UINT, direction: inout, tag: Ui }
  - { name: Ud, type: UDINT, direction: inout, tag: Ud }
  - { name: Ul, type: ULINT, direction: inout, tag: Ul }
  - { name: Lr, type: LREAL, direction: inout, tag: Lr }
  - { name: F5, type: BOOL, direction: inout, tag: Flags.5 }
  - { name: Nope, type: INT, direction: input, tag: Nope }
  - { name: Wrong, type: REAL, direction: input, tag: "Counts[4]" }
  - { name: Label, type: STRING, direction: inout, tag: Name }
  - { name: Sh, type: STRING, direction: inout, tag: Short }
"#;

async fn gateway(name: &str, port: u16) -> anyhow::Result<TestGateway> {
    gateway_with(name, port, "").await
}

/// The same, with more configuration (other front-ends).
async fn gateway_with(name: &str, port: u16, more: &str) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/line.yaml"), PROFILE)?;
    TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {port}, path: \"1,0\", timeout: 1s }} }}\ndevices:\n  - {{ name: line, profile: Line, link: plc, refresh_rate: 100ms }}\n{more}",
        dir.join("profiles").display()
    ))
    .await
}

fn field<'a>(device: &'a Value, name: &str) -> &'a Value {
    &device["fields"][name]
}

/// The device once every field has been read (good or with its error).
async fn read_once(gw: &TestGateway) -> anyhow::Result<Value> {
    gw.until("/api/v1/devices/line", "every tag read", |d| {
        field(d, "Speed")["quality"] == "good" && field(d, "Nope")["error"].is_string()
    })
    .await
}

/// Writes through REST and waits for the outcome.
async fn put(gw: &TestGateway, name: &str, value: Value) -> anyhow::Result<Value> {
    gw.write_outcome("line", name, value)
        .await?
        .map_err(|refused| anyhow::anyhow!("{name}: {refused}"))
}

#[tokio::test]
async fn every_atomic_type_is_read_and_written_and_each_tags_status_is_its_own() {
    let plc = LogixPlc::start(None, TAGS).await.expect("controller");
    let gw = gateway("eip-types", plc.port).await.expect("gateway");
    let device = read_once(&gw).await.expect("read");
    for name in [
        "Speed", "C3", "Flag", "Small", "Wd", "Big", "Us", "Ui", "Ud", "Ul", "Lr", "F5", "Label",
        "Sh",
    ] {
        assert_eq!(field(&device, name)["quality"], "good", "{name}: {device}");
    }
    // A tag the controller does not have, and one of another type: their own errors only.
    let nope = field(&device, "Nope")["error"].as_str().unwrap_or_default();
    assert!(nope.contains("0x05"), "{nope}");
    let wrong = field(&device, "Wrong")["error"]
        .as_str()
        .unwrap_or_default();
    assert!(wrong.contains("DINT") && wrong.contains("REAL"), "{wrong}");
    // The controller's identity, and the connection Large Forward Open made.
    let (_, link) = gw.get("/api/v1/links/plc").await.expect("link");
    assert_eq!(link["peer"]["connection_size"], "4002", "{link}");
    assert!(
        link["peer"]["product_name"]
            .as_str()
            .is_some_and(|n| !n.is_empty()),
        "{link}"
    );
    // Writes of every type, read back by pylogix.
    for (name, value) in [
        ("Speed", json!(12.5)),
        ("C3", json!(-42)),
        ("Flag", json!(true)),
        ("Small", json!(-5)),
        ("Wd", json!(-32768)),
        ("Big", json!(-9_000_000_000i64)),
        ("Us", json!(255)),
        ("Ui", json!(65535)),
        ("Ud", json!(4_000_000_000u64)),
        ("Ul", json!(18_000_000_000_000_000_000u64)),
        ("Lr", json!(2.25)),
        ("Label", json!("hello plant")),
        ("Sh", json!("short one")),
    ] {
        let outcome = put(&gw, name, value).await.expect("write");
        assert_eq!(outcome["status"], "written", "{name}: {outcome}");
    }
    let seen = plc
        .read(&[
            "Speed",
            "Counts[3]",
            "Flag",
            "Small",
            "Word",
            "Big",
            "Us",
            "Ui",
            "Ud",
            "Ul",
            "Lr",
        ])
        .await
        .expect("pylogix");
    assert_eq!(
        seen,
        json!({"Speed": 12.5, "Counts[3]": -42, "Flag": true, "Small": -5, "Word": -32768,
               "Big": -9_000_000_000i64, "Us": 255, "Ui": 65535, "Ud": 4_000_000_000u64,
               "Ul": 18_000_000_000_000_000_000u64, "Lr": 2.25})
    );
    let label = plc.print("Name").await.expect("cpppo");
    assert!(label.contains("['hello plant']"), "{label}");
    let short = plc.print("Short").await.expect("cpppo");
    assert!(short.contains("short one"), "{short}");
    // A Logix STRING takes 82 characters without a `length` in the profile.
    let long = "x".repeat(82);
    let outcome = put(&gw, "Label", json!(long)).await.expect("write");
    assert_eq!(outcome["status"], "written", "{outcome}");
    gw.shutdown().await;
    plc.kill().await.expect("kill");
}

/// The link's plan as the API shows it (the text `iogate plan` prints).
async fn plan(gw: &TestGateway) -> anyhow::Result<String> {
    let url = gw.url("/api/v1/links/plc/plan");
    Ok(gw.client.get(url).send().await?.text().await?)
}

/// How many times the link reopened after it was lost.
async fn reconnects(gw: &TestGateway) -> anyhow::Result<u64> {
    let text = gw.metrics().await?;
    Ok(text
        .lines()
        .find(|l| l.starts_with("iogate_link_reconnects_total{") && l.contains("link=\"plc\""))
        .and_then(|l| l.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or(0))
}

#[tokio::test]
async fn a_write_the_controller_refuses_is_not_sent_again_and_again() {
    // cpppo has no Read-Modify-Write Tag: it refuses the request (an encapsulation status).
    // The refusal is the write's outcome; the value is not written again after that (nor
    // more than twice more, had the controller dropped the connection at it), and the
    // integer holding the bit is never rewritten.
    let plc = LogixPlc::start(None, TAGS).await.expect("controller");
    let gw = gateway("eip-refused", plc.port).await.expect("gateway");
    read_once(&gw).await.expect("read");
    let outcome = put(&gw, "F5", json!(true)).await.expect("write");
    assert_eq!(outcome["status"], "failed", "{outcome}");
    let generation = outcome["generation"].as_u64().unwrap_or(0);
    let (_, now) = gw.get("/api/v1/devices/line").await.expect("device");
    let cycles = now["io_cycles"].as_u64().unwrap_or(0);
    gw.until("/api/v1/devices/line", "more cycles read", |d| {
        d["connected"] == true && d["io_cycles"].as_u64() >= Some(cycles + 10)
    })
    .await
    .expect("cycles");
    let (_, f5) = gw
        .get("/api/v1/devices/line/fields/F5")
        .await
        .expect("field");
    let last = &f5["last_write"];
    let replays = last["generation"].as_u64().unwrap_or(0) - generation;
    assert!(replays <= 2, "{f5}");
    if replays > 0 {
        assert!(
            last["error"]
                .as_str()
                .is_some_and(|e| e.contains("not written again")),
            "{f5}"
        );
    }
    let refused = last["error"].as_str().unwrap_or_default();
    assert!(refused.contains("Read-Modify-Write"), "{f5}");
    // cpppo ends the session after the refusal: one reconnect, with no value sent again.
    let before = reconnects(&gw).await.expect("metrics");
    assert!(before <= 3);
    // Learned: the next bit write is refused at once with why, and costs no session.
    let outcome = put(&gw, "F5", json!(false)).await.expect("write");
    assert_eq!(outcome["status"], "failed", "{outcome}");
    let error = outcome["error"].as_str().unwrap_or_default();
    assert!(
        error.contains("does not support Read-Modify-Write"),
        "{outcome}"
    );
    gw.until("/api/v1/devices/line", "cycles after it", |d| {
        d["connected"] == true && d["io_cycles"].as_u64() >= Some(cycles + 20)
    })
    .await
    .expect("cycles");
    assert_eq!(reconnects(&gw).await.expect("metrics"), before);
    assert_eq!(
        plc.read(&["Flags"]).await.expect("pylogix"),
        json!({"Flags": 0})
    );
    gw.shutdown().await;
    plc.kill().await.expect("kill");
}

#[tokio::test]
async fn a_controller_stopped_and_started_again_is_read_again() {
    let plc = LogixPlc::start(None, TAGS).await.expect("controller");
    let port = plc.port;
    let gw = gateway("eip-restart", port).await.expect("gateway");
    read_once(&gw).await.expect("read");
    plc.kill().await.expect("kill");
    gw.until("/api/v1/links/plc", "the link down", |l| {
        l["connected"] == false
    })
    .await
    .expect("down");
    let again = LogixPlc::start(Some(port), TAGS).await.expect("again");
    gw.until("/api/v1/links/plc", "the link back", |l| {
        l["connected"] == true
    })
    .await
    .expect("back");
    let outcome = put(&gw, "C3", json!(7)).await.expect("write");
    assert_eq!(outcome["status"], "written", "{outcome}");
    assert_eq!(
        again.read(&["Counts[3]"]).await.expect("pylogix"),
        json!({"Counts[3]": 7})
    );
    gw.shutdown().await;
    again.kill().await.expect("kill");
}

#[tokio::test]
async fn six_hundred_tags_are_read_in_several_packets_each_within_the_connection() {
    // Every other element of an array: 600 tags, none next to another (elements next to
    // each other are read together, see below).
    let plc = LogixPlc::start(None, &["Counts=DINT[1200]"])
        .await
        .expect("controller");
    let dir = temp_dir("eip-many");
    std::fs::create_dir_all(dir.join("profiles")).expect("dir");
    let mut profile = String::from("name: Many\nprotocol: ab-eip\nfields:\n");
    for i in 0..600 {
        profile.push_str(&format!(
            "  - {{ name: C{i}, type: DINT, direction: inout, tag: \"Counts[{}]\" }}\n",
            2 * i
        ));
    }
    std::fs::write(dir.join("profiles/many.yaml"), profile).expect("profile");
    let gw = TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {} }} }}\ndevices:\n  - {{ name: many, profile: Many, link: plc, refresh_rate: 100ms }}\n",
        dir.join("profiles").display(),
        plc.port
    ))
    .await
    .expect("gateway");
    // Elements written through the gateway, then every one read back in the gateway's
    // packets (16 to 18 bytes a tag asked: three packets of the 4,002-byte connection); a
    // packet past the connection would be refused whole.
    for i in [0, 31, 300, 599] {
        let (status, w) = gw
            .send(
                reqwest::Method::PUT,
                &format!("/api/v1/devices/many/fields/C{i}"),
                json!({ "value": 1000 + i }).to_string(),
            )
            .await
            .expect("write");
        assert_eq!(status, 202, "{w}");
    }
    let device = gw
        .until("/api/v1/devices/many", "every element read back", |d| {
            (0..600).all(|i| {
                let f = field(d, &format!("C{i}"));
                let want = if [0, 31, 300, 599].contains(&i) {
                    1000 + i
                } else {
                    0
                };
                f["quality"] == "good" && f["value"] == want
            })
        })
        .await;
    assert!(device.is_ok(), "{device:?}");
    // The plan, as `iogate plan` and the API show it: three packets a cycle.
    let plan = plan(&gw).await.expect("plan");
    assert!(plan.contains("3 packet(s) per cycle"), "{plan}");
    assert_eq!(
        plc.read(&["Counts[1198]", "Counts[62]"])
            .await
            .expect("pylogix"),
        json!({"Counts[1198]": 1599, "Counts[62]": 1031})
    );
    // The 600 written at once (one write group): in packets of the connection's size,
    // each write its own outcome; every value read back.
    let all: serde_json::Map<String, Value> = (0..600)
        .map(|i| (format!("C{i}"), json!(5000 + i)))
        .collect();
    let (status, body) = gw
        .send(
            reqwest::Method::PATCH,
            "/api/v1/devices/many/fields",
            Value::Object(all).to_string(),
        )
        .await
        .expect("patch");
    assert_eq!(status, 202, "{body}");
    let device = gw
        .until("/api/v1/devices/many", "every element written", |d| {
            (0..600).all(|i| {
                let f = field(d, &format!("C{i}"));
                f["value"] == 5000 + i && f["last_write"]["status"] == "written"
            })
        })
        .await;
    assert!(device.is_ok(), "{device:?}");
    assert_eq!(
        plc.read(&["Counts[0]", "Counts[600]", "Counts[1198]"])
            .await
            .expect("pylogix"),
        json!({"Counts[0]": 5000, "Counts[600]": 5300, "Counts[1198]": 5599})
    );
    gw.shutdown().await;
    plc.kill().await.expect("kill");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_sse_and_the_modbus_server_serve_a_logix_device_unchanged() -> anyhow::Result<()> {
    use iogate_tests::SseReader;
    use tokio_modbus::prelude::*;
    let plc = LogixPlc::start(None, TAGS).await?;
    let more = "modbus_server:\n  listen: 127.0.0.1:0\n  auto: true\n";
    let gw = gateway_with("eip-doors", plc.port, more).await?;
    read_once(&gw).await?;
    let mut grpc = gw.client().await?;
    let read = grpc.get("line", "Wd").await?;
    assert_eq!(read.value, Some(iogate_client::Value::Int(0)), "{read:?}");
    // The map's automatic binding of Wd (an INT), read and written by a Modbus master.
    let (_, map) = gw.get("/api/v1/map").await?;
    let binding = map["bindings"]
        .as_array()
        .and_then(|b| {
            b.iter()
                .find(|b| b["device"] == "line" && b["field"] == "Wd")
        })
        .ok_or_else(|| anyhow::anyhow!("no binding of Wd in {map}"))?;
    let register = binding["address"]
        .as_u64()
        .ok_or_else(|| anyhow::anyhow!("no address in {binding}"))? as u16;
    let addr = gw
        .modbus
        .ok_or_else(|| anyhow::anyhow!("no Modbus server"))?;
    let mut master = tcp::connect_slave(addr, Slave(1)).await?;
    let mut events = SseReader::open(&gw, "/api/v1/events?device=line").await?;
    master
        .write_single_register(register, (-1234i16) as u16)
        .await??;
    let told = events
        .until(|_, e| e["field"] == "Wd" && e["value"] == json!(-1234))
        .await?;
    assert_eq!(told["device"], "line", "{told}");
    assert_eq!(plc.read(&["Word"]).await?, json!({"Word": -1234}));
    let words = master.read_holding_registers(register, 1).await??;
    assert_eq!(words, vec![(-1234i16) as u16]);
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test]
async fn elements_next_to_each_other_are_read_together_and_a_large_array_fragmented() {
    // Data: 2,000 DINTs (8,000 bytes, twice the connection): one read, fragmented. Tail:
    // elements 8 to 10 of an array of 10, read together at first; the read fails (10 is
    // past the end), so each is read on its own: 8 and 9 good, 10 its own error.
    // Mid: 500 DINTs, one read that fits the connection, which cpppo answers in part
    // (status 0x06): read fragmented instead.
    let plc = LogixPlc::start(None, &["Data=DINT[2000]", "Tail=INT[10]", "Mid=DINT[500]"])
        .await
        .expect("controller");
    let dir = temp_dir("eip-runs");
    std::fs::create_dir_all(dir.join("profiles")).expect("dir");
    let mut profile = String::from("name: Runs\nprotocol: ab-eip\nfields:\n");
    for i in 0..2000 {
        profile.push_str(&format!(
            "  - {{ name: D{i}, type: DINT, direction: inout, tag: \"Data[{i}]\" }}\n"
        ));
    }
    for i in 8..=10 {
        profile.push_str(&format!(
            "  - {{ name: T{i}, type: INT, direction: input, tag: \"Tail[{i}]\" }}\n"
        ));
    }
    for i in 0..500 {
        profile.push_str(&format!(
            "  - {{ name: M{i}, type: DINT, direction: inout, tag: \"Mid[{i}]\" }}\n"
        ));
    }
    std::fs::write(dir.join("profiles/runs.yaml"), profile).expect("profile");
    let gw = TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {} }} }}\ndevices:\n  - {{ name: runs, profile: Runs, link: plc, refresh_rate: 100ms }}\n",
        dir.join("profiles").display(),
        plc.port
    ))
    .await
    .expect("gateway");
    let plan = plan(&gw).await.expect("plan");
    assert!(
        plan.contains("D0 (Data[0]) to D1999 (Data[1999]), 2000 elements in one read")
            && plan.contains("read fragmented (8008 bytes"),
        "{plan}"
    );
    // Written through the gateway (the last element, one in the second part), read back.
    for (f, v) in [("D1999", 77), ("D1000", -5), ("M499", 9)] {
        let (status, w) = gw
            .send(
                reqwest::Method::PUT,
                &format!("/api/v1/devices/runs/fields/{f}"),
                json!({ "value": v }).to_string(),
            )
            .await
            .expect("write");
        assert_eq!(status, 202, "{w}");
    }
    let device = gw
        .until("/api/v1/devices/runs", "every element read", |d| {
            let good = |n: &str| field(d, n)["quality"] == "good";
            field(d, "D1999")["value"] == 77
                && field(d, "D1000")["value"] == -5
                && field(d, "M499")["value"] == 9
                && good("M0")
                && good("D0")
                && good("D1998")
                && good("T8")
                && good("T9")
                && field(d, "T10")["error"].is_string()
        })
        .await;
    assert!(device.is_ok(), "{device:?}");
    assert_eq!(
        plc.read(&["Data[1999]", "Data[1000]"])
            .await
            .expect("pylogix"),
        json!({"Data[1999]": 77, "Data[1000]": -5})
    );
    gw.shutdown().await;
    plc.kill().await.expect("kill");
}
