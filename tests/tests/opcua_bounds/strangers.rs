//! What strangers can make the OPC UA server hold: sessions never activated and the
//! connections they came on, and browse continuation points never released.

use super::*;

#[tokio::test]
async fn sessions_never_activated_cannot_keep_a_client_out() {
    let dir = temp_dir("opcua-unactivated");
    let tokens = dir.join("tokens");
    std::fs::write(&tokens, "read reader-0123456789abcdef\n").expect("tokens");
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: plant, profile: SimPlant, refresh_rate: 100ms }}\nsecurity: {{ tokens_file: {} }}\n{}",
        tokens.display(),
        opcua(&dir, "  max_sessions: 10\n")
    ))
    .await
    .expect("gateway");
    // Ten sessions created and left: the whole table.
    iogate_tests::opcua::install().expect("asyncua");
    let mut command = tokio::process::Command::new(iogate_tests::python());
    command
        .arg(iogate_tests::repo_file("opcua/unactivated.py"))
        .arg(url(&gw))
        .arg("10");
    let mut squatter = iogate_tests::spawn_piped(command).expect("unactivated.py");
    let line = squatter
        .lines
        .next_line()
        .await
        .expect("answer")
        .expect("a line");
    let created: serde_json::Value = serde_json::from_str(&line).expect("json");
    assert_eq!(created["created"], 10, "{created}");
    // A real client with a token gets in at once (the oldest unactivated session gives way).
    let reader = Options {
        user: Some(("token".into(), "reader-0123456789abcdef".into())),
        ..Options::default()
    };
    let mut ua = UaClient::connect(&url(&gw), &reader)
        .await
        .expect("a real client is not locked out");
    assert_eq!(
        ua.read("plant.Level").await.expect("read")["status"],
        "Good"
    );
    ua.close().await.expect("closed");
    drop(squatter);
    gw.shutdown().await;
}

#[tokio::test]
async fn connections_whose_sessions_are_never_activated_are_closed_with_them() {
    let dir = temp_dir("opcua-unactivated-connections");
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: plant, profile: SimPlant, refresh_rate: 100ms }}\n{}",
        opcua(&dir, "  max_connections_per_client: 4\n")
    ))
    .await
    .expect("gateway");
    // Four secure channels with a session each, never activated, kept open: every place
    // this address has.
    iogate_tests::opcua::install().expect("asyncua");
    let mut command = tokio::process::Command::new(iogate_tests::python());
    command
        .arg(iogate_tests::repo_file("opcua/unactivated.py"))
        .arg(url(&gw))
        .arg("4");
    let started = std::time::Instant::now();
    let mut squatter = iogate_tests::spawn_piped(command).expect("unactivated.py");
    let line = squatter
        .lines
        .next_line()
        .await
        .expect("answer")
        .expect("a line");
    let created: serde_json::Value = serde_json::from_str(&line).expect("json");
    assert_eq!(created["created"], 4, "{created}");
    // The gateway closes them (the squatter still holds its end), so a real client from
    // the same address gets in.
    eventually(
        "the connections without an activated session closed",
        || async {
            gw.metrics().await.is_ok_and(|m| {
                m.contains("iogate_bound_used{bound=\"opcua_connections_per_client\"} 0\n")
            })
        },
    )
    .await
    .expect("closed");
    println!(
        "unactivated connections closed after {:?}",
        started.elapsed()
    );
    let mut ua = client(&gw).await;
    assert_eq!(
        ua.read("plant.Level").await.expect("read")["status"],
        "Good"
    );
    ua.close().await.expect("closed");
    drop(squatter);
    gw.shutdown().await;
}

#[tokio::test]
async fn browse_continuation_points_are_bounded_per_session_and_for_the_whole_gateway() {
    let (gw, _dir) = plant(
        "opcua-browse-points",
        "  max_sessions: 100\n  max_connections_per_client: 100\n",
    )
    .await;
    iogate_tests::opcua::install().expect("asyncua");
    // 60 sessions each asking for 100 points (6,000): the gateway keeps the newest 5,000,
    // the first session's first point released to make room.
    let mut command = tokio::process::Command::new(iogate_tests::python());
    command
        .arg(iogate_tests::repo_file("opcua/browse_points.py"))
        .arg(url(&gw))
        .arg("60")
        .arg("100");
    let mut holder = iogate_tests::spawn_piped(command).expect("browse_points.py");
    let line = tokio::time::timeout(iogate_tests::PATIENCE, holder.lines.next_line())
        .await
        .expect("in time")
        .expect("answer")
        .expect("a line");
    let got: serde_json::Value = serde_json::from_str(&line).expect("json");
    assert_eq!(got["held"], 6_000, "{got}");
    assert_eq!(got["refused"], 0, "{got}");
    assert_eq!(got["first"], "BadContinuationPointInvalid", "{got}");
    // One session asking past its own 100: the rest refused, its first point kept.
    let mut command = tokio::process::Command::new(iogate_tests::python());
    command
        .arg(iogate_tests::repo_file("opcua/browse_points.py"))
        .arg(url(&gw))
        .arg("1")
        .arg("300");
    let mut one = iogate_tests::spawn_piped(command).expect("browse_points.py");
    let line = tokio::time::timeout(iogate_tests::PATIENCE, one.lines.next_line())
        .await
        .expect("in time")
        .expect("answer")
        .expect("a line");
    let got: serde_json::Value = serde_json::from_str(&line).expect("json");
    assert_eq!(
        (got["held"].as_u64(), got["refused"].as_u64()),
        (Some(100), Some(200)),
        "{got}"
    );
    assert_eq!(got["first"], "Good", "{got}");
    drop((one, holder));
    gw.shutdown().await;
}

#[tokio::test]
async fn a_read_with_a_range_that_does_not_parse_refuses_that_item_only() {
    let (gw, _) = plant("opcua-index-range", "").await;
    iogate_tests::opcua::install().expect("asyncua");
    // Three items of one Read: a range that is no range, a scalar read whole, a range on a
    // scalar. asyncua sends the range's text as it is given.
    let script = r#"
import asyncio, json, sys
from asyncua import Client, ua
async def main(url):
    async with Client(url) as c:
        ns = await c.get_namespace_index("urn:iogate:devices")
        items = []
        for node, rng in [("plant.Level", "x:y"), ("plant.Level", None), ("plant.Level", "0:1")]:
            rv = ua.ReadValueId()
            rv.NodeId = ua.NodeId(node, ns)
            rv.AttributeId = ua.AttributeIds.Value
            rv.IndexRange = rng
            items.append(rv)
        params = ua.ReadParameters()
        params.NodesToRead = items
        got = await c.uaclient.read(params)
        print(json.dumps([d.StatusCode_.name if hasattr(d, "StatusCode_") else d.StatusCode.name for d in got]))
asyncio.run(main(sys.argv[1]))
"#;
    let out = tokio::process::Command::new(iogate_tests::python())
        .args(["-c", script, &url(&gw)])
        .output()
        .await
        .expect("python");
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let statuses: Vec<String> = serde_json::from_str(said.trim()).expect("json");
    assert_eq!(statuses[0], "BadIndexRangeInvalid", "{statuses:?}");
    assert_eq!(statuses[1], "Good", "{statuses:?}");
    assert!(statuses[2].starts_with("Bad"), "{statuses:?}");
    gw.shutdown().await;
}
