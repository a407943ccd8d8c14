//! The outputs a device is written again when it is back: its newest requested values, in
//! the log as replays, except one another master changed since.

use super::*;

#[tokio::test]
async fn outputs_written_again_after_the_device_returns_are_in_the_log_as_replays() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "replay",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, timeout: 50ms, retries: 0 }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    let g = put(&gw, "/api/v1/devices/io/fields/DO_5", json!(true)).await;
    assert_eq!(outcome(&gw, g).await["status"], "written");

    // The device goes silent, loses its memory, and answers again.
    bus.slave(1, |s| {
        s.behaviour = iogate_tests::devices::Behaviour::Silent
    });
    gw.until("/api/v1/devices/io", "disconnected", |b| {
        b["connected"] == false
    })
    .await
    .expect("lost");
    bus.slave(1, |s| {
        s.tables = Default::default();
        s.behaviour = iogate_tests::devices::Behaviour::Normal;
    });
    let field = gw
        .until("/api/v1/devices/io/fields/DO_5", "replayed", |b| {
            b["last_write"]["origin"] == "replay" && b["last_write"]["status"] == "written"
        })
        .await
        .expect("replay recorded");
    assert!(
        field["last_write"]["generation"].as_u64() > Some(g),
        "{field}"
    );
    assert_eq!(bus.read_slave(1, |s| s.tables.coils[5]), Some(true));
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn an_output_another_master_changed_is_not_written_again_when_the_device_returns() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "replay-other",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, timeout: 50ms, retries: 0 }\n",
    )
    .await;
    let (_, device) = gw.get("/api/v1/devices/io").await.expect("device");
    assert_eq!(
        device["rewrite_outputs"], "on_reconnect",
        "Modbus's default"
    );
    let g = put(&gw, "/api/v1/devices/io/fields/DO_5", json!(true)).await;
    assert_eq!(outcome(&gw, g).await["status"], "written");

    // Another master switches it off, and the gateway reads it so.
    bus.slave(1, |s| s.tables.coils[5] = false);
    gw.until("/api/v1/devices/io/fields/DO_5", "read off", |b| {
        b["value"] == false && b["quality"] == "good"
    })
    .await
    .expect("read");
    // The device goes silent and answers again: the other master's value stays.
    bus.slave(1, |s| {
        s.behaviour = iogate_tests::devices::Behaviour::Silent
    });
    gw.until("/api/v1/devices/io", "disconnected", |b| {
        b["connected"] == false
    })
    .await
    .expect("lost");
    bus.slave(1, |s| {
        s.behaviour = iogate_tests::devices::Behaviour::Normal;
    });
    let field = gw
        .until("/api/v1/devices/io/fields/DO_5", "left", |b| {
            b["last_write"]["origin"] == "replay" && b["last_write"]["status"] == "superseded"
        })
        .await
        .expect("the rule in the log");
    let why = field["last_write"]["error"].as_str().unwrap_or_default();
    assert!(
        why.contains("holding FALSE") && why.contains("someone else"),
        "{field}"
    );
    let (_, now) = gw.get("/api/v1/devices/io").await.expect("device");
    let cycles = now["io_cycles"].as_u64().unwrap_or_default();
    gw.until("/api/v1/devices/io", "read again", |b| {
        b["io_cycles"].as_u64().unwrap_or_default() >= cycles + 3
    })
    .await
    .expect("read");
    assert_eq!(bus.read_slave(1, |s| s.tables.coils[5]), Some(false));
    gw.shutdown().await;
    task.abort();
}
