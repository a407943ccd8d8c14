//! The OPC UA server under subscription load, in its own process (`iogate serve`):
//! 100 simulated devices of 100 UINT outputs, every field written once a second (one REST
//! PATCH per device), and
//!
//! 1. one session monitoring all 10,000 fields;
//! 2. 50 sessions monitoring 100 fields each (one device each);
//! 3. no session at all, beside the same gateway without its `opcua:` section (what an
//!    OPC UA server nobody uses costs).
//!
//! For each: notifications received against changes made, change-to-client latency (from
//! the value's SourceTimestamp, when the simulated device took it, to its arrival at the
//! client; both clocks are this machine's) p50 / p99, the gateway's CPU (share of one core)
//! and resident memory; and the part of the latency before the OPC UA server took the
//! change (its ServerTimestamp: the device, the cache and the address space's feed). The
//! client is async-opcua's (publishing interval 0: the server's shortest, 10 ms; sampling
//! interval 0).
//!
//! `cargo bench -p iogate --bench opcua`
#![allow(clippy::too_many_lines)]

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use opcua::client::{ClientBuilder, DataChangeCallback, IdentityToken, Session};
use opcua::crypto::SecurityPolicy;
use opcua::types::{
    DataValue, MessageSecurityMode, MonitoredItemCreateRequest, NodeId, TimestampsToReturn,
    UserTokenPolicy,
};

mod common;

const DEVICES: usize = 100;
const FIELDS: usize = 100;
const RUN: Duration = Duration::from_secs(10);

/// Latencies in ms seen by the clients' callbacks: from the source timestamp to the
/// client, and the part of it before the OPC UA server took the change (its server
/// timestamp).
type Seen = Arc<Mutex<Vec<(f64, f64)>>>;

