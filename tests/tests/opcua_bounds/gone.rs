//! What goes from the OPC UA server when its owner does: a vanished client's subscriptions
//! and items, a removed device's variables (told so to the items that monitored them).

use super::*;

/// A subscription asked for (interval in ms, lifetime and keep-alive counts), with `count`
/// items on `node`: what the server revised, and how many items it took.
async fn subscription(
    ua: &mut UaClient,
    (interval, lifetime, keepalive): (f64, u32, u32),
    node: &str,
    count: usize,
) -> serde_json::Value {
    ua.cmd(
        json!({"cmd": "subscription", "interval": interval, "lifetime": lifetime,
                  "keepalive": keepalive, "node": node, "count": count}),
    )
    .await
    .expect("subscription")
}

#[tokio::test]
async fn a_vanished_clients_subscriptions_end_within_their_lifetime_and_free_their_items() {
    let (gw, _) = plant("opcua-lifetime", "  subscription_lifetime: 2s\n").await;
    let mut ua = client(&gw).await;
    // asyncua's own defaults would keep it for hours: 10,000 intervals of 100 ms.
    let made = subscription(&mut ua, (100.0, 10000, 3000), "plant.Level", 20).await;
    assert_eq!(made["interval"], 100.0, "{made}");
    let (lifetime, keepalive) = (
        made["lifetime"].as_u64().unwrap_or(u64::MAX),
        made["keepalive"].as_u64().unwrap_or(u64::MAX),
    );
    assert!(lifetime <= 20, "2 s of 100 ms intervals at most: {made}");
    assert!(keepalive >= 1 && lifetime >= 3 * keepalive, "{made}");
    assert_eq!(made["good"], 20, "{made}");
    // An interval that would outlive any count: a third of the lifetime at most. A Value
    // item on an object (which has none) is refused, its place given back.
    let long = subscription(&mut ua, (1e300, 10, 3), "Devices/plant", 1).await;
    let interval = long["interval"].as_f64().unwrap_or(f64::INFINITY);
    let lifetime = long["lifetime"].as_f64().unwrap_or(f64::INFINITY);
    assert!(interval * lifetime <= 2000.0 + 1e-6, "{long}");
    assert_eq!(long["good"], 0, "{long}");
    let metrics = gw.metrics().await.expect("metrics");
    for line in [
        "iogate_opcua_subscriptions 2\n",
        "iogate_opcua_monitored_items 20\n",
    ] {
        assert!(metrics.contains(line), "{line}{metrics}");
    }
    // Killed: no CloseSession, no publish request ever again.
    drop(ua);
    eventually(
        "the vanished client's subscription and items gone",
        || async {
            gw.metrics().await.is_ok_and(|m| {
                m.contains("iogate_opcua_subscriptions 0\n")
                    && m.contains("iogate_opcua_monitored_items 0\n")
            })
        },
    )
    .await
    .expect("freed within the lifetime");
    gw.shutdown().await;
}

#[tokio::test]
async fn a_removed_devices_fields_and_diagnostics_are_told_gone() {
    let (gw, _) = plant("opcua-gone", "").await;
    declare_sim(&gw, "extra").await;
    let mut ua = client(&gw).await;
    let watched = [
        "extra.DI_0",
        "Diagnostics/extra/connected",
        "Diagnostics/extra/error_code",
        "Diagnostics/extra/io_cycles",
        "Diagnostics/extra/last_response_ms",
    ];
    eventually("the declared device shown", || async {
        ua_children(&url(&gw), "/iogate/Devices")
            .await
            .is_some_and(|c| c.contains("Devices/extra"))
    })
    .await
    .expect("shown");
    let subscribed = ua
        .cmd(json!({"cmd": "subscribe", "nodes": watched, "interval": 50}))
        .await
        .expect("subscribe");
    assert_eq!(subscribed["subscribed"], watched.len(), "{subscribed}");
    let (status, body) = gw
        .send(Method::DELETE, "/api/v1/devices/extra", "")
        .await
        .expect("remove");
    assert!((200..300).contains(&status), "{body}");
    let mut gone = std::collections::BTreeSet::new();
    let deadline = tokio::time::Instant::now() + iogate_tests::PATIENCE;
    while gone.len() < watched.len() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "told gone: {gone:?}"
        );
        let changes = ua
            .cmd(json!({"cmd": "changes", "wait": 5}))
            .await
            .expect("changes");
        for change in changes["changes"].as_array().into_iter().flatten() {
            if change["status"] == "BadNodeIdUnknown" {
                gone.insert(change["node"].as_str().unwrap_or_default().to_owned());
            }
        }
    }
    assert_eq!(
        gone,
        watched.iter().map(|w| w.to_string()).collect(),
        "every item on the device"
    );
    gw.shutdown().await;
}
