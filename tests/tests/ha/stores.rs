//! The pair with its lease on a store instead of the broker: etcd (Debian's etcd-server)
//! and a Kubernetes Lease (a Lease API server written from the API's conventions, with
//! its bearer token). Mosquitto carries the handover beside it. Each arbiter is reached by
//! each node through a tap of its own: the active is cut from the store but not from the
//! field nor the broker, stands down before the standby takes over, and comes back as the
//! standby; then the new active is killed, and the first takes over again, with the
//! records of the writes handed over.

use std::time::{Duration, Instant};

use iogate_tests::arbiters::{Etcd, KubeApi};
use iogate_tests::mqtt::Broker;
use iogate_tests::tap::Tap;

use super::pair::{Node, Pair, Writer};

const LEASE_S: u64 = 3;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn on_etcd_a_cut_active_stands_down_first_and_a_killed_one_is_replaced() {
    let etcd = Etcd::start().await.expect("etcd");
    cut_then_kill("ha-etcd", etcd.port, |port| {
        format!("arbiter: etcd, etcd: {{ endpoints: [\"http://127.0.0.1:{port}\"] }}")
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn on_a_kubernetes_lease_a_cut_active_stands_down_first_and_a_killed_one_is_replaced() {
    let api = KubeApi::start().await.expect("the Lease API");
    let token = iogate_tests::devices::temp_dir("ha-kube-token").join("token");
    std::fs::write(&token, format!("{}\n", api.token)).expect("token");
    let token = token.display().to_string();
    cut_then_kill("ha-kube", api.port, move |port| {
        format!(
            "arbiter: kubernetes, kubernetes: {{ api: \"http://127.0.0.1:{port}\", namespace: plant, token_file: \"{token}\" }}"
        )
    })
    .await;
}

async fn cut_then_kill(name: &str, store: u16, arbiter: impl Fn(u16) -> String) {
    let broker = Broker::start().await.expect("broker");
    let taps = [
        Tap::start(store).await.expect("tap"),
        Tap::start(store).await.expect("tap"),
    ];
    let ports = [taps[0].port, taps[1].port];
    let mut pair = Pair::start_with(name, [broker.port; 2], LEASE_S, |n| {
        arbiter(ports[n.index()])
    })
    .await
    .expect("pair");
    let writer = Writer::start(&pair);
    writer.until_written(Node::A, 30).await;
    let epoch = pair.ha(Node::A).await["epoch"].as_u64().expect("epoch");
    taps[0].cut();
    let cut = Instant::now();
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
    // The store frees the lease a lease after the last renewal; the standby reads it every
    // quarter lease. Two leases is the goal measured without load: two gateways, the
    // store and the other tests share two cores here, so 2 s of scheduling on top.
    assert!(
        b_up < Duration::from_secs(2 * LEASE_S + 2),
        "took over in {b_up:?}"
    );
    let ha = pair.ha(Node::B).await;
    assert_eq!(ha["epoch"].as_u64(), Some(epoch + 1), "{ha}");
    writer.until_written(Node::B, 30).await;
    taps[0].restore();
    pair.until_ha(Node::A, "a standby seeing b active", |ha| {
        ha["role"] == "standby" && ha["active"]["node"] == "b"
    })
    .await;
    let killed = Instant::now();
    pair.kill(Node::B).await;
    let ha = pair.until_active(Node::A).await;
    let takeover = killed.elapsed();
    assert!(
        takeover < Duration::from_secs(2 * LEASE_S + 2),
        "took over in {takeover:?}"
    );
    assert_eq!(ha["epoch"].as_u64(), Some(epoch + 2), "{ha}");
    writer.until_written(Node::A, 30).await;
    let log = writer.stop().await;
    let handed = pair.assert_handed_over(&log, Node::B, killed).await;
    assert!(handed >= 20, "only {handed} of node b's writes handed over");
    eprintln!(
        "{name}: cut: a stood down {a_down:?}, b took over {b_up:?}; kill -9: a took over {takeover:?}; {} written",
        log.written().len()
    );
    pair.field.assert_one_master_at_a_time();
    pair.field.assert_written_once(&log);
    pair.field.assert_only_asked(&log);
}

/// Someone else removes the holder from the store while the active holds it (deletes
/// etcd's holder key; empties the Lease's holder): the active finds its record gone at its
/// next renewal and stands down; the standby does not take a lease whose holder may still
/// be active. Never two active at once, one field master at a time.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_holder_removed_by_someone_else_is_not_two_masters() {
    let etcd = Etcd::start().await.expect("etcd");
    let url = format!("http://127.0.0.1:{}", etcd.port);
    let arbiter = |_| format!("arbiter: etcd, etcd: {{ endpoints: [\"{url}\"] }}");
    let delete = || async {
        let key = base64::Engine::encode(
            &base64::engine::general_purpose::STANDARD,
            "iogate/ha/iogate/holder",
        );
        reqwest::Client::new()
            .post(format!("{url}/v3/kv/deleterange"))
            .body(serde_json::json!({ "key": key }).to_string())
            .send()
            .await
            .expect("etcd")
            .error_for_status()
            .expect("deleted");
    };
    tampered("ha-etcd-tamper", arbiter, delete).await;

    let api = KubeApi::start().await.expect("the Lease API");
    let token = iogate_tests::devices::temp_dir("ha-kube-tamper-token").join("token");
    std::fs::write(&token, format!("{}\n", api.token)).expect("token");
    let (base, bearer) = (format!("http://127.0.0.1:{}", api.port), api.token.clone());
    let file = token.display().to_string();
    let arbiter = |_| {
        format!(
            "arbiter: kubernetes, kubernetes: {{ api: \"{base}\", namespace: plant, token_file: \"{file}\" }}"
        )
    };
    let empty = || async {
        let path =
            format!("{base}/apis/coordination.k8s.io/v1/namespaces/plant/leases/iogate-iogate");
        let client = reqwest::Client::new();
        let mut lease: serde_json::Value = client
            .get(&path)
            .bearer_auth(&bearer)
            .send()
            .await
            .expect("GET")
            .json()
            .await
            .expect("a Lease");
        lease["spec"]["holderIdentity"] = serde_json::Value::Null;
        let status = client
            .put(&path)
            .bearer_auth(&bearer)
            .body(lease.to_string())
            .send()
            .await
            .expect("PUT")
            .status();
        assert!(status.is_success(), "{status}");
    };
    tampered("ha-kube-tamper", arbiter, empty).await;
}

async fn tampered<F: std::future::Future<Output = ()>>(
    name: &str,
    arbiter: impl Fn(Node) -> String,
    tamper: impl Fn() -> F,
) {
    let broker = Broker::start().await.expect("broker");
    let pair = Pair::start_with(name, [broker.port; 2], LEASE_S, arbiter)
        .await
        .expect("pair");
    let writer = Writer::start(&pair);
    writer.until_written(Node::A, 20).await;
    tamper().await;
    let since = Instant::now();
    let mut actives = std::collections::BTreeSet::new();
    while since.elapsed() < Duration::from_secs(2 * LEASE_S + 2) {
        let (a, b) = (pair.ha(Node::A).await, pair.ha(Node::B).await);
        let both = a["role"] == "active" && b["role"] == "active";
        assert!(
            !both,
            "{name}: two active {:?} after: {a} {b}",
            since.elapsed()
        );
        for (node, ha) in [("a", &a), ("b", &b)] {
            if ha["role"] == "active" {
                actives.insert((node, ha["epoch"].as_u64()));
            }
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let active = |n| pair.ha(n);
    let (a, b) = (active(Node::A).await, active(Node::B).await);
    assert!(
        (a["role"] == "active") != (b["role"] == "active"),
        "{name}: one active in the end: {a} {b}"
    );
    eprintln!("{name}: active after the tamper: {actives:?}");
    let log = writer.stop().await;
    pair.field.assert_one_master_at_a_time_or_one(&log);
}