async fn session(url: &str, seen: Seen, nodes: Vec<NodeId>) -> anyhow::Result<Arc<Session>> {
    let mut client = ClientBuilder::new()
        .application_name("iogate bench")
        .application_uri("urn:iogate:bench")
        .trust_server_certs(true)
        .create_sample_keypair(false)
        .session_retry_limit(1)
        // Arrays past async-opcua's default 1,000, for a server that answers with more
        // notifications at once (`max_notifications_per_publish`).
        .max_array_length(100_000)
        .client()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let (session, event_loop) = client
        .connect_to_matching_endpoint(
            (
                url,
                SecurityPolicy::None.to_str(),
                MessageSecurityMode::None,
                UserTokenPolicy::anonymous(),
            ),
            IdentityToken::Anonymous,
        )
        .await
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    event_loop.spawn();
    session.wait_for_connection().await;
    let sub = session
        .create_subscription(
            // The server's shortest.
            Duration::ZERO,
            300,
            30,
            0,
            0,
            true,
            DataChangeCallback::new(move |dv: DataValue, _item| {
                if let (Some(source), Some(server)) = (dv.source_timestamp, dv.server_timestamp) {
                    let now = opcua::types::DateTime::now();
                    let ms = (now.as_chrono() - source.as_chrono()).num_microseconds();
                    let door = (server.as_chrono() - source.as_chrono()).num_microseconds();
                    if let (Some(us), Some(door), Ok(mut seen)) = (ms, door, seen.lock()) {
                        seen.push((us as f64 / 1000.0, door as f64 / 1000.0));
                    }
                }
            }),
        )
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    for chunk in nodes.chunks(500) {
        let items: Vec<MonitoredItemCreateRequest> =
            chunk.iter().map(|n| n.clone().into()).collect();
        session
            .create_monitored_items(sub, TimestampsToReturn::Both, items)
            .await
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    Ok(session)
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

struct Row {
    name: &'static str,
    expected: usize,
    received: usize,
    p50: f64,
    p99: f64,
    /// Source to the server's timestamp (the gateway before its OPC UA server).
    door_p50: f64,
    door_p99: f64,
    cpu: f64,
    rss_mib: f64,
}

async fn scenario(
    name: &'static str,
    gw: &common::Gateway,
    url: &str,
    ns: u16,
    sessions: usize,
    devices_per_session: usize,
) -> anyhow::Result<Row> {
    let seen: Seen = Arc::default();
    let mut opened = Vec::new();
    for s in 0..sessions {
        let nodes: Vec<NodeId> = (0..devices_per_session)
            .flat_map(|d| {
                let device = s * devices_per_session + d;
                (0..FIELDS).map(move |f| NodeId::new(ns, format!("d{device}.F{f}")))
            })
            .collect();
        opened.push(session(url, seen.clone(), nodes).await?);
    }
    let monitored_devices = sessions * devices_per_session;
    // The initial values, then writes once a second.
    tokio::time::sleep(Duration::from_secs(2)).await;
    seen.lock().map_err(|_| anyhow::anyhow!("lock"))?.clear();
    let mut patchers = Vec::new();
    for _ in 0..4 {
        patchers.push(common::http::Kept::connect(gw.http).await?);
    }
    let pid = gw.child.id();
    let cpu0 = common::cpu_seconds(pid);
    let started = Instant::now();
    let mut rounds = 0;
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    while started.elapsed() < RUN {
        tick.tick().await;
        rounds += 1;
        let mut sends = Vec::new();
        for (p, patcher) in patchers.iter_mut().enumerate() {
            let bodies: Vec<(String, String)> = (0..DEVICES)
                .filter(|d| d % 4 == p)
                .map(|d| {
                    let body: Vec<String> = (0..FIELDS)
                        .map(|f| format!("\"F{f}\": {}", (rounds * 7 + f + d) % 60000))
                        .collect();
                    (
                        format!("/api/v1/devices/d{d}/fields"),
                        format!("{{{}}}", body.join(",")),
                    )
                })
                .collect();
            sends.push(async move {
                for (path, body) in bodies {
                    patcher.send("PATCH", &path, &body).await?;
                }
                anyhow::Ok(())
            });
        }
        for r in futures_util::future::join_all(sends).await {
            r?;
        }
    }
    let elapsed = started.elapsed().as_secs_f64();
    tokio::time::sleep(Duration::from_secs(1)).await;
    let cpu = (common::cpu_seconds(pid) - cpu0) / elapsed;
    let rss_mib = common::rss_kib(pid) as f64 / 1024.0;
    let seen = seen.lock().map_err(|_| anyhow::anyhow!("lock"))?.clone();
    let mut latencies: Vec<f64> = seen.iter().map(|s| s.0).collect();
    latencies.sort_by(f64::total_cmp);
    let mut door: Vec<f64> = seen.iter().map(|s| s.1).collect();
    door.sort_by(f64::total_cmp);
    for s in opened {
        let _ = s.disconnect().await;
    }
    Ok(Row {
        name,
        expected: rounds * monitored_devices * FIELDS,
        received: latencies.len(),
        p50: percentile(&latencies, 0.5),
        p99: percentile(&latencies, 0.99),
        door_p50: percentile(&door, 0.5),
        door_p99: percentile(&door, 0.99),
        cpu,
        rss_mib,
    })
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let dir = common::temp_dir("opcua")?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Wide\nprotocol: simulated\nfields:\n");
    for f in 0..FIELDS {
        profile.push_str(&format!(
            "  - {{ name: F{f}, type: UINT, direction: output, register: {{ address: {f}, kind: virtual }} }}\n"
        ));
    }
    std::fs::write(profiles.join("wide.yaml"), profile)?;
    let port = common::free_port()?;
    let mut config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nopcua: {{ listen: 127.0.0.1:{port}, security: [none], pki_dir: {} }}\ndevices:\n",
        profiles.display(),
        dir.join("pki").display()
    );
    for d in 0..DEVICES {
        config.push_str(&format!(
            "  - {{ name: d{d}, profile: Wide, refresh_rate: 100ms }}\n"
        ));
    }
    let gw = common::start(&dir, &config)?;
    let plain_dir = common::temp_dir("opcua-plain")?;
    let plain_config = config.replace(
        &format!(
            "opcua: {{ listen: 127.0.0.1:{port}, security: [none], pki_dir: {} }}\n",
            dir.join("pki").display()
        ),
        "",
    );
    let plain = common::start(&plain_dir, &plain_config)?;
    let url = format!("opc.tcp://127.0.0.1:{port}/");
    // The same with ten thousand notifications allowed in a publish answer.
    let wide_dir = common::temp_dir("opcua-wide")?;
    let wide_port = common::free_port()?;
    let wide = common::start(
        &wide_dir,
        &config.replace(
            &format!("listen: 127.0.0.1:{port},"),
            &format!("listen: 127.0.0.1:{wide_port}, max_notifications_per_publish: 10000,"),
        ),
    )?;
    let wide_url = format!("opc.tcp://127.0.0.1:{wide_port}/");
    // The namespace index: the server's namespace array is [UA, application, iogate].
    let ns = 2;
    let idle_rss = common::rss_kib(gw.child.id()) as f64 / 1024.0;
    let rows = [
        scenario("no session, opcua: configured", &gw, &url, ns, 0, 0).await?,
        scenario("the same without opcua:", &plain, &url, ns, 0, 0).await?,
        scenario("1 session x 10,000 items", &gw, &url, ns, 1, DEVICES).await?,
        scenario("50 sessions x 100 items", &gw, &url, ns, 50, 1).await?,
        scenario(
            "1 session x 10,000 items, max_notifications_per_publish: 10000",
            &wide,
            &wide_url,
            ns,
            1,
            DEVICES,
        )
        .await?,
    ];
    drop(plain);
    drop(wide);
    // Against the same server under the same load with no session (the allocator's growth
    // under the load is not the items').
    let per_item = (rows[2].rss_mib - rows[0].rss_mib) * 1024.0 / (DEVICES * FIELDS) as f64;
    println!(
        "OPC UA subscriptions: {DEVICES} simulated devices x {FIELDS} UINT outputs written once a second; {} s per row; gateway RSS before any session {idle_rss:.1} MiB",
        RUN.as_secs()
    );
    println!(
        "| load | changes | notifications | latency p50 | latency p99 | of which to the server's timestamp p50 / p99 | gateway CPU | gateway RSS |"
    );
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    println!(
        "gateway memory per monitored item (RSS with 10,000 items over RSS with no session, same load): {per_item:.2} KiB"
    );
    for r in rows {
        println!(
            "| {} | {} | {} | {:.1} ms | {:.1} ms | {:.1} / {:.1} ms | {:.1} % | {:.1} MiB |",
            r.name,
            r.expected,
            r.received,
            r.p50,
            r.p99,
            r.door_p50,
            r.door_p99,
            r.cpu * 100.0,
            r.rss_mib
        );
    }
    Ok(())
}
