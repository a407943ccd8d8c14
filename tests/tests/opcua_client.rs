//! The OPC UA client driver against an independent server (asyncua, Python, as a PLC):
//! every IEC type read and written, a server-side change seen once with its source
//! timestamp, status codes as qualities, a value that does not fit its field, a write the
//! server refuses, the server killed and restarted with its namespaces in another order, a
//! server without subscriptions, a subscription the server drops.

use std::path::Path;

use iogate_tests::devices::temp_dir;
use iogate_tests::plc::UaPlc;
use iogate_tests::{SseReader, TestGateway};
use serde_json::{Value, json};

/// One field per variable of the PLC, as a profile writes them (namespace index 2, which
/// the server's first start has).
const PROFILE: &str = r#"name: TestPlc
protocol: opcua
fields:
  - { name: B, type: BOOL, direction: inout, node: "ns=2;s=Line1.Bool" }
  - { name: SI, type: SINT, direction: inout, node: "ns=2;s=Line1.SInt" }
  - { name: I, type: INT, direction: inout, node: "ns=2;s=Line1.Int" }
  - { name: DI, type: DINT, direction: inout, node: "ns=2;s=Line1.DInt" }
  - { name: LI, type: LINT, direction: inout, node: "ns=2;s=Line1.LInt" }
  - { name: USI, type: USINT, direction: inout, node: "ns=2;s=Line1.USInt" }
  - { name: UI, type: UINT, direction: inout, node: "ns=2;s=Line1.UInt" }
  - { name: UDI, type: UDINT, direction: inout, node: "ns=2;s=Line1.UDInt" }
  - { name: ULI, type: ULINT, direction: inout, node: "ns=2;s=Line1.ULInt" }
  - { name: R, type: REAL, direction: inout, node: "ns=2;s=Line1.Real" }
  - { name: LR, type: LREAL, direction: inout, node: "ns=2;s=Line1.LReal" }
  - { name: S, type: STRING, direction: inout, node: "ns=2;s=Line1.Str", length: 20 }
  - { name: Big, type: INT, direction: input, node: "ns=2;s=Line1.Big" }
  - { name: Locked, type: INT, direction: inout, node: "ns=2;s=Line1.Locked" }
  - { name: Speed, type: LREAL, direction: input, browse_path: "2:Line1/2:Speed", unit: rpm }
  - { name: Missing, type: INT, direction: input, node: "nsu=urn:iogate:test:plc;s=Line1.Nope" }
"#;

/// A gateway with the PLC as device `line1` (refreshed every 100 ms) on link `plc`.
async fn gateway(dir: &Path, plc: &UaPlc, extra: &str) -> anyhow::Result<TestGateway> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    std::fs::write(profiles.join("plc.yaml"), PROFILE)?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: plc\n    opcua: {{ url: \"{}\", pki_dir: {}{extra} }}\ndevices:\n  - {{ name: line1, profile: TestPlc, link: plc, refresh_rate: 100ms }}\n",
        profiles.display(),
        plc.url,
        dir.join("pki").display()
    );
    TestGateway::start(&config).await
}

fn field<'a>(device: &'a Value, name: &str) -> &'a Value {
    &device["fields"][name]
}

