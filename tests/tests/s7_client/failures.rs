//! A PLC in STOP (values kept, stale, with what to do), and a server stopped and started
//! again (values bad while it is away, good again after).

use super::*;
use iogate_tests::s7::S7Plc;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plc_in_stop_is_told_and_a_restarted_one_is_read_again() -> anyhow::Result<()> {
    let mut plc = S7Plc::start(None).await?;
    let port = plc.port;
    let gw = gateway("s7-failures", port).await?;
    until_device(&gw, "press960", "read", |d| {
        field(d, "In")["quality"] == "good"
    })
    .await?;
    assert_eq!(plc.cmd("stop").await?, "ok");
    let d = until_device(&gw, "press960", "stale in STOP", |d| {
        field(d, "In")["quality"] == "stale"
    })
    .await?;
    assert_eq!(field(&d, "In")["value"], json!(-300), "the value is kept");
    let why = field(&d, "In")["error"].as_str().unwrap_or_default();
    assert!(
        why.contains("STOP") && why.contains("switch it to RUN"),
        "{why}"
    );
    let (_, link) = gw.get("/api/v1/links/plc960").await?;
    assert_eq!(link["peer"]["cpu_state"], "stop", "{link}");
    assert_eq!(plc.cmd("run").await?, "ok");
    until_device(&gw, "press960", "good in RUN", |d| {
        field(d, "In")["quality"] == "good"
    })
    .await?;

    // The server goes away: the link is down and the values bad; back on the same port, it
    // is read again.
    plc.kill().await?;
    gw.until("/api/v1/links/plc960", "the link down", |l| {
        l["connected"] == false
    })
    .await?;
    until_device(&gw, "press960", "bad while away", |d| {
        field(d, "In")["quality"] == "bad"
    })
    .await?;
    let plc = S7Plc::start(Some(port)).await?;
    until_device(&gw, "press960", "good again", |d| {
        field(d, "In")["quality"] == "good" && field(d, "In")["value"] == json!(-300)
    })
    .await?;
    gw.until("/api/v1/links/plc960", "the link up", |l| {
        l["connected"] == true
    })
    .await?;
    gw.shutdown().await;
    plc.kill().await
}
