//! The built-in demo's pages in a real headless Chromium: the overview a newcomer first
//! sees (the demo's field line with its meter and I/O module, the servers and how to reach
//! them) and a link's page with its poll plan. The overview's screenshot at desktop width is
//! written to `target/ui-screenshots/demo-overview.png` (the README's picture).

use std::time::Duration;

use iogate_tests::TestGateway;
use iogate_tests::browser::{Browser, screenshots_dir};

#[tokio::test]
async fn the_demos_overview_shows_its_field_line_and_how_to_reach_every_server()
-> anyhow::Result<()> {
    let gw = TestGateway::demo_as_shipped().await?;
    gw.all_read("meter").await?;
    let browser = Browser::start(1280, 1000).await?;
    browser.goto(&gw.url("/")).await?;
    for device in ["sim", "plant", "meter", "io"] {
        browser
            .until_text(
                &format!("tr[data-device='{device}']"),
                Duration::from_secs(10),
                |t| t.contains("connected") && !t.contains("disconnected"),
            )
            .await?;
    }
    let link = browser
        .until_text("tr[data-link='field']", Duration::from_secs(10), |t| {
            t.contains("connected") && t.contains("% measured")
        })
        .await?;
    assert!(link.contains("127.0.0.1:"), "{link}");

    let (_, config) = gw.get("/api/v1/config").await?;
    let listening = config["listening"].as_array().cloned().unwrap_or_default();
    let mut servers: Vec<&str> = listening
        .iter()
        .filter_map(|l| l["server"].as_str())
        .collect();
    servers.sort_unstable();
    assert_eq!(servers, ["grpc", "http", "modbus", "opcua"], "{config}");
    for listener in &listening {
        let server = listener["server"].as_str().unwrap_or_default();
        let address = listener["address"].as_str().unwrap_or_default();
        let row = browser
            .text(&format!("#servers tr[data-server='{server}']"))
            .await?;
        assert!(row.contains(address), "{server}: {row}");
    }
    let opcua = gw.opcua.expect("the demo serves OPC UA");
    let row = browser.text("#servers tr[data-server='opcua']").await?;
    assert!(row.contains(&format!("opc.tcp://{opcua}/")), "{row}");
    let row = browser.text("#servers tr[data-server='modbus']").await?;
    assert!(row.contains("iogate map"), "{row}");
    let order = browser
        .run(
            "return [...document.querySelectorAll('#servers tr')].map((r) => r.dataset.server)",
            serde_json::json!([]),
        )
        .await?;
    assert_eq!(
        order,
        serde_json::json!(["http", "grpc", "modbus", "opcua"])
    );
    browser
        .screenshot(&screenshots_dir().join("demo-overview.png"))
        .await?;

    // The link's page: its poll plan, as `iogate plan` prints it.
    browser.goto(&gw.url("/ui#/links/field")).await?;
    let plan = browser
        .until_text("main", Duration::from_secs(10), |t| {
            t.contains("device meter (profile EastronSDM630")
        })
        .await?;
    assert!(
        plan.contains("device io (profile WaveshareIo8, slave 2"),
        "{plan}"
    );
    gw.shutdown().await;
    Ok(())
}
