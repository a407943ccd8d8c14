//! The OPC UA server against what clients found (asyncua, Python, as the independent peer):
//! names that could collide, browse paths, every session's monitored items bounded together,
//! diagnostics and links that follow the gateway.

mod gone;
mod strangers;

use iogate_tests::devices::temp_dir;
use iogate_tests::opcua::{Options, UaClient};
use iogate_tests::{TestGateway, eventually};
use reqwest::Method;
use serde_json::json;

fn opcua(dir: &std::path::Path, extra: &str) -> String {
    format!(
        "opcua:\n  listen: 127.0.0.1:0\n  pki_dir: {}\n{extra}",
        dir.join("pki").display()
    )
}

fn url(gw: &TestGateway) -> String {
    format!("opc.tcp://{}/", gw.opcua.expect("an OPC UA server"))
}

/// The demo's plant (SimPlant) behind an OPC UA server with `extra` keys, in `name`'s dir.
async fn plant(name: &str, extra: &str) -> (TestGateway, std::path::PathBuf) {
    let dir = temp_dir(name);
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: plant, profile: SimPlant, refresh_rate: 100ms }}\n{}",
        opcua(&dir, extra)
    ))
    .await
    .expect("gateway");
    (gw, dir)
}

/// A simulated device (SimIo, every 100 ms) declared at run time as `name`.
async fn declare_sim(gw: &TestGateway, name: &str) {
    let (status, body) = gw
        .send(
            Method::PUT,
            &format!("/api/v1/devices/{name}"),
            json!({"profile": "SimIo", "refresh_rate_ms": 100}).to_string(),
        )
        .await
        .expect("declare");
    assert_eq!(status, 201, "{name}: {body}");
}

/// An asyncua client of its own, anonymous.
async fn client(gw: &TestGateway) -> UaClient {
    UaClient::connect(&url(gw), &Options::default())
        .await
        .expect("asyncua connects")
}

#[tokio::test]
async fn a_dotted_device_name_never_takes_another_devices_node() {
    let (gw, _) = plant("opcua-dots", "").await;
    let mut ua = client(&gw).await;
    let level = ua.read("plant.Level").await.expect("read");
    assert_eq!(level["type"], "Float", "{level}");
    // A device named `plant.Level` beside it: its own object, its own fields.
    declare_sim(&gw, "plant.Level").await;
    eventually("the dotted device browsed", || async {
        ua_children(&url(&gw), "Devices/plant.Level")
            .await
            .is_some_and(|c| c.contains("DI_0"))
    })
    .await
    .expect("browsed");
    assert_eq!(
        ua.read("plant.Level").await.expect("read")["type"],
        "Float",
        "plant's Level is still plant's Level"
    );
    assert_eq!(
        ua.read("plant.Level.DI_0").await.expect("read")["type"],
        "Boolean"
    );
    // Removing the dotted device removes its nodes only.
    let (status, _) = gw
        .send(Method::DELETE, "/api/v1/devices/plant.Level", "")
        .await
        .expect("remove");
    assert!((200..300).contains(&status));
    eventually("the dotted device gone", || async {
        ua_children(&url(&gw), "/iogate/Devices")
            .await
            .is_some_and(|c| !c.contains("plant.Level"))
    })
    .await
    .expect("gone");
    let level = ua.read("plant.Level").await.expect("read");
    assert_eq!(level["status"], "Good", "{level}");
    // Browse paths name nodes in the gateway's namespace, as clients write them.
    let ns = ua.ns;
    let found = ua
        .cmd(json!({"cmd": "path", "path": [
            format!("{ns}:iogate"), format!("{ns}:Devices"), format!("{ns}:plant"), format!("{ns}:Level")
        ]}))
        .await
        .expect("path");
    assert_eq!(found["id"], "plant.Level", "{found}");
    let found = ua
        .cmd(json!({"cmd": "path", "path": [
            format!("{ns}:iogate"), format!("{ns}:Devices"), format!("{ns}:plant"),
            format!("{ns}:Diagnostics"), format!("{ns}:io_cycles")
        ]}))
        .await
        .expect("path");
    assert_eq!(found["id"], "Diagnostics/plant/io_cycles", "{found}");
    gw.shutdown().await;
}

