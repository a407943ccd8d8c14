//! A standing write's `state` as source document 002 names it, through a run on a real
//! (pseudo-terminal) line to a slow slave: 1 waiting for the link, 2 the link taken, 3 on
//! the line, then 4.

use std::time::Duration;

use iogate_tests::TestGateway;
use iogate_tests::devices::{Behaviour, RtuBus, pty_at, temp_dir};

#[tokio::test]
async fn a_standing_write_shows_each_state_of_its_run() {
    let bus = RtuBus::default();
    bus.slave(17, |s| {
        s.behaviour = Behaviour::Slow(Duration::from_millis(400))
    });
    let dir = temp_dir("tx-states");
    let port = dir.join("ttyTX");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: 115200 }} }}\n\
         transactions:\n  - {{ name: setpoint, link: rs485, function: 6, slave: 17, address: 1, type: uint16, byte_order: Big-endian, values: [7], timeout_ms: 1000, polling_period: 0s, enabled: false }}\n",
        port.display()
    ))
    .await
    .expect("gateway");
    let (_, before) = gw.get("/api/v1/transactions/setpoint").await.expect("get");
    assert_eq!(before["state"], 0, "not active: {before}");
    let (status, body) = gw
        .send(
            reqwest::Method::POST,
            "/api/v1/transactions/setpoint/enable",
            "",
        )
        .await
        .expect("enable");
    assert!((200..300).contains(&status), "{body}");
    // Every state seen while the slave takes 400 ms to answer, then the end.
    let mut seen: Vec<i64> = Vec::new();
    let deadline = tokio::time::Instant::now() + iogate_tests::PATIENCE;
    while seen.last() != Some(&4) {
        assert!(tokio::time::Instant::now() < deadline, "{seen:?}");
        let (_, t) = gw.get("/api/v1/transactions/setpoint").await.expect("get");
        let state = t["state"].as_i64().expect("state");
        if seen.last() != Some(&state) {
            seen.push(state);
        }
    }
    assert!(
        seen.contains(&3),
        "on the line while the slave answers: {seen:?}"
    );
    assert!(seen.iter().all(|s| [0, 1, 2, 3, 4].contains(s)), "{seen:?}");
    assert!(
        seen.windows(2).all(|w| w[0] < w[1] || w[0] == 0),
        "in order: {seen:?}"
    );
    gw.shutdown().await;
    task.abort();
}
