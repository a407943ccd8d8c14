//! Bits of an integer written with Read-Modify-Write Tag, against a controller that has the
//! service (`tests/eip/directory_plc.py`; cpppo's simulator refuses it), with pylogix
//! (whose own bit writes use the same service) setting and reading the integers: only the
//! bit asked for changes, even when the integer changed on the controller after the
//! gateway last read it. Stopped, the gateway closes its connection (Forward Close) and its
//! session. A controller without Large Forward Open, or without any, is read and written on
//! what it has.

use iogate_tests::TestGateway;
use iogate_tests::devices::temp_dir;
use iogate_tests::eip::LogixPlc;
use serde_json::{Value, json};

const PROFILE: &str = r#"name: Bits
protocol: ab-eip
fields:
  - { name: Flags, type: DINT, direction: input, tag: Flags }
  - { name: Wd, type: INT, direction: input, tag: Word }
  - { name: F0, type: BOOL, direction: inout, tag: Flags.0 }
  - { name: F4, type: BOOL, direction: inout, tag: Flags.4 }
  - { name: W15, type: BOOL, direction: inout, tag: Word.15 }
  - { name: Ghost, type: DINT, direction: inout, tag: Ghost }
"#;

/// Writes through REST and waits for the outcome.
async fn put(gw: &TestGateway, name: &str, value: Value) -> anyhow::Result<Value> {
    gw.write_outcome("bits", name, value)
        .await?
        .map_err(|refused| anyhow::anyhow!("{name}: {refused}"))
}

#[tokio::test]
async fn a_bit_is_written_alone_whatever_the_rest_of_its_integer_became() {
    let mut plc = LogixPlc::directory(&[]).await.expect("controller");
    assert_eq!(
        plc.write(&["Flags=0x0F0F0F0F", "Word=1"])
            .await
            .expect("pylogix"),
        json!({"Flags": "Success", "Word": "Success"})
    );
    let dir = temp_dir("eip-bits");
    std::fs::create_dir_all(dir.join("profiles")).expect("dir");
    std::fs::write(dir.join("profiles/bits.yaml"), PROFILE).expect("profile");
    // Read once an hour: the gateway's value of each integer stays the first one read.
    let gw = TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {} }} }}\ndevices:\n  - {{ name: bits, profile: Bits, link: plc, refresh_rate: 1h }}\n",
        dir.join("profiles").display(),
        plc.port
    ))
    .await
    .expect("gateway");
    gw.until("/api/v1/devices/bits", "the integers read", |d| {
        d["fields"]["Flags"]["value"] == 0x0F0F0F0F
            && d["fields"]["Wd"]["value"] == 1
            && d["fields"]["Ghost"]["error"].is_string()
    })
    .await
    .expect("read");
    // The controller's integers change after the gateway's read (pylogix's own
    // Read-Modify-Write: bit 12 of Flags set, bit 0 of Word cleared, bit 3 set), then the
    // gateway writes other bits.
    assert_eq!(
        plc.write(&["Flags.12=true", "Word.0=false", "Word.3=true"])
            .await
            .expect("pylogix"),
        json!({"Flags.12": "Success", "Word.0": "Success", "Word.3": "Success"})
    );
    for (name, value) in [("F4", true), ("F0", false), ("W15", true)] {
        let outcome = put(&gw, name, json!(value)).await.expect("write");
        assert_eq!(outcome["status"], "written", "{name}: {outcome}");
    }
    // What pylogix changed stays; only the gateway's bits changed besides: Flags
    // 0x0F0F0F0F | bit 12 | bit 4, less bit 0; Word 8 | bit 15 (an INT: -32760).
    assert_eq!(
        plc.read(&["Flags", "Word"]).await.expect("pylogix"),
        json!({"Flags": 0x0F0F_1F1E, "Word": -32760})
    );
    // Two writes at once go in one Multiple Service Packet: each its own outcome (a tag
    // the controller does not have refused, the bit written).
    let (status, body) = gw
        .send(
            reqwest::Method::PATCH,
            "/api/v1/devices/bits/fields",
            json!({"F4": false, "Ghost": 5}).to_string(),
        )
        .await
        .expect("patch");
    assert_eq!(status, 202, "{body}");
    let device = gw
        .until("/api/v1/devices/bits", "both outcomes", |d| {
            let f = &d["fields"];
            f["F4"]["last_write"]["value"] == false
                && f["F4"]["last_write"]["status"] == "written"
                && f["Ghost"]["last_write"]["status"] == "failed"
        })
        .await
        .expect("outcomes");
    let ghost = device["fields"]["Ghost"]["last_write"]["error"]
        .as_str()
        .unwrap_or_default();
    assert!(ghost.contains("0x05"), "{ghost}");
    assert_eq!(
        plc.read(&["Flags"]).await.expect("pylogix"),
        json!({"Flags": 0x0F0F_1F0E})
    );
    // Stopped, the gateway closes its connection and its session on the controller.
    gw.shutdown().await;
    let mut told = Vec::new();
    while !told
        .iter()
        .any(|l: &String| l.starts_with("forward-close vendor=0x4947"))
    {
        told.push(plc.said().await.expect("the gateway's Forward Close"));
    }
    assert_eq!(
        plc.said().await.expect("and its session"),
        "unregister-session"
    );
    plc.kill().await.expect("kill");
}

#[tokio::test]
async fn a_controller_without_large_forward_open_or_any_is_read_on_what_it_has() {
    // The last: a controller with connections, read unconnected as the link asks.
    for (flag, asked, size) in [
        (Some("--small"), "", "504"),
        (Some("--unconnected"), "", "unconnected"),
        (None, ", connected: false", "unconnected"),
    ] {
        // pylogix needs a connection: the gateway's own reads are the check here.
        let flags: Vec<&str> = flag.into_iter().collect();
        let plc = LogixPlc::directory(&flags).await.expect("controller");
        let dir = temp_dir("eip-sizes");
        std::fs::create_dir_all(dir.join("profiles")).expect("dir");
        std::fs::write(dir.join("profiles/bits.yaml"), PROFILE).expect("profile");
        let gw = TestGateway::start(&format!(
            "profiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {}{asked} }} }}\ndevices:\n  - {{ name: bits, profile: Bits, link: plc, refresh_rate: 100ms }}\n",
            dir.join("profiles").display(),
            plc.port
        ))
        .await
        .expect("gateway");
        gw.until("/api/v1/devices/bits", "Flags read", |d| {
            d["fields"]["Flags"]["value"] == 0
        })
        .await
        .expect("read");
        let (_, link) = gw.get("/api/v1/links/plc").await.expect("link");
        assert_eq!(link["peer"]["connection_size"], size, "{flag:?}: {link}");
        let outcome = put(&gw, "F4", json!(true)).await.expect("write");
        assert_eq!(outcome["status"], "written", "{flag:?}: {outcome}");
        gw.until("/api/v1/devices/bits", "the bit read back", |d| {
            d["fields"]["Flags"]["value"] == 16
        })
        .await
        .expect("read back");
        gw.shutdown().await;
        plc.kill().await.expect("kill");
    }
}
