use super::*;

#[tokio::test]
async fn a_request_whose_caller_is_gone_or_late_is_never_sent() {
    use iogate::cache::{Passthrough, PassthroughError};
    use iogate::link::frame::Request;
    use std::time::Duration;
    use tokio::time::Instant;
    let bus = RtuBus::default();
    bus.slave(3, |_| {});
    let on = on_bus("tx-gone", &bus, "").await;
    let link = on
        .gw
        .service()
        .expect("service")
        .cache
        .link("rs485")
        .expect("link");
    let read = |address| Request::ReadHoldingRegisters { address, count: 1 };
    // The caller gave up (its receiver is dropped) before the link reached it.
    let (gone, receiver) = tokio::sync::oneshot::channel();
    drop(receiver);
    link.submit(Passthrough {
        slave: 3,
        request: read(10),
        timeout: Duration::from_millis(100),
        deadline: Instant::now() + Duration::from_secs(5),
        reply: gone,
        stage: None,
    });
    // A deadline the slave's timeout would pass: answered, not sent.
    let (late, late_answer) = tokio::sync::oneshot::channel();
    link.submit(Passthrough {
        slave: 3,
        request: read(11),
        timeout: Duration::from_millis(100),
        deadline: Instant::now() + Duration::from_millis(50),
        reply: late,
        stage: None,
    });
    // And one that is sent.
    let (fine, fine_answer) = tokio::sync::oneshot::channel();
    link.submit(Passthrough {
        slave: 3,
        request: read(12),
        timeout: Duration::from_millis(100),
        deadline: Instant::now() + Duration::from_secs(5),
        reply: fine,
        stage: None,
    });
    assert!(matches!(
        late_answer.await.expect("answered"),
        Err(PassthroughError::Expired)
    ));
    assert!(fine_answer.await.expect("answered").is_ok());
    let sent: Vec<u16> = bus
        .seen()
        .into_iter()
        .filter(|s| s.slave == 3)
        .map(|s| s.address)
        .collect();
    assert_eq!(sent, vec![12], "only the request with a caller was sent");
    // A full inbox answers busy at once.
    let mut answers = Vec::new();
    for k in 0..(iogate::cache::INBOX_CAPACITY as u16 + 4) {
        let (reply, answer) = tokio::sync::oneshot::channel();
        link.submit(Passthrough {
            slave: 3,
            request: read(100 + k),
            timeout: Duration::from_millis(100),
            deadline: Instant::now() + Duration::from_secs(5),
            reply,
            stage: None,
        });
        answers.push(answer);
    }
    let mut busy = 0;
    for answer in answers {
        if matches!(answer.await.expect("answered"), Err(PassthroughError::Busy)) {
            busy += 1;
        }
    }
    assert!(busy >= 3, "{busy} answered busy");
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn a_write_of_period_zero_runs_when_enabled_and_when_given_values() {
    let bus = RtuBus::default();
    bus.slave(17, |_| {});
    let on = on_bus(
        "tx-write-zero",
        &bus,
        "transactions:\n  - { name: once, link: rs485, function: 6, slave: 17, address: 1, type: uint16, byte_order: Big-endian, values: [5], timeout_ms: 100, enabled: false }\n",
    )
    .await;
    let gw = &on.gw;
    let (status, _) = gw
        .send(Method::POST, "/api/v1/transactions/once/enable", "")
        .await
        .expect("enable");
    assert_eq!(status, 200);
    gw.until("/api/v1/transactions/once", "sent when enabled", |b| {
        b["runs"] == 1 && b["state"] == 4
    })
    .await
    .expect("one run");
    assert_eq!(bus.read_slave(17, |s| s.tables.holding[1]), Some(5));
    gw.send(
        Method::PUT,
        "/api/v1/transactions/once/values",
        json!({"values": [6]}).to_string(),
    )
    .await
    .expect("values");
    gw.until(
        "/api/v1/transactions/once",
        "sent with its new values",
        |b| b["runs"] == 2,
    )
    .await
    .expect("a second run");
    assert_eq!(bus.read_slave(17, |s| s.tables.holding[1]), Some(6));
    on.gw.shutdown().await;
    on.task.abort();
}
