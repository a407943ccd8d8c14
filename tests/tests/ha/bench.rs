//! The pair measured: takeover time over 50 kills of the active (p50, p99), and what a
//! standby costs (CPU over ten seconds, resident memory) while the active polls and
//! writes. A benchmark, not a test: `cargo test -p iogate-tests --release --test ha --
//! --ignored --nocapture`.

use std::time::{Duration, Instant};

use std::sync::{Arc, Mutex};

use iogate_tests::mqtt::{Broker, Peer};

use super::pair::{Node, Pair, Writer};

/// CPU seconds (user + system) and resident KiB of process `pid`.
fn usage(pid: u32) -> (f64, u64) {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    // Fields after the command's closing parenthesis: utime and stime are the 12th and 13th.
    let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let fields: Vec<&str> = after.split_whitespace().collect();
    let ticks: f64 = fields[11..13]
        .iter()
        .filter_map(|f| f.parse::<f64>().ok())
        .sum();
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let rss = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next()?.parse().ok())
        .unwrap_or(0);
    (ticks / 100.0, rss)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "a benchmark: run with --ignored --nocapture"]
async fn takeover_over_fifty_kills_and_the_cost_of_a_standby() {
    let broker = Broker::start().await.expect("broker");
    let mut pair = Pair::start("ha-bench", [broker.port, broker.port], 3)
        .await
        .expect("pair");
    let standby = pair.pid(Node::B);
    let share = |pid| async move {
        let (cpu0, _) = usage(pid);
        let started = Instant::now();
        tokio::time::sleep(Duration::from_secs(10)).await;
        let (cpu1, rss) = usage(pid);
        ((cpu1 - cpu0) / started.elapsed().as_secs_f64() * 100.0, rss)
    };
    let (idle, rss) = share(standby).await;
    let (_, active_rss) = usage(pair.pid(Node::A));
    eprintln!(
        "standby, no writes: {idle:.3} % of a core over 10 s, {rss} KiB resident (the active: {active_rss} KiB)"
    );
    let writer = Writer::start(&pair);
    writer.until_written(Node::A, 20).await;
    let (busy, rss) = share(standby).await;
    eprintln!(
        "standby, the active writing ~100/s: {busy:.3} % of a core over 10 s, {rss} KiB resident"
    );
    let _ = writer.stop().await;
    missed_over_kills(&broker, &mut pair, 10).await;
    let mut takeovers = Vec::new();
    let mut active = Node::A;
    for _ in 0..50 {
        let killed = Instant::now();
        pair.kill(active).await;
        pair.until_active(active.other()).await;
        takeovers.push(killed.elapsed());
        pair.restart(active).await;
        active = active.other();
    }
    takeovers.sort();
    let at = |q: f64| takeovers[((takeovers.len() as f64 * q).ceil() as usize).saturating_sub(1)];
    eprintln!(
        "takeover over {} kills (lease 3 s): p50 {:?}, p99 {:?}, max {:?}",
        takeovers.len(),
        at(0.5),
        at(0.99),
        takeovers[takeovers.len() - 1]
    );
    assert!(at(0.99) < Duration::from_secs(6), "p99 {:?}", at(0.99));
}

/// Values a subscriber misses over `kills` takeovers: the field's level counts up every
/// 100 ms (the gateway polls it every 20 ms, so a subscriber sees each value while a node
/// is active); a paho subscriber of its JSON topic notes each value it gets. Per kill: the
/// values between the last seen before it and the first seen after, and that blind time.
async fn missed_over_kills(broker: &Broker, pair: &mut Pair, kills: usize) {
    let tables = pair.field.device.tables.clone();
    let ticker = tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_millis(100));
        loop {
            tick.tick().await;
            let mut t = tables.lock().unwrap_or_else(|e| e.into_inner());
            t.holding[11] = t.holding[11].wrapping_add(1);
        }
    });
    let mut peer = Peer::subscribe(broker, "plant/#").await.expect("paho");
    let seen: Arc<Mutex<Vec<(Instant, u64)>>> = Arc::default();
    let noted = seen.clone();
    let reader = tokio::spawn(async move {
        while let Ok(m) = peer.next().await {
            if m.topic.contains("pump")
                && m.topic.ends_with("level")
                && let Some(v) = m.json()["value"].as_u64()
            {
                noted
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push((Instant::now(), v));
            }
        }
    });
    let (mut missed, mut blind) = (Vec::new(), Vec::new());
    let mut active = if pair.ha(Node::A).await["role"] == "active" {
        Node::A
    } else {
        Node::B
    };
    for _ in 0..kills {
        tokio::time::sleep(Duration::from_millis(1500)).await;
        let killed = Instant::now();
        pair.kill(active).await;
        pair.until_active(active.other()).await;
        tokio::time::sleep(Duration::from_millis(1500)).await;
        let seen = seen.lock().unwrap_or_else(|e| e.into_inner()).clone();
        let before = seen.iter().rev().find(|(t, _)| *t < killed).copied();
        let after = seen
            .iter()
            .find(|(t, v)| *t > killed && before.is_none_or(|(_, b)| v > &b))
            .copied();
        if let (Some((t0, v0)), Some((t1, v1))) = (before, after) {
            missed.push(v1 - v0 - 1);
            blind.push(t1 - t0);
        }
        pair.restart(active).await;
        active = active.other();
    }
    ticker.abort();
    reader.abort();
    missed.sort_unstable();
    blind.sort();
    eprintln!(
        "a subscriber over {} kills, the level changing every 100 ms: missed p50 {} values, max {}; blind p50 {:?}, max {:?}",
        missed.len(),
        missed.get(missed.len() / 2).copied().unwrap_or_default(),
        missed.last().copied().unwrap_or_default(),
        blind.get(blind.len() / 2).copied().unwrap_or_default(),
        blind.last().copied().unwrap_or_default(),
    );
    assert_eq!(
        missed.len(),
        kills,
        "a value seen before and after each kill"
    );
}
