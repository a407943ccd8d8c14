//! The EtherNet/IP driver beside pylogix (a Logix client in Python, not ours) on the same
//! cpppo Logix simulator, one after the other in the same run, cycles a second as a ratio;
//! the gateway's CPU and memory (only `iogate serve`'s process is measured). Two layouts:
//! 500 DINT tags of their own (both clients pack them in Multiple Service Packets), and the
//! 500 elements of a DINT[500] (the gateway reads the fields next to each other as one
//! read; pylogix with its own array read of 500 elements). Both are bound by the simulator,
//! a Python program answering on the same two cores: the ratio compares the clients'
//! packing (how many requests a cycle takes), not the controllers a plant has.
//!
//! `cargo bench -p iogate --bench eip_client`

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

mod common;

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

async fn iogate(port: u16, layout: Layout) -> anyhow::Result<(f64, f64, f64)> {
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
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - {{ name: plc, eip: {{ host: 127.0.0.1, port: {port} }} }}\ndevices:\n  - {{ name: bench, profile: Bench, link: plc, refresh_rate: 1ms }}\n",
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
    Ok((rate, cpu, rss))
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
        let pylogix = reference(simulator.port, layout)?;
        let (rate, cpu, rss) = runtime.block_on(iogate(simulator.port, layout))?;
        println!(
            "{what} a cycle from cpppo's simulator: iogate {rate:.1} cycles/s, {peer} {pylogix:.1}: ratio {:.2}; gateway CPU {:.1} % of a core, {rss:.1} MiB resident",
            rate / pylogix,
            cpu * 100.0
        );
        rows.push(common::Row {
            measure: format!("EtherNet/IP, {what} a cycle: cycles a second; gateway CPU, memory"),
            iogate: format!("{rate:.1}; {:.1} % of a core, {rss:.1} MiB", cpu * 100.0),
            peer: format!("{peer} {pylogix:.1}"),
            ratio: rate / pylogix,
            goal: "at least 1.0".into(),
        });
    }
    common::print_table(&rows);
    Ok(())
}
