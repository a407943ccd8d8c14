//! What a server sends that the client's decoding limits used to refuse: a string longer
//! than 65,535 bytes (the field's error, named; the session stays) and the first publish of
//! a 2,000-field device in one answer (FreeOpcUa's server sends them so).

use super::*;
use iogate_tests::devices::temp_dir;
use serde_json::json;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_value_too_long_for_its_field_is_the_fields_error_and_the_session_stays()
-> anyhow::Result<()> {
    let dir = temp_dir("uaclient-long");
    let mut plc = UaPlc::start(&[]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    until_field(&gw, "S", "read", |f| f["quality"] == "good").await?;
    plc.set("Str", json!("x".repeat(100_000))).await?;
    let s = until_field(&gw, "S", "the error", |f| f["error"].is_string()).await?;
    let why = s["error"].as_str().unwrap_or_default();
    assert!(why.contains("100000 bytes"), "{s}");
    // The same session reads on.
    plc.set("UInt", json!(5)).await?;
    until_field(&gw, "UI", "read on", |f| f["value"] == json!(5)).await?;
    let metrics = gw.metrics().await?;
    assert!(
        metrics.contains("iogate_link_reconnects_total{link=\"plc\"} 0"),
        "reconnected: {}",
        metrics
            .lines()
            .filter(|l| l.contains("reconnects"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_of_two_thousand_fields_is_read_whole_from_one_publish() -> anyhow::Result<()> {
    const N: usize = 2000;
    let dir = temp_dir("uaclient-many");
    let plc = UaPlc::start(&["--many", &N.to_string()]).await?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Many\nprotocol: opcua\nfields:\n");
    for k in 0..N {
        profile.push_str(&format!(
            "  - {{ name: M{k}, type: DINT, direction: input, node: \"ns={};s=Line1.Many.{k}\" }}\n",
            plc.ns
        ));
    }
    std::fs::write(profiles.join("many.yaml"), profile)?;
    let gw = TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - name: plc\n    opcua: {{ url: \"{}\", pki_dir: {} }}\ndevices:\n  - {{ name: many, profile: Many, link: plc, refresh_rate: 500ms }}\n",
        profiles.display(),
        plc.url,
        dir.join("pki").display()
    ))
    .await?;
    gw.until("/api/v1/devices/many", "every field read", |d| {
        (0..N).all(|k| d["fields"][format!("M{k}")]["value"] == json!(k))
    })
    .await?;
    let metrics = gw.metrics().await?;
    assert!(
        metrics.contains("iogate_link_reconnects_total{link=\"plc\"} 0"),
        "reconnected"
    );
    gw.shutdown().await;
    plc.kill().await
}
