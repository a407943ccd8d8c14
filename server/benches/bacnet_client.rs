//! The BACnet driver against a bacpypes3 device farm (`tests/bacnet/router.py`: one router
//! with 100 devices of 100 analog inputs behind it, 10,000 points, a BBMD the gateway joins
//! as a foreign device), every point read every second: the points a second the gateway
//! published, its CPU and memory (only `iogate serve`'s process is measured; the farm is a
//! Python program on the same two cores, and is what bounds the rate). Then change of
//! value: a device's present value changed on the farm and the time until a gRPC subscriber
//! of the gateway sees it, for a device read once an hour (the change can only come by its
//! subscription), p50 and p99 of 30 changes.
//!
//! `cargo bench -p iogate --bench bacnet_client`

use std::io::{BufRead, Write};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, Command, Stdio};
use std::time::{Duration, Instant};

use futures_util::StreamExt;

mod common;

const DEVICES: usize = 100;
const OBJECTS: usize = 100;
const RUN: Duration = Duration::from_secs(20);

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The farm; killed when dropped.
struct Farm {
    child: Child,
    stdin: ChildStdin,
    lines: std::io::Lines<std::io::BufReader<std::process::ChildStdout>>,
    port: u16,
}

impl Farm {
    fn start(devices: usize, objects: usize) -> anyhow::Result<Farm> {
        let port = std::net::UdpSocket::bind("127.0.0.2:0")?
            .local_addr()?
            .port();
        let mut child = Command::new(common::python())
            .arg(repo().join("tests/bacnet/router.py"))
            .args(["--host", "127.0.0.2", "--port", &port.to_string()])
            .args([
                "--count",
                &devices.to_string(),
                "--objects",
                &objects.to_string(),
            ])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()?;
        let stdin = child
            .stdin
            .take()
            .ok_or_else(|| anyhow::anyhow!("no stdin"))?;
        let out = child
            .stdout
            .take()
            .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
        let mut lines = std::io::BufReader::new(out).lines();
        let ready = lines
            .next()
            .ok_or_else(|| anyhow::anyhow!("the farm ended"))??;
        anyhow::ensure!(ready == "ready", "the farm said {ready}");
        Ok(Farm {
            child,
            stdin,
            lines,
            port,
        })
    }

    fn cmd(&mut self, command: &str) -> anyhow::Result<String> {
        writeln!(self.stdin, "{command}")?;
        self.lines
            .next()
            .ok_or_else(|| anyhow::anyhow!("the farm ended"))?
            .map_err(Into::into)
    }
}

impl Drop for Farm {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A gateway with `devices` devices of the farm, each every `refresh`.
fn gateway(
    farm: &Farm,
    devices: usize,
    objects: usize,
    refresh: &str,
    cov: bool,
) -> anyhow::Result<common::Gateway> {
    let dir = common::temp_dir("bacnet")?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Vav\nprotocol: bacnet\nfields:\n");
    for i in 1..=objects {
        profile.push_str(&format!(
            "  - {{ name: I{i}, type: REAL, direction: input, object: \"analog-input:{i}\" }}\n"
        ));
    }
    std::fs::write(profiles.join("vav.yaml"), profile)?;
    let bind = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let mut config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - name: bms\n    bacnet: {{ bind: \"{bind}\", bbmd: \"127.0.0.2:{}\", timeout: 3s, retries: 1 }}\ndevices:\n",
        profiles.display(),
        farm.port
    );
    for k in 1..=devices {
        config.push_str(&format!(
            "  - {{ name: vav{k}, profile: Vav, link: bms, device_instance: {}, refresh_rate: {refresh}, cov: {cov} }}\n",
            3000 + k
        ));
    }
    common::start(&dir, &config)
}

async fn cycles(client: &mut iogate_client::Client) -> anyhow::Result<u64> {
    Ok(client
        .devices()
        .await?
        .iter()
        .map(|d| d.diagnostics.as_ref().map_or(0, |d| d.io_cycles))
        .sum())
}

/// 10,000 points every second: points a second, CPU, memory.
async fn polled() -> anyhow::Result<(f64, f64, f64)> {
    let farm = Farm::start(DEVICES, OBJECTS)?;
    let gw = gateway(&farm, DEVICES, OBJECTS, "1s", false)?;
    let pid = gw.child.id();
    let mut client = iogate_client::Client::connect(&format!("http://{}", gw.grpc)).await?;
    let deadline = Instant::now() + Duration::from_secs(120);
    while cycles(&mut client).await? < (DEVICES * 2) as u64 {
        anyhow::ensure!(Instant::now() < deadline, "the devices are not read");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let (c0, cpu0, wall) = (
        cycles(&mut client).await?,
        common::cpu_seconds(pid),
        Instant::now(),
    );
    tokio::time::sleep(RUN).await;
    let elapsed = wall.elapsed().as_secs_f64();
    let points = (cycles(&mut client).await? - c0) as f64 * OBJECTS as f64 / elapsed;
    let cpu = (common::cpu_seconds(pid) - cpu0) / elapsed;
    Ok((points, cpu, common::rss_kib(pid) as f64 / 1024.0))
}

/// Waits for the update that brings `want`.
async fn seen(
    updates: &mut (
             impl futures_util::Stream<Item = Result<iogate_client::Update, iogate_client::Error>>
             + Unpin
         ),
    want: f64,
) -> anyhow::Result<()> {
    while let Some(u) = updates.next().await {
        if let Ok(iogate_client::Update::Value(v)) = u
            && v.value.as_ref().and_then(|x| x.as_f64()) == Some(want)
        {
            return Ok(());
        }
    }
    anyhow::bail!("the stream ended")
}

/// Change of value to a gRPC subscriber: p50 and p99 in milliseconds.
async fn changes() -> anyhow::Result<(f64, f64)> {
    let mut farm = Farm::start(1, 1)?;
    let gw = gateway(&farm, 1, 1, "1h", true)?;
    let mut client = iogate_client::Client::connect(&format!("http://{}", gw.grpc)).await?;
    let selection = iogate_client::Selection {
        devices: vec!["vav1".into()],
        fields: Vec::new(),
    };
    let mut updates = Box::pin(client.subscribe(&selection, false).await?);
    tokio::time::timeout(Duration::from_secs(30), seen(&mut updates, 1.0)).await??;
    // The subscription is made once the first read answered.
    tokio::time::sleep(Duration::from_secs(2)).await;
    let mut times = Vec::new();
    for k in 0..30 {
        let want = 100.0 + f64::from(k);
        let at = Instant::now();
        anyhow::ensure!(farm.cmd(&format!("set 3001 analog-input,1 {want}"))? == "ok");
        tokio::time::timeout(Duration::from_secs(10), seen(&mut updates, want)).await??;
        times.push(at.elapsed().as_secs_f64() * 1000.0);
    }
    times.sort_by(f64::total_cmp);
    Ok((times[times.len() / 2], times[times.len() * 99 / 100]))
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let (points, cpu, rss) = runtime.block_on(polled())?;
    println!(
        "BACnet, {} points of {DEVICES} devices behind a router every 1 s (bacpypes3): {points:.0} points/s, gateway CPU {:.1} % of a core, {rss:.1} MiB resident",
        DEVICES * OBJECTS,
        cpu * 100.0
    );
    let (p50, p99) = runtime.block_on(changes())?;
    println!(
        "BACnet, change of value to a gRPC subscriber (a device read once an hour): p50 {p50:.1} ms, p99 {p99:.1} ms"
    );
    Ok(())
}
