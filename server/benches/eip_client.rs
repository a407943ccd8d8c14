//! The EtherNet/IP driver beside pylogix (a Logix client in Python, not ours) on the same
//! cpppo Logix simulator, one after the other in the same run, cycles a second as a ratio;
//! the gateway's CPU and memory (only `iogate serve`'s process is measured). Two layouts:
//! 500 DINT tags of their own (both clients pack them in Multiple Service Packets), and the
//! 500 elements of a DINT[500] (the gateway reads the fields next to each other as one
//! read; pylogix with its own array read of 500 elements). Both are bound by the simulator,
//! a Python program answering on the same two cores: the ratio compares the clients'
//! packing (how many requests a cycle takes), not the controllers a plant has. Then both
//! layouts against a Logix written for the bench (`parts/logix.rs`: Rust, connected
//! messaging up to 4,002 bytes, Multiple Service Packets), which answers faster than
//! either client asks: the ratio of the clients themselves. The gateway reads back to back
//! (`refresh_rate: 0ms`).
//!
//! With `AB_SERVER` naming libplctag's `ab_server` (a Logix simulator in C, fast enough not
//! to be the bottleneck; built from libplctag's `src/tests/ab_server` with gcc), the array
//! layout again against it. It routes nothing (an Unconnected Send is not one of its
//! services), has no Multiple Service Packets, and its connected answers lack the interface
//! handle and timeout of SendUnitData's data; the gateway reads it unconnected without a route
//! (`connected: false, path: ""`), five Read Tag Fragmented answers of 480 bytes a cycle,
//! where pylogix, parsing answers at fixed offsets, reads it in one connected answer.
//!
//! `cargo bench -p iogate --bench eip_client`

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

mod common;
#[path = "parts/logix.rs"]
mod logix;

const TAGS: usize = 500;
const RUN: Duration = Duration::from_secs(10);

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The two layouts: tags of their own, or the elements of one array.
#[derive(Clone, Copy, PartialEq)]
enum Layout {
    Tags,
    Array,
}

/// cpppo's simulator with `T0=DINT` .. or `Counts=DINT[TAGS]`; killed when dropped.
struct Simulator {
    child: Child,
    port: u16,
}

impl Simulator {
    /// libplctag's ab_server at `program` with `Counts=DINT[TAGS]`, once it listens.
    fn ab_server(program: &str) -> anyhow::Result<Simulator> {
        let port = std::net::TcpListener::bind("127.0.0.1:0")?
            .local_addr()?
            .port();
        let child = Command::new(program)
            .args(["--plc=ControlLogix", "--path=1,0"])
            .arg(format!("--port={port}"))
            .arg(format!("--tag=Counts:DINT[{TAGS}]"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()?;
        let simulator = Simulator { child, port };
        let deadline = Instant::now() + Duration::from_secs(10);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            anyhow::ensure!(Instant::now() < deadline, "ab_server does not listen");
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(simulator)
    }

    fn start(layout: Layout) -> anyhow::Result<Simulator> {
        use std::io::BufRead;
        let tags: Vec<String> = match layout {
            Layout::Tags => (0..TAGS).map(|i| format!("T{i}=DINT")).collect(),
            Layout::Array => vec![format!("Counts=DINT[{TAGS}]")],
        };
        let mut child = Command::new(common::python())
            .arg(repo().join("tests/eip/plc.py"))
            .args(&tags)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()?;
        let out = child
            .stdout
            .take()
            .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
        let mut line = String::new();
        std::io::BufReader::new(out).read_line(&mut line)?;
        let port = line.trim().parse()?;
        Ok(Simulator { child, port })
    }
}

impl Drop for Simulator {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// pylogix's cycles a second.
fn reference(port: u16, layout: Layout) -> anyhow::Result<f64> {
    let out = Command::new(common::python())
        .arg(repo().join("tests/eip/bench_read.py"))
        .args([
            port.to_string(),
            TAGS.to_string(),
            RUN.as_secs().to_string(),
            if layout == Layout::Array {
                "array"
            } else {
                "tags"
            }
            .to_owned(),
        ])
        .output()?;
    anyhow::ensure!(
        out.status.success(),
        "pylogix: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout)?;
    anyhow::ensure!(v["good"] == TAGS, "pylogix read {} of {TAGS}", v["good"]);
    Ok(v["cycles"].as_f64().unwrap_or(0.0) / v["seconds"].as_f64().unwrap_or(1.0))
}

async fn cycles(client: &mut iogate_client::Client) -> anyhow::Result<u64> {
    let d = client.device("bench").await?;
    Ok(d.diagnostics.map_or(0, |d| d.io_cycles))
}

/// The gateway's cycles a second, CPU and resident MiB, reading the controller at `port`
/// with the link's settings `more` (after host and port).
async fn iogate(port: u16, layout: Layout, more: &str) -> anyhow::Result<(f64, f64, f64)> {
    let dir = common::temp_dir("eip")?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Bench\nprotocol: ab-eip\nfields:\n");
    for i in 0..TAGS {
        let tag = match layout {
            Layout::Tags => format!("T{i}"),
            Layout::Array => format!("Counts[{i}]"),
        };
        profile.push_str(&format!(
            "  - {{ name: C{i}, type: DINT, direction: input, tag: \"{tag}\" }}\n"
        ));
    }
    std::fs::write(profiles.join("bench.yaml"), profile)?;
    let gateway = common::start(
        &dir,
        &format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {port}{more} }} }}\ndevices:\n  - {{ name: bench, profile: Bench, link: plc, refresh_rate: 0ms }}\n",
            profiles.display()
        ),
    )?;
    let pid = gateway.child.id();
    let mut client = iogate_client::Client::connect(&format!("http://{}", gateway.grpc)).await?;
    let deadline = Instant::now() + Duration::from_secs(30);
    while cycles(&mut client).await? < 2 {
        anyhow::ensure!(Instant::now() < deadline, "the device is not read");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let (c0, cpu0, wall) = (
        cycles(&mut client).await?,
        common::cpu_seconds(pid),
        Instant::now(),
    );
    tokio::time::sleep(RUN).await;
    let elapsed = wall.elapsed().as_secs_f64();
    let rate = (cycles(&mut client).await? - c0) as f64 / elapsed;
    let cpu = (common::cpu_seconds(pid) - cpu0) / elapsed;
    let rss = common::rss_kib(pid) as f64 / 1024.0;
    every_field_right(&mut client).await?;
    Ok((rate, cpu, rss))
}

