//! The EtherNet/IP driver beside pylogix (a Logix client in Python, not ours) on the same
//! cpppo Logix simulator, one after the other in the same run: 500 tags (the elements of a
//! DINT[500]) read per cycle, cycles a second as a ratio; the gateway's CPU and memory (only
//! `iogate serve`'s process is measured). Both are bound by the simulator, a Python
//! program answering on the same two cores: the ratio compares the clients' packing (how
//! many requests a cycle takes), not the controllers a plant has.
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

/// cpppo's simulator with `Counts=DINT[TAGS]`; killed when dropped.
struct Simulator {
    child: Child,
    port: u16,
}

impl Simulator {
    fn start() -> anyhow::Result<Simulator> {
        use std::io::BufRead;
        let mut child = Command::new("python3")
            .arg(repo().join("tests/eip/plc.py"))
            .arg(format!("Counts=DINT[{TAGS}]"))
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
fn reference(port: u16) -> anyhow::Result<f64> {
    let out = Command::new("python3")
        .arg(repo().join("tests/eip/bench_read.py"))
        .args([
            port.to_string(),
            TAGS.to_string(),
            RUN.as_secs().to_string(),
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

async fn iogate(port: u16) -> anyhow::Result<(f64, f64, f64)> {
    let dir = common::temp_dir("eip")?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Bench\nprotocol: ab-eip\nfields:\n");
    for i in 0..TAGS {
        profile.push_str(&format!(
            "  - {{ name: C{i}, type: DINT, direction: input, tag: \"Counts[{i}]\" }}\n"
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
    let simulator = Simulator::start()?;
    let pylogix = reference(simulator.port)?;
    let (rate, cpu, rss) = runtime.block_on(iogate(simulator.port))?;
    println!(
        "{TAGS} tags a cycle from cpppo's simulator: iogate {rate:.1} cycles/s, pylogix {pylogix:.1}: ratio {:.2}; gateway CPU {:.1} % of a core, {rss:.1} MiB resident",
        rate / pylogix,
        cpu * 100.0
    );
    common::print_table(&[common::Row {
        measure: format!(
            "EtherNet/IP, {TAGS} DINT tags a cycle: cycles a second; gateway CPU, memory"
        ),
        iogate: format!("{rate:.1}; {:.1} % of a core, {rss:.1} MiB", cpu * 100.0),
        peer: format!("pylogix {pylogix:.1}"),
        ratio: rate / pylogix,
        goal: "at least 1.0".into(),
    }]);
    Ok(())
}