/// The names of a node's children, by a client of its own.
async fn ua_children(url: &str, node: &str) -> Option<String> {
    let mut ua = UaClient::connect(url, &Options::default()).await.ok()?;
    let children = ua.cmd(json!({"cmd": "browse", "node": node})).await.ok()?;
    Some(children.to_string())
}

#[tokio::test]
async fn monitored_items_are_bounded_for_every_session_together() {
    let (gw, _) = plant("opcua-items", "  max_monitored_items: 2500\n").await;
    let mut first = client(&gw).await;
    let mut second = client(&gw).await;
    let one = first
        .cmd(json!({"cmd": "monitor_many", "node": "plant.Level", "count": 2000}))
        .await
        .expect("items");
    assert_eq!(one["good"], 2000, "{one}");
    let two = second
        .cmd(json!({"cmd": "monitor_many", "node": "plant.Level", "count": 2000}))
        .await
        .expect("items");
    assert_eq!(two["good"], 500, "{two}");
    assert_eq!(two["refused"]["BadTooManyMonitoredItems"], 1500, "{two}");
    let metrics = gw.metrics().await.expect("metrics");
    for line in [
        "iogate_opcua_monitored_items 2500",
        "iogate_opcua_monitored_items_refused_total 1500",
        "iogate_bound_limit{bound=\"opcua_monitored_items\"} 2500",
        "iogate_bound_used{bound=\"opcua_monitored_items\"} 2500",
        "iogate_bound_refused_total{bound=\"opcua_monitored_items\"} 1500",
    ] {
        assert!(metrics.contains(line), "{line}\n{metrics}");
    }
    // A session that goes gives its places back.
    first.close().await.expect("closed");
    eventually("the first session's items released", || async {
        gw.metrics()
            .await
            .is_ok_and(|m| m.contains("iogate_opcua_monitored_items 500\n"))
    })
    .await
    .expect("released");
    let again = second
        .cmd(json!({"cmd": "monitor_many", "node": "plant.Level", "count": 1000}))
        .await
        .expect("items");
    assert_eq!(again["good"], 1000, "{again}");
    gw.shutdown().await;
}

#[tokio::test]
async fn diagnostics_count_on_and_links_follow_declarations() {
    let dir = temp_dir("opcua-diagnostics");
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: plant, profile: SimPlant, refresh_rate: 50ms }}\n{}",
        opcua(&dir, "")
    ))
    .await
    .expect("gateway");
    let mut ua = client(&gw).await;
    let cycles = |v: &serde_json::Value| v["value"].as_u64().unwrap_or(0);
    let before = cycles(&ua.read("Diagnostics/plant/io_cycles").await.expect("read"));
    let deadline = tokio::time::Instant::now() + iogate_tests::PATIENCE;
    while cycles(&ua.read("Diagnostics/plant/io_cycles").await.expect("read")) <= before {
        assert!(
            tokio::time::Instant::now() < deadline,
            "io_cycles never counts on"
        );
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }
    // Monitored, it is told as it counts.
    ua.cmd(json!({"cmd": "subscribe", "nodes": ["Diagnostics/plant/io_cycles"], "interval": 50}))
        .await
        .expect("subscribe");
    let mut told = Vec::new();
    while told.len() < 3 {
        let changes = ua
            .cmd(json!({"cmd": "changes", "wait": 5}))
            .await
            .expect("changes");
        told.extend(
            changes["changes"]
                .as_array()
                .cloned()
                .unwrap_or_default()
                .iter()
                .map(cycles),
        );
        assert!(
            !changes["changes"].as_array().is_none_or(|c| c.is_empty()),
            "{told:?}"
        );
    }
    assert!(told.windows(2).all(|w| w[0] < w[1]), "{told:?}");
    // A link declared at run time appears in the Links folder, and goes.
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/links/far",
            json!({"tcp": {"host": "127.0.0.1", "port": 9}}).to_string(),
        )
        .await
        .expect("declare a link");
    assert!((200..300).contains(&status), "{body}");
    eventually("the link browsed", || async {
        ua_children(&url(&gw), "/iogate/Links")
            .await
            .is_some_and(|c| c.contains("/Links/far"))
    })
    .await
    .expect("link shown");
    let (status, body) = gw
        .send(Method::DELETE, "/api/v1/links/far", "")
        .await
        .expect("remove the link");
    assert!((200..300).contains(&status), "{body}");
    eventually("the link gone", || async {
        ua_children(&url(&gw), "/iogate/Links")
            .await
            .is_some_and(|c| !c.contains("/Links/far"))
    })
    .await
    .expect("link gone");
    gw.shutdown().await;
}

