//! The OPC UA client driver under load: an OPC UA server (async-opcua's, in a process of
//! its own: this program again) with 10,000 and then 100,000 Double variables, every one
//! changed once a second, read by `iogate serve` (its own process) on one link as ten
//! devices of a tenth each (a subscription each, publishing every second, then every 100 ms;
//! each variable sampled every 100 ms).
//!
//! For each size: changes seen against changes made and the change-to-subscriber latency
//! (from the value's SourceTimestamp, set by the server as it changed it, to a gRPC
//! subscriber of 1,000 fields spread over the devices; the cache and the gRPC stream
//! together, so an upper bound of the cache's part) p50 / p99; the gateway's CPU (share of
//! one core) and resident memory, beside the figures NG Gateway and NeuronEX publish for
//! 100,000 OPC UA points at 1 s.
//!
//! `cargo bench -p iogate --bench opcua_client`

use std::time::{Duration, Instant, SystemTime};

use futures_util::StreamExt;

mod common;

/// Variables, and the devices' refresh rate (the subscriptions' publishing interval).
const RUNS: [(usize, u64); 3] = [(10_000, 1000), (100_000, 1000), (10_000, 100)];
const DEVICES: usize = 10;
const SAMPLED: usize = 1_000;
const WARM_UP: Duration = Duration::from_secs(4);
const RUN: Duration = Duration::from_secs(20);
const SERVER_ENV: &str = "IOGATE_BENCH_UA_SERVER";