/// Every field good, and each `C{i}` 0 (cpppo's and ab_server's tags) or `i` (the bench
/// Logix's): a cycle counted is a cycle read right.
async fn every_field_right(client: &mut iogate_client::Client) -> anyhow::Result<()> {
    let values = client
        .read(&iogate_client::Selection::device("bench"))
        .await?;
    let mut good = 0;
    for v in &values {
        let i: f64 = v.field.trim_start_matches('C').parse().unwrap_or(-1.0);
        let value = v.value.as_ref().and_then(|v| v.as_f64());
        anyhow::ensure!(
            v.quality == iogate_client::Quality::Good,
            "{} is {:?}: {:?}",
            v.field,
            v.quality,
            v.error
        );
        anyhow::ensure!(
            value == Some(0.0) || value == Some(i),
            "{} reads {value:?}",
            v.field
        );
        good += 1;
    }
    anyhow::ensure!(good == TAGS, "the gateway read {good} of {TAGS} fields");
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let install = repo().join("tests/eip/install.sh");
    let ok = Command::new("bash").arg(&install).status()?.success();
    anyhow::ensure!(ok, "{} failed", install.display());
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let mut rows = Vec::new();
    for (layout, what, peer) in [
        (
            Layout::Tags,
            "500 DINT tags",
            "pylogix, Multiple Service Packets",
        ),
        (
            Layout::Array,
            "the 500 elements of a DINT[500]",
            "pylogix, an array read",
        ),
    ] {
        let simulator = Simulator::start(layout)?;
        let row = pair(&runtime, simulator.port, layout, "")?;
        rows.push(report(row, what, "cpppo's simulator", peer));
        let port = runtime.block_on(logix::start(bench_tags(layout)))?;
        let row = pair(&runtime, port, layout, "")?;
        rows.push(report(row, what, "a Logix written for the bench", peer));
    }
    match std::env::var("AB_SERVER") {
        Ok(program) => {
            let simulator = Simulator::ab_server(&program)?;
            let more = ", connected: false, path: \"\"";
            let row = pair(&runtime, simulator.port, Layout::Array, more)?;
            let (what, peer) = ("the 500 elements of a DINT[500]", "pylogix, an array read");
            rows.push(report(row, what, "libplctag's ab_server", peer));
        }
        Err(_) => println!("AB_SERVER not set: no rows against libplctag's ab_server"),
    }
    common::print_table(&rows);
    Ok(())
}

/// The bench Logix's tags for `layout`.
fn bench_tags(layout: Layout) -> logix::Tags {
    let tags = match layout {
        Layout::Tags => (0..TAGS)
            .map(|i| (format!("T{i}").into_bytes(), 1))
            .collect(),
        Layout::Array => [(b"Counts".to_vec(), TAGS as u32)].into_iter().collect(),
    };
    std::sync::Arc::new(tags)
}

/// pylogix's cycles a second, then the gateway's, its CPU and memory.
fn pair(
    runtime: &tokio::runtime::Runtime,
    port: u16,
    layout: Layout,
    more: &str,
) -> anyhow::Result<(f64, f64, f64, f64)> {
    let pylogix = reference(port, layout)?;
    let (rate, cpu, rss) = runtime.block_on(iogate(port, layout, more))?;
    Ok((pylogix, rate, cpu, rss))
}

fn report(
    (pylogix, rate, cpu, rss): (f64, f64, f64, f64),
    what: &str,
    from: &str,
    peer: &str,
) -> common::Row {
    println!(
        "{what} a cycle from {from}: iogate {rate:.1} cycles/s, {peer} {pylogix:.1}: ratio {:.2}; gateway CPU {:.1} % of a core, {rss:.1} MiB resident",
        rate / pylogix,
        cpu * 100.0
    );
    common::Row {
        measure: format!(
            "EtherNet/IP, {what} a cycle from {from}: cycles a second; gateway CPU, memory"
        ),
        iogate: format!("{rate:.1}; {:.1} % of a core, {rss:.1} MiB", cpu * 100.0),
        peer: format!("{peer} {pylogix:.1}"),
        ratio: rate / pylogix,
        goal: "at least 1.0 (2.0 against ab_server)".into(),
    }
}
