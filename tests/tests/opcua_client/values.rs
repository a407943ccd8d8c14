//! Values both ways: every IEC type read and written, a change with its source timestamp
//! and status, a profile imported from the server.

use iogate_tests::devices::temp_dir;
use iogate_tests::plc::UaPlc;
use iogate_tests::{SseReader, TestGateway};
use serde_json::json;

use super::{field, gateway, until_field};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_iec_type_is_read_and_written_through_an_independent_server() -> anyhow::Result<()> {
    let dir = temp_dir("uaclient-types");
    let mut plc = UaPlc::start(&[]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    let read = [
        ("B", json!(false)),
        ("SI", json!(-5)),
        ("I", json!(-300)),
        ("DI", json!(100000)),
        ("LI", json!(-(1i64 << 40))),
        ("USI", json!(200)),
        ("UI", json!(60000)),
        ("UDI", json!(4000000000u64)),
        ("ULI", json!(1u64 << 63)),
        ("R", json!(1.5)),
        ("LR", json!(2.25)),
        ("S", json!("hello")),
        ("Speed", json!(0.0)),
    ];
    for (name, value) in &read {
        let f = until_field(&gw, name, name, |f| f["quality"] == "good").await?;
        assert_eq!(&f["value"], value, "{name}: {f}");
    }
    // A value that does not fit its field is an error naming both, never a wrapped number.
    let big = until_field(&gw, "Big", "Big bad", |f| f["quality"] == "bad").await?;
    assert!(big["value"].is_null(), "{big}");
    let error = big["error"].as_str().unwrap_or_default();
    assert!(error.contains("Int32") && error.contains("INT"), "{error}");
    // A node the server does not have is that field's error in the server's words.
    let missing = until_field(&gw, "Missing", "Missing bad", |f| f["quality"] == "bad").await?;
    assert_eq!(missing["error"], "BadNodeIdUnknown", "{missing}");

    writes_of_every_type(&gw, &mut plc).await?;
    // The server's refusal is the write's failure reason.
    let (_, body) = gw
        .send(
            reqwest::Method::PUT,
            "/api/v1/devices/line1/fields/Locked",
            json!({ "value": 1 }).to_string(),
        )
        .await?;
    let generation = body["generation"].as_u64().unwrap_or_default();
    let outcome = gw
        .until(&format!("/api/v1/writes/{generation}"), "refused", |w| {
            w["status"] != "pending"
        })
        .await?;
    assert_eq!(outcome["status"], "failed", "{outcome}");
    let error = outcome["error"].as_str().unwrap_or_default();
    assert!(
        error.contains("BadUserAccessDenied") || error.contains("BadNotWritable"),
        "{error}"
    );
    assert_eq!(plc.get("Locked").await?, json!(7));
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_change_on_the_server_is_seen_once_with_its_source_timestamp_and_its_status()
-> anyhow::Result<()> {
    let dir = temp_dir("uaclient-change");
    let mut plc = UaPlc::start(&[]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    until_field(&gw, "Speed", "Speed read", |f| f["quality"] == "good").await?;
    let mut events = SseReader::open(&gw, "/api/v1/events?device=line1").await?;
    let before = std::time::SystemTime::now();
    plc.set("Speed", json!(12.5)).await?;
    let change = events
        .until(|_, e| e["field"] == "Speed" && e["value"] == json!(12.5))
        .await?;
    let stamp = change["timestamp"].as_str().unwrap_or_default().to_owned();
    let at = humantime::parse_rfc3339_weak(stamp.trim_end_matches('Z'))?;
    let skew = at.duration_since(before).unwrap_or_else(|e| e.duration());
    assert!(
        skew < std::time::Duration::from_secs(2),
        "source timestamp {stamp}"
    );
    // Once: the next event of the field is the next change, not a repeat.
    plc.set("Speed", json!(13.5)).await?;
    let next = events.until(|_, e| e["field"] == "Speed").await?;
    assert_eq!(next["value"], json!(13.5), "{next}");
    // A change within a field's deadband (LR's, 0.5) is not reported by the server.
    plc.set("LReal", json!(20.0)).await?;
    events
        .until(|_, e| e["field"] == "LR" && e["value"] == json!(20.0))
        .await?;
    plc.set("LReal", json!(20.3)).await?;
    // Two publishing cycles pass (Speed's changes told) before the next change of LR; no
    // event of LR comes meanwhile.
    let mut told = Vec::new();
    for speed in [31.0, 32.0] {
        plc.set("Speed", json!(speed)).await?;
        events
            .until(|_, e| {
                if e["field"] == "LR" {
                    told.push(e["value"].clone());
                }
                e["field"] == "Speed" && e["value"] == json!(speed)
            })
            .await?;
    }
    assert!(told.is_empty(), "told within the deadband: {told:?}");
    plc.set("LReal", json!(21.0)).await?;
    let next = events.until(|_, e| e["field"] == "LR").await?;
    assert_eq!(next["value"], json!(21.0), "{next}");

    plc.cmd(json!({"cmd": "status", "name": "Speed", "status": "UncertainLastUsableValue"}))
        .await?;
    let doubt = until_field(&gw, "Speed", "uncertain", |f| f["quality"] == "stale").await?;
    assert_eq!(doubt["value"], json!(32.0), "{doubt}");
    assert_eq!(doubt["error"], "UncertainLastUsableValue", "{doubt}");
    plc.cmd(json!({"cmd": "status", "name": "Speed", "status": "BadSensorFailure"}))
        .await?;
    let bad = until_field(&gw, "Speed", "bad", |f| f["quality"] == "bad").await?;
    assert_eq!(bad["error"], "BadSensorFailure", "{bad}");
    plc.set("Speed", json!(14.0)).await?;
    until_field(&gw, "Speed", "good again", |f| {
        f["quality"] == "good" && f["value"] == json!(14.0)
    })
    .await?;
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_profile_imported_from_the_server_reads_it() -> anyhow::Result<()> {
    let dir = temp_dir("uaclient-import");
    let plc = UaPlc::start(&[]).await?;
    let profiles = dir.join("profiles");
    let (url, out) = (plc.url.clone(), profiles.clone());
    let code = tokio::task::spawn_blocking(move || {
        iogate::drivers::opcua::import::run(&url, Some("ns=2;s=Line1"), Some(&out))
    })
    .await?;
    assert_eq!(code, 0);
    let text = std::fs::read_to_string(profiles.join("Line1.yaml"))?;
    // Units from EngineeringUnits, directions from access levels, nodes by namespace URI;
    // a DateTime and an array are reported, not made fields.
    assert!(
        text.contains(
            "name: Speed, type: LREAL, direction: inout, node: \"nsu=urn:iogate:test:plc;s=Line1.Speed\", unit: \"rpm\""
        ),
        "{text}"
    );
    assert!(
        text.contains("name: Locked, type: INT, direction: input"),
        "{text}"
    );
    assert!(
        !text.contains("Started") && !text.contains("Counts"),
        "{text}"
    );
    let config = format!(
        "profiles: {}\nlinks:\n  - name: plc\n    opcua: {{ url: \"{}\", pki_dir: {} }}\ndevices:\n  - {{ name: line1, profile: Line1, link: plc, refresh_rate: 100ms }}\n",
        profiles.display(),
        plc.url,
        dir.join("pki").display()
    );
    let gw = TestGateway::start(&config).await?;
    let device = gw.all_read("line1").await?;
    assert_eq!(field(&device, "Locked")["value"], json!(7), "{device}");
    assert_eq!(field(&device, "Speed")["unit"], "rpm", "{device}");
    gw.shutdown().await;
    plc.kill().await
}

/// Each type written through REST reaches the server as that type's value.
async fn writes_of_every_type(gw: &TestGateway, plc: &mut UaPlc) -> anyhow::Result<()> {
    let writes = [
        ("B", "Bool", json!(true)),
        ("SI", "SInt", json!(-128)),
        ("I", "Int", json!(32767)),
        ("DI", "DInt", json!(-7)),
        ("LI", "LInt", json!(i64::MIN)),
        ("USI", "USInt", json!(255)),
        ("UI", "UInt", json!(1)),
        ("UDI", "UDInt", json!(u32::MAX)),
        ("ULI", "ULInt", json!(u64::MAX)),
        ("R", "Real", json!(-3.25)),
        ("LR", "LReal", json!(1e300)),
        ("S", "Str", json!("world")),
    ];
    for (field_name, var, value) in &writes {
        let (status, body) = gw
            .send(
                reqwest::Method::PUT,
                &format!("/api/v1/devices/line1/fields/{field_name}"),
                json!({ "value": value }).to_string(),
            )
            .await?;
        assert!(status < 300, "{field_name}: {status} {body}");
        let generation = body["generation"].as_u64().unwrap_or_default();
        let outcome = gw
            .until(&format!("/api/v1/writes/{generation}"), "written", |w| {
                w["status"] != "pending"
            })
            .await?;
        assert_eq!(outcome["status"], "written", "{field_name}: {outcome}");
        assert_eq!(&plc.get(var).await?, value, "{var} on the server");
    }
    Ok(())
}