#[tokio::test]
async fn opcua_sessions_past_the_bound_are_refused_and_counted() {
    let (gw, _) = plant("opcua-sessions", "  max_sessions: 2\n").await;
    let mut first = client(&gw).await;
    let mut second = client(&gw).await;
    let third = UaClient::connect(&url(&gw), &Options::default()).await;
    let refused = third.err().map(|e| format!("{e:#}")).unwrap_or_default();
    assert!(refused.contains("TooManySessions"), "{refused}");
    // The sessions in place are served as before.
    for ua in [&mut first, &mut second] {
        assert_eq!(
            ua.read("plant.Level").await.expect("read")["status"],
            "Good"
        );
    }
    let metrics = gw.metrics().await.expect("metrics");
    for line in [
        "iogate_bound_limit{bound=\"opcua_sessions\"} 2\n",
        "iogate_bound_used{bound=\"opcua_sessions\"} 2\n",
        "iogate_bound_refused_total{bound=\"opcua_sessions\"} 1\n",
        // Two sessions of ten subscriptions each, none made by plain reads.
        "iogate_bound_limit{bound=\"opcua_subscriptions\"} 20\n",
        "iogate_bound_used{bound=\"opcua_subscriptions\"} 0\n",
    ] {
        assert!(metrics.contains(line), "{line}\n{metrics}");
    }
    first.close().await.expect("closed");
    let mut again = client(&gw).await;
    assert_eq!(
        again.read("plant.Level").await.expect("read")["status"],
        "Good"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn the_advertised_operation_limits_are_the_ones_kept() {
    let (gw, dir) = plant("opcua-limits", "").await;
    let mut ua = client(&gw).await;
    // Server_ServerCapabilities_OperationLimits_MaxNodesPerRead (Part 5).
    let advertised = ua
        .cmd(json!({"cmd": "read0", "id": 11705}))
        .await
        .expect("MaxNodesPerRead");
    let max = advertised["value"].as_u64().expect("a number");
    let at = ua
        .cmd(json!({"cmd": "read_many", "node": "plant.Level", "count": max}))
        .await
        .expect("read");
    assert_eq!(at, json!({"status": "Good", "results": max}));
    let past = ua
        .cmd(json!({"cmd": "read_many", "node": "plant.Level", "count": max + 1}))
        .await
        .expect("read");
    assert_eq!(past["status"], "BadTooManyOperations", "{past}");
    // The session goes on.
    assert_eq!(
        ua.read("plant.Level").await.expect("read")["status"],
        "Good"
    );
    // The key the server made is its user's alone.
    use std::os::unix::fs::PermissionsExt;
    let private = dir.join("pki/private");
    let mode =
        |p: &std::path::Path| std::fs::metadata(p).expect("stat").permissions().mode() & 0o777;
    assert_eq!(mode(&private), 0o700);
    let keys: Vec<_> = std::fs::read_dir(&private)
        .expect("private")
        .filter_map(Result::ok)
        .map(|e| e.path())
        .collect();
    assert!(!keys.is_empty());
    for key in keys {
        assert_eq!(mode(&key), 0o600, "{}", key.display());
    }
    gw.shutdown().await;
}

#[tokio::test]
async fn an_event_item_is_told_events_and_never_a_data_value() {
    let (gw, _) = plant("opcua-event-item", "").await;
    let mut ua = client(&gw).await;
    ua.cmd(json!({"cmd": "subscribe_events", "type": "GeneralModelChangeEventType"}))
        .await
        .expect("events");
    declare_sim(&gw, "extra").await;
    // Everything the event item is told, up to the model change event.
    let mut seen: Vec<serde_json::Value> = Vec::new();
    while !seen.iter().any(|c| c["event"] == 2133) {
        let changes = ua
            .cmd(json!({"cmd": "changes", "wait": 5}))
            .await
            .expect("changes");
        let batch = changes["changes"].as_array().cloned().unwrap_or_default();
        assert!(!batch.is_empty(), "no event came: {seen:?}");
        seen.extend(batch);
    }
    assert!(
        seen.iter().all(|c| c.get("node").is_none()),
        "a data value on an event item: {seen:?}"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn security_refusals_are_each_counted() {
    let dir = temp_dir("opcua-refusals");
    let tokens = dir.join("tokens");
    std::fs::write(&tokens, "read reader-0123456789abcdef\n").expect("tokens");
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: plant, profile: SimPlant, refresh_rate: 100ms }}\nsecurity: {{ tokens_file: {} }}\n{}",
        tokens.display(),
        opcua(&dir, "")
    ))
    .await
    .expect("gateway");
    let count = |m: &str| -> u64 {
        m.lines()
            .find_map(|l| l.strip_prefix("iogate_opcua_security_rejected_total "))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(0)
    };
    let before = count(&gw.metrics().await.expect("metrics"));
    // Two refusals: no token at all (anonymous), and a token the gateway does not know.
    let anonymous = iogate_tests::opcua::refused(&url(&gw), &Options::default())
        .await
        .expect("anonymous refused");
    assert!(anonymous.contains("Bad"), "{anonymous}");
    let wrong = Options {
        user: Some(("token".into(), "not-a-token-at-all".into())),
        ..Options::default()
    };
    iogate_tests::opcua::refused(&url(&gw), &wrong)
        .await
        .expect("unknown token refused");
    let after = count(&gw.metrics().await.expect("metrics"));
    assert_eq!(after - before, 2, "each refusal counted once");
    gw.shutdown().await;
}

