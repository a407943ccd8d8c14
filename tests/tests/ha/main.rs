//! Two gateway processes, one plant: an active/standby pair (`ha:`) with Mosquitto as the
//! arbiter, and as the field tokio-modbus's Modbus TCP server and pymodbus speaking RTU over
//! TCP, each behind a tap that logs every connection (`field.rs`). A client writes about a hundred times a second to whichever
//! node is active; the active is killed (`kill -9`), cut from the broker but not from the
//! field, and cut again and again. Each time: one node takes over within two leases, every
//! write the gateways said was written is on the field once, nothing is written that was
//! not asked for, and two field connections are never open at once.

mod bench;
mod field;
mod pair;
mod stores;

use std::time::{Duration, Instant};

use iogate_client::{Client, Value};
use serde_json::json;

use iogate_tests::mqtt::{Broker, Message, Peer};
use iogate_tests::opcua::{Options, UaClient};
use iogate_tests::tap::Tap;
use pair::{Node, Pair, Writer};

const LEASE_S: u64 = 3;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_killed_active_is_replaced_within_two_leases_and_every_written_value_is_on_the_field_once()
 {
    let broker = Broker::start().await.expect("broker");
    // A Sparkplug host's view (paho, pysparkplug): one edge node for the pair.
    let mut host = Peer::subscribe(&broker, "spBv1.0/plant/+/pair")
        .await
        .expect("paho");
    let mut pair = Pair::start("ha-kill", [broker.port, broker.port], LEASE_S)
        .await
        .expect("pair");
    // An OPC UA client on each node (asyncua): the pair as Part 4's non-transparent
    // redundancy says it.
    let mut ua = [
        UaClient::connect(&pair.opcua(Node::A).await, &Options::default())
            .await
            .expect("ua a"),
        UaClient::connect(&pair.opcua(Node::B).await, &Options::default())
            .await
            .expect("ua b"),
    ];
    for (node, level) in [(0, 255), (1, 1)] {
        assert_eq!(
            ua[node]
                .read_absolute("i=2267")
                .await
                .expect("ServiceLevel")["value"],
            level
        );
        assert_eq!(
            ua[node]
                .read_absolute("i=3709")
                .await
                .expect("RedundancySupport")["value"],
            2,
            "Warm"
        );
    }
    let uris = ua[1]
        .read_absolute("i=11314")
        .await
        .expect("ServerUriArray")["value"]
        .clone();
    // asyncua's list, as text: both nodes' application URIs.
    let uris = uris.to_string();
    assert!(
        uris.contains("urn:iogate:a") && uris.contains("urn:iogate:b"),
        "{uris}"
    );
    let born = host
        .until(|m| m.topic == "spBv1.0/plant/NBIRTH/pair")
        .await
        .expect("NBIRTH of node a");
    let born_with = bd_seq(&born);
    // Declared on the active, handed to the standby: a link (nothing answers at its port,
    // so it adds no field connection) and a device on it.
    pair.declare(
        Node::A,
        "/api/v1/links/spare",
        json!({"tcp": {"host": "127.0.0.1", "port": 1}}),
    )
    .await;
    let device =
        json!({"profile": "Setpoints", "link": "spare", "slave_id": 2, "refresh_rate_ms": 500});
    pair.declare(Node::A, "/api/v1/devices/pump2", device).await;
    pair.until_path(
        Node::B,
        "/api/v1/devices/pump2",
        "the declared device on the standby",
    )
    .await;
    // The remote runtime's client, given both nodes, talks to the active. Its writes go
    // to the declared device, whose link is down: accepted, they fail, and touch no field.
    let urls = [pair.grpc(Node::A).await, pair.grpc(Node::B).await];
    let mut runtime = Client::connect_pair(&urls)
        .await
        .expect("the pair's client");
    assert_eq!(runtime.ha().await.expect("ha").node, "a");
    let before = runtime
        .write("pump2", "sp", Value::UInt(7))
        .await
        .expect("write on a");
    let writer = Writer::start(&pair);
    writer.until_written(Node::A, 50).await;
    let epoch = pair.ha(Node::A).await["epoch"].as_u64().expect("epoch");
    let killed = Instant::now();
    pair.kill(Node::A).await;
    let ha = pair.until_active(Node::B).await;
    let takeover = killed.elapsed();
    assert!(
        takeover < Duration::from_secs(2 * LEASE_S),
        "took over in {takeover:?}"
    );
    assert_eq!(ha["epoch"].as_u64(), Some(epoch + 1), "{ha}");
    // Prometheus sees the role and the takeover.
    let metrics = iogate_tests::TestGateway::remote(pair.bases[1].clone())
        .metrics()
        .await
        .expect("metrics");
    for line in [
        "iogate_ha_role{role=\"active\"} 1",
        "iogate_ha_role{role=\"standby\"} 0",
        "iogate_ha_takeovers_total 1",
    ] {
        assert!(metrics.contains(line), "{line} in {metrics}");
    }
    let [_, ua_b] = &mut ua;
    assert_eq!(
        ua_b.read_absolute("i=2267").await.expect("ServiceLevel")["value"],
        255
    );
    // The runtime's client follows the takeover: its next write goes to node b, and the
    // write node a took is found there.
    let after = runtime
        .write("pump2", "sp", Value::UInt(8))
        .await
        .expect("write after the takeover");
    assert_eq!(runtime.ha().await.expect("ha").node, "b");
    assert!(after > before, "{after} after {before}");
    let status = runtime
        .write_status(before)
        .await
        .expect("the old write on b");
    assert_eq!(
        (status.generation, status.device.as_str(), status.value),
        (before, "pump2", Some(Value::UInt(7)))
    );
    // The edge node dies (node a's Will) and is born again from node b with the next bdSeq.
    let death = host
        .until(|m| m.topic == "spBv1.0/plant/NDEATH/pair")
        .await
        .expect("NDEATH");
    assert_eq!(bd_seq(&death), born_with);
    let reborn = host
        .until(|m| m.topic == "spBv1.0/plant/NBIRTH/pair")
        .await
        .expect("NBIRTH of node b");
    assert_eq!(
        bd_seq(&reborn),
        (born_with + 1) % 256,
        "{:?}",
        reborn.sparkplug
    );
    writer.until_written(Node::B, 50).await;
    pair.until_path(
        Node::B,
        "/api/v1/links/spare",
        "the declared link on the new active",
    )
    .await;
    let log = writer.stop().await;
    // Handed over: every write node a said was written, followed on node b, is written
    // there too, with its value.
    let on_a = pair.assert_handed_over(&log, Node::A, killed).await;
    eprintln!(
        "takeover after kill -9: {takeover:?}; {} writes asked, {} written, {} of node a's found on node b",
        log.asked(),
        log.written().len(),
        on_a
    );
    pair.field.assert_one_master_at_a_time();
    pair.field.assert_written_once(&log);
    pair.field.assert_only_asked(&log);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_active_cut_from_the_broker_stops_before_the_standby_starts() {
    let broker = Broker::start().await.expect("broker");
    let tap_a = Tap::start(broker.port).await.expect("tap");
    let pair = Pair::start("ha-cut", [tap_a.port, broker.port], LEASE_S)
        .await
        .expect("pair");
    let writer = Writer::start(&pair);
    writer.until_written(Node::A, 30).await;
    tap_a.cut();
    let cut = Instant::now();
    // Both nodes watched every 20 ms: the old active says standby before the new says
    // active.
    let (mut a_down, mut b_up) = (None, None);
    while b_up.is_none() {
        if a_down.is_none() && pair.ha(Node::A).await["role"] == "standby" {
            a_down = Some(cut.elapsed());
        }
        if pair.ha(Node::B).await["role"] == "active" {
            b_up = Some(cut.elapsed());
        }
        assert!(cut.elapsed() < iogate_tests::PATIENCE, "no takeover");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (a_down, b_up) = (a_down.expect("a stood down first"), b_up.expect("b"));
    assert!(
        a_down < b_up,
        "a stood down at {a_down:?}, b took over at {b_up:?}"
    );
    // A silent loss is bounded by the broker: it drops the lock 1.5 keep-alives after the
    // last packet, counted in whole seconds (at most 4 s for a 3 s lease), then the new
    // holder settles (0.5 s). Two leases is the goal measured without load; here two
    // gateways, the broker and the other tests share two cores, so the bound is that worst
    // case with 2 s of scheduling on top.
    assert!(
        b_up < Duration::from_secs(2 * LEASE_S + 2),
        "took over in {b_up:?}"
    );
    writer.until_written(Node::B, 30).await;
    tap_a.restore();
    // Back on the broker, a finds b holding the lease and stays standby.
    pair.until_ha(Node::A, "a standby seeing b active", |ha| {
        ha["role"] == "standby" && ha["active"]["node"] == "b"
    })
    .await;
    assert_eq!(pair.ha(Node::B).await["role"], "active");
    let log = writer.stop().await;
    eprintln!(
        "partition: a stood down {a_down:?} and b took over {b_up:?} after the cut; {} written",
        log.written().len()
    );
    pair.field.assert_one_master_at_a_time();
    pair.field.assert_written_once(&log);
    pair.field.assert_only_asked(&log);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn twenty_cuts_and_restores_never_make_two_masters() {
    const LEASE: u64 = 2;
    let broker = Broker::start().await.expect("broker");
    let taps = [
        Tap::start(broker.port).await.expect("tap"),
        Tap::start(broker.port).await.expect("tap"),
    ];
    let pair = Pair::start("ha-flap", [taps[0].port, taps[1].port], LEASE)
        .await
        .expect("pair");
    let writer = Writer::start(&pair);
    let mut active = Node::A;
    let mut takeovers = Vec::new();
    for _ in 0..20 {
        writer.until_written(active, 5).await;
        let tap = &taps[active.index()];
        tap.cut();
        let cut = Instant::now();
        let next = active.other();
        pair.until_active(next).await;
        takeovers.push(cut.elapsed());
        tap.restore();
        pair.until_ha(active, "the old active standing by", |ha| {
            ha["role"] == "standby" && ha["active"]["node"] == next.name()
        })
        .await;
        active = next;
    }
    let log = writer.stop().await;
    takeovers.sort();
    eprintln!(
        "20 partitions, lease {LEASE} s: takeover p50 {:?}, max {:?}; {} written",
        takeovers[takeovers.len() / 2],
        takeovers[takeovers.len() - 1],
        log.written().len()
    );
    pair.field.assert_one_master_at_a_time();
    pair.field.assert_written_once(&log);
    pair.field.assert_only_asked(&log);
}

/// The `bdSeq` metric of a Sparkplug NBIRTH or NDEATH.
fn bd_seq(m: &Message) -> u64 {
    m.sparkplug["metrics"]
        .as_array()
        .and_then(|ms| ms.iter().find(|x| x["name"] == "bdSeq"))
        .and_then(|x| x["value"].as_u64())
        .unwrap_or_else(|| panic!("no bdSeq in {:?}", m.sparkplug))
}