fn main() -> anyhow::Result<()> {
    if let Ok(spec) = std::env::var(SERVER_ENV) {
        return server::run(&spec);
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let mut rows = Vec::new();
    for (n, refresh_ms) in RUNS {
        rows.extend(runtime.block_on(measure(n, refresh_ms))?);
    }
    common::print_table(&rows);
    Ok(())
}

/// The server process for `n` variables on `port`; killed when dropped.
struct Server(std::process::Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_server(n: usize, port: u16) -> anyhow::Result<Server> {
    use std::io::BufRead;
    let mut child = std::process::Command::new(std::env::current_exe()?)
        .env(SERVER_ENV, format!("{n}:{port}"))
        .stdout(std::process::Stdio::piped())
        .spawn()?;
    let stdout = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
    let mut lines = std::io::BufReader::new(stdout).lines();
    let first = lines.next().transpose()?.unwrap_or_default();
    anyhow::ensure!(first == "ready", "the OPC UA server said {first:?}");
    Ok(Server(child))
}

/// The profiles (one a device, a tenth of the variables each) and the config.
fn config(dir: &std::path::Path, n: usize, port: u16, refresh_ms: u64) -> anyhow::Result<String> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let per = n / DEVICES;
    let mut devices = String::new();
    for d in 0..DEVICES {
        let mut text = format!("name: Bench{d}\nprotocol: opcua\nfields:\n");
        for i in d * per..(d + 1) * per {
            text.push_str(&format!(
                "  - {{ name: v{i}, type: LREAL, direction: input, node: \"ns=2;i={i}\", sampling_interval: 100ms }}\n"
            ));
        }
        std::fs::write(profiles.join(format!("bench{d}.yaml")), text)?;
        devices.push_str(&format!(
            "  - {{ name: d{d}, profile: Bench{d}, link: ua, refresh_rate: {refresh_ms}ms }}\n"
        ));
    }
    Ok(format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - name: ua\n    opcua: {{ url: \"opc.tcp://127.0.0.1:{port}/\", pki_dir: {} }}\ndevices:\n{devices}",
        profiles.display(),
        dir.join("pki").display()
    ))
}

/// Latencies from the gRPC subscriber, after the warm-up: (latencies, changes seen).
async fn listen(grpc: std::net::SocketAddr, n: usize) -> anyhow::Result<(Vec<Duration>, usize)> {
    let mut client = iogate_client::Client::connect(&format!("http://{grpc}")).await?;
    let per = n / DEVICES;
    let step = n / SAMPLED;
    let fields: Vec<(String, String)> = (0..SAMPLED)
        .map(|k| {
            let i = k * step;
            (format!("d{}", i / per), format!("v{i}"))
        })
        .collect();
    let selection = iogate_client::Selection {
        devices: Vec::new(),
        fields,
    };
    let mut stream = Box::pin(client.subscribe(&selection, false).await?);
    let started = Instant::now();
    let mut latencies = Vec::new();
    let mut seen = 0;
    while started.elapsed() < WARM_UP + RUN {
        let next = tokio::time::timeout(Duration::from_secs(5), stream.next()).await;
        let Ok(Some(update)) = next else { break };
        let iogate_client::Update::Value(v) = update? else {
            continue;
        };
        if started.elapsed() < WARM_UP {
            continue;
        }
        if let Some(at) = v.timestamp {
            seen += 1;
            latencies.push(SystemTime::now().duration_since(at).unwrap_or_default());
        }
    }
    Ok((latencies, seen))
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

async fn measure(n: usize, refresh_ms: u64) -> anyhow::Result<Vec<common::Row>> {
    let port = common::free_port()?;
    let _server = start_server(n, port)?;
    let dir = common::temp_dir(&format!("uaclient-{n}-{refresh_ms}"))?;
    let gateway = common::start(&dir, &config(&dir, n, port, refresh_ms)?)?;
    let pid = gateway.child.id();
    // Every subscription made and reporting before anything is measured.
    tokio::time::sleep(Duration::from_secs(3)).await;
    let cpu_before = common::cpu_seconds(pid);
    let wall = Instant::now();
    let (mut latencies, seen) = listen(gateway.grpc, n).await?;
    let cpu = (common::cpu_seconds(pid) - cpu_before) / wall.elapsed().as_secs_f64();
    let rss_mib = common::rss_kib(pid) as f64 / 1024.0;
    latencies.sort();
    let expected = SAMPLED as f64 * RUN.as_secs_f64();
    let (p50, p99) = (percentile(&latencies, 0.5), percentile(&latencies, 0.99));
    println!(
        "{n} variables, publishing every {refresh_ms} ms: {seen} changes of {SAMPLED} sampled fields in {} s (expected about {expected:.0}); p50 {p50:?}, p99 {p99:?}; CPU {:.1} %; RSS {rss_mib:.1} MiB",
        RUN.as_secs(),
        cpu * 100.0
    );
    let big = n == 100_000;
    let at = format!("{n} variables at 1 s, publishing every {refresh_ms} ms");
    Ok(vec![
        common::Row {
            measure: format!("OPC UA client, {at}: change to subscriber p50 / p99"),
            iogate: format!("{p50:.1?} / {p99:.1?}"),
            peer: "(no published figure)".into(),
            ratio: 0.0,
            goal: format!("every change seen: {seen} of ~{expected:.0}"),
        },
        common::Row {
            measure: format!("OPC UA client, {at}: CPU, memory"),
            iogate: format!("{:.1} % of a core, {rss_mib:.0} MiB", cpu * 100.0),
            peer: if big {
                "NG Gateway 8.3 %, 165 MiB; NeuronEX 60 %, 594 MB".into()
            } else {
                "(published for 100,000 only)".into()
            },
            ratio: if big { rss_mib / 165.0 } else { 0.0 },
            goal: "memory and CPU below NG Gateway's".into(),
        },
    ])
}

/// The server side: async-opcua's server with `n` Double variables (`ns=2;i=0..n`) under
/// the Objects folder, each changed once a second with the time as its SourceTimestamp.
mod server {
    use std::time::Duration;

    use opcua::server::ServerBuilder;
    use opcua::server::address_space::Variable;
    use opcua::server::node_manager::memory::{SimpleNodeManager, simple_node_manager};
    use opcua::types::{DataValue, DateTime, NodeId, Variant};

    pub fn run(spec: &str) -> anyhow::Result<()> {
        let (n, port) = spec
            .split_once(':')
            .ok_or_else(|| anyhow::anyhow!("N:PORT"))?;
        let (n, port): (usize, u16) = (n.parse()?, port.parse()?);
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()?;
        runtime.block_on(serve(n, port))
    }

    async fn serve(n: usize, port: u16) -> anyhow::Result<()> {
        let mut builder = ServerBuilder::new_anonymous("bench")
            .host("127.0.0.1")
            .port(port)
            .with_node_manager(simple_node_manager(
                opcua::server::diagnostics::NamespaceMetadata {
                    namespace_uri: "urn:iogate:bench".to_owned(),
                    ..Default::default()
                },
                "bench",
            ))
            .max_message_size(0)
            .max_chunk_count(0);
        builder
            .limits_mut()
            .subscriptions
            .max_monitored_items_per_sub = n;
        let (server, handle) = builder.build().map_err(|e| anyhow::anyhow!("{e}"))?;
        let manager = handle
            .node_managers()
            .get_of_type::<SimpleNodeManager>()
            .ok_or_else(|| anyhow::anyhow!("no node manager"))?;
        let ns = handle
            .get_namespace_index("urn:iogate:bench")
            .ok_or_else(|| anyhow::anyhow!("no namespace"))?;
        let ids: Vec<NodeId> = (0..n).map(|i| NodeId::new(ns, i as u32)).collect();
        {
            let mut space = manager.address_space().write();
            let variables = ids
                .iter()
                .map(|id| Variable::new(id, format!("v{id}"), format!("v{id}"), 0.0f64))
                .collect();
            space.add_variables(variables, &NodeId::objects_folder_id());
        }
        let subscriptions = handle.subscriptions().clone();
        tokio::spawn(server.run());
        println!("ready");
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        let mut k = 0.0f64;
        loop {
            tick.tick().await;
            k += 1.0;
            let now = DateTime::now();
            let value = DataValue {
                value: Some(Variant::Double(k)),
                source_timestamp: Some(now),
                server_timestamp: Some(now),
                ..Default::default()
            };
            let _ = manager.set_values(
                &subscriptions,
                ids.iter().map(|id| (id, None, value.clone())),
            );
        }
    }
}