/// Waits until field `name` of `line1` satisfies `check`.
async fn until_field(
    gw: &TestGateway,
    name: &str,
    what: &str,
    check: impl Fn(&Value) -> bool,
) -> anyhow::Result<Value> {
    let device = gw
        .until("/api/v1/devices/line1", what, |d| check(field(d, name)))
        .await?;
    Ok(field(&device, name).clone())
}

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

    plc.cmd(json!({"cmd": "status", "name": "Speed", "status": "UncertainLastUsableValue"}))
        .await?;
    let doubt = until_field(&gw, "Speed", "uncertain", |f| f["quality"] == "stale").await?;
    assert_eq!(doubt["value"], json!(13.5), "{doubt}");
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
async fn a_server_restarted_with_its_namespaces_reordered_is_read_again_without_an_operator()
-> anyhow::Result<()> {
    let dir = temp_dir("uaclient-restart");
    let mut plc = UaPlc::start(&[]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    until_field(&gw, "I", "read", |f| f["quality"] == "good").await?;
    plc.set("Int", json!(11)).await?;
    until_field(&gw, "I", "11", |f| f["value"] == json!(11)).await?;
    let port = plc.port();
    plc.kill().await?;
    // While the server is away its values stay, stale, with why.
    let away = until_field(&gw, "I", "stale", |f| f["quality"] == "stale").await?;
    assert_eq!(away["value"], json!(11), "{away}");
    assert!(away["error"].is_string(), "{away}");
    let link = gw
        .until("/api/v1/links/plc", "link down", |l| {
            l["connected"] == false
        })
        .await?;
    assert_eq!(link["kind"], "opcua", "{link}");
    // Back with two namespaces before ours: the profile's `ns=2` is found by its URI.
    let mut plc = UaPlc::start(&["--port", &port, "--reorder"]).await?;
    assert_eq!(plc.ns, 4);
    plc.set("Int", json!(22)).await?;
    let back = until_field(&gw, "I", "fresh again", |f| {
        f["quality"] == "good" && f["value"] == json!(22)
    })
    .await?;
    assert!(back["error"].is_null(), "{back}");
    gw.until("/api/v1/links/plc", "link up", |l| l["connected"] == true)
        .await?;
    let reconnects = gw.metrics().await?;
    assert!(
        reconnects.contains("iogate_link_reconnects_total{link=\"plc\"} 1"),
        "{}",
        reconnects
            .lines()
            .filter(|l| l.contains("reconnect"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_without_subscriptions_is_read_every_refresh() -> anyhow::Result<()> {
    let dir = temp_dir("uaclient-reads");
    let mut plc = UaPlc::start(&["--no-subscriptions"]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    until_field(&gw, "UI", "read", |f| f["value"] == json!(60000)).await?;
    plc.set("UInt", json!(5)).await?;
    until_field(&gw, "UI", "read again", |f| f["value"] == json!(5)).await?;
    let subscriptions = plc.cmd(json!({"cmd": "subscriptions"})).await?;
    assert_eq!(subscriptions["count"], 0);
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscription_the_server_drops_is_made_again() -> anyhow::Result<()> {
    let dir = temp_dir("uaclient-dropped");
    let mut plc = UaPlc::start(&[]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    until_field(&gw, "UDI", "read", |f| f["quality"] == "good").await?;
    let dropped = plc.cmd(json!({"cmd": "drop_subscriptions"})).await?;
    assert_eq!(dropped["dropped"], 1);
    plc.set("UDInt", json!(77)).await?;
    // Silent past its keep-alive allowance, it is made again and reports the change.
    until_field(&gw, "UDI", "the change after the drop", |f| {
        f["value"] == json!(77) && f["quality"] == "good"
    })
    .await?;
    assert_eq!(plc.cmd(json!({"cmd": "subscriptions"})).await?["count"], 1);
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sign_and_encrypt_connects_once_each_side_trusts_the_others_certificate()
-> anyhow::Result<()> {
    let dir = temp_dir("uaclient-secure");
    let trusted = dir.join("plc-trusted");
    std::fs::create_dir_all(&trusted)?;
    let (cert, key) = (dir.join("plc.der"), dir.join("plc.pem"));
    let security = |plc_args: &mut Vec<String>| {
        plc_args.extend(["--security".into(), cert.display().to_string()]);
        plc_args.extend([key.display().to_string(), trusted.display().to_string()]);
    };
    let mut args = Vec::new();
    security(&mut args);
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let plc = UaPlc::start(&refs).await?;
    // The gateway's application certificate, made by the PLC's library.
    let (own, own_key) = (dir.join("iogate.der"), dir.join("iogate.pem"));
    let made = std::process::Command::new("python3")
        .arg(iogate_tests::repo_file("opcua/plc.py"))
        .args(["--client-cert", &own.display().to_string()])
        .arg(&own_key)
        .output()?;
    anyhow::ensure!(made.status.success(), "{made:?}");
    // The gateway trusts the PLC's certificate; the PLC does not know the gateway's yet.
    let extra = format!(
        ", security_policy: Basic256Sha256, certificate: {}, private_key: {}, trusted: [{}]",
        own.display(),
        own_key.display(),
        cert.display()
    );
    let gw = gateway(&dir, &plc, &extra).await?;
    let refused = gw
        .until("/api/v1/links/plc", "refused", |l| l["error_code"] == 2)
        .await?;
    assert_eq!(refused["connected"], false, "{refused}");
    // Named in the server's words where users look: the field and the link.
    let untrusted = until_field(&gw, "I", "the refusal", |f| {
        f["error"]
            .as_str()
            .is_some_and(|e| e.contains("BadCertificateUntrusted"))
    })
    .await?;
    assert_eq!(untrusted["quality"], "bad", "{untrusted}");
    // Trusted by the PLC (restarted, on the same port), the gateway's next attempt gets in.
    std::fs::copy(&own, trusted.join("iogate.der"))?;
    let port = plc.port();
    plc.kill().await?;
    let mut args = vec!["--port".to_owned(), port];
    security(&mut args);
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let mut plc = UaPlc::start(&refs).await?;
    until_field(&gw, "I", "read over a secure channel", |f| {
        f["quality"] == "good"
    })
    .await?;
    plc.set("Int", json!(5)).await?;
    until_field(&gw, "I", "a change over it", |f| f["value"] == json!(5)).await?;
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