/// The sizes of the data change messages that bring 8,000 items' first values on one node
/// to asyncua, with the server's `extra` keys.
async fn first_values_in_messages(name: &str, extra: &str) -> Vec<u64> {
    let (gw, _) = plant(name, extra).await;
    let mut ua = client(&gw).await;
    let many = ua
        .cmd(json!({"cmd": "monitor_many", "node": "plant.Level", "count": 8000}))
        .await
        .expect("items");
    assert_eq!(many["good"], 8000, "{many}");
    let mut sizes: Vec<u64> = Vec::new();
    let deadline = tokio::time::Instant::now() + iogate_tests::PATIENCE;
    while sizes.iter().sum::<u64>() < 8000 {
        assert!(
            tokio::time::Instant::now() < deadline,
            "the first values not delivered: {sizes:?}"
        );
        let seen = ua
            .cmd(json!({"cmd": "message_sizes"}))
            .await
            .expect("sizes");
        let got = seen["sizes"].as_array().cloned().unwrap_or_default();
        sizes.extend(got.iter().filter_map(|n| n.as_u64()));
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    }
    gw.shutdown().await;
    sizes
}

#[tokio::test]
async fn a_burst_of_changes_is_answered_in_messages_within_the_count_and_the_size() {
    // By default a thousand notifications an answer, what async-opcua's clients decode.
    let sizes = first_values_in_messages("opcua-burst", "").await;
    assert_eq!(sizes.iter().copied().max(), Some(1000), "{sizes:?}");
    // With more allowed, an answer is closed by its size: 8,000 values of about 30 bytes
    // each as encoded (240 KB) go in two answers, not one past the 160 KiB.
    let sizes = first_values_in_messages(
        "opcua-burst-more",
        "  max_notifications_per_publish: 20000\n",
    )
    .await;
    let largest = sizes.iter().copied().max().unwrap_or(0);
    assert!(largest > 1000, "answers of at most {largest}: {sizes:?}");
    assert!(
        largest < 8000,
        "one answer carried the whole burst: {sizes:?}"
    );
}
