//! A guest on someone else's PLC: an output another client changed is not written back
//! after a connection drop, a PLC that opens and then fails is not stormed, and nothing is
//! left open on it.

use super::*;
use iogate_tests::cable::Cable;
use iogate_tests::s7::S7Plc;
use std::time::{Duration, Instant};

const GUEST: &str = r#"name: Guest
protocol: s7
fields:
  - { name: Mb5, type: USINT, direction: inout, address: MB5 }
  - { name: Mw10, type: INT, direction: input, address: MW10 }
"#;

/// A gateway with one S7 link to `port` (a cable to the PLC).
async fn guest(name: &str, port: u16) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/guest.yaml"), GUEST)?;
    TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - name: plc\n    s7: {{ host: 127.0.0.1, port: {port}, timeout: 1s }}\ndevices:\n  - {{ name: guest, profile: Guest, link: plc, refresh_rate: 50ms }}\n",
        dir.join("profiles").display()
    ))
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_output_another_client_set_is_not_written_back_after_a_connection_drop()
-> anyhow::Result<()> {
    let mut plc = S7Plc::start(None).await?;
    let cable = Cable::to(plc.port).await?;
    let gw = guest("s7-guest-rewrite", cable.port).await?;
    let d = until_device(&gw, "guest", "read", |d| {
        field(d, "Mb5")["quality"] == "good"
    })
    .await?;
    assert_eq!(d["rewrite_outputs"], "never", "S7's default");
    let outcome = write(&gw, "guest", "Mb5", json!(17)).await?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    assert_eq!(plc.dump("MK 0", 5, 1).await?, "11");
    // An HMI sets 34; the gateway reads it; the connection drops for a moment.
    assert_eq!(plc.cmd("set MK 0 5 22").await?, "ok");
    until_device(&gw, "guest", "34 read", |d| {
        field(d, "Mb5")["value"] == json!(34)
    })
    .await?;
    cable.cut();
    iogate_tests::eventually("the gateway connects again", || async {
        cable.accepted() >= 2
    })
    .await?;
    // Read again after the reconnect (a write would have gone before the first read).
    let (_, now) = gw.get("/api/v1/devices/guest").await?;
    let cycles = now["io_cycles"].as_u64().unwrap_or_default();
    let d = until_device(&gw, "guest", "read after the reconnect", |d| {
        d["io_cycles"].as_u64().unwrap_or_default() >= cycles + 3 && d["connected"] == true
    })
    .await?;
    assert_eq!(plc.dump("MK 0", 5, 1).await?, "22", "34 stays");
    assert_eq!(field(&d, "Mb5")["value"], json!(34));
    assert_eq!(
        field(&d, "Mb5")["last_write"]["generation"],
        outcome["generation"],
        "no write of the gateway's own: {d}"
    );
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_plc_that_opens_and_then_fails_is_reconnected_to_with_a_growing_back_off()
-> anyhow::Result<()> {
    let plc = S7Plc::start(None).await?;
    // Every connection passes the COTP connect and Setup Communication, then closes at the
    // first read.
    let cable = Cable::failing_after(plc.port, Some(2)).await?;
    let gw = guest("s7-guest-storm", cable.port).await?;
    let started = Instant::now();
    iogate_tests::eventually("five connections", || async { cable.accepted() >= 5 }).await?;
    // 0.25 + 0.5 + 1 + 2 s of back-off at least between the five; a back-off that restarts
    // at each open makes them in about a second.
    let took = started.elapsed();
    assert!(
        took >= Duration::from_millis(3500),
        "5 connections in {took:?}"
    );
    assert!(cable.open() <= 1, "{} open at once", cable.open());
    let (_, d) = gw.get("/api/v1/devices/guest").await?;
    assert_eq!(field(&d, "Mb5")["quality"], "bad", "{d}");
    gw.shutdown().await;
    iogate_tests::eventually("nothing left open on the PLC", || async {
        cable.open() == 0
    })
    .await?;
    plc.kill().await
}
