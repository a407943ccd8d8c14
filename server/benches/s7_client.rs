//! The S7 driver at the protocol's limit, beside Snap7's own client (python-snap7, the
//! Snap7 C library) reading the same fields from the same Snap7 server in the same run, one
//! after the other; only `iogate serve`'s process is measured for CPU and memory.
//!
//! - 1,000 INT fields of one DB (bytes 0-1999): Snap7's `db_read` of the block against one
//!   device read back to back (`refresh_rate: 0ms`); cycles a second, PDUs a cycle.
//! - 200 REAL fields scattered over ten DBs, 100 bytes apart (nothing to merge): Snap7's
//!   `read_multi_vars` of 20 items at a time against one device.
//! - 500 INT fields of one DB 8 bytes apart: Snap7's `read_multi_vars` of 20 items at a
//!   time against one device read with the default `max_gap` (32) and with `max_gap: 0`.
//! - Under the 1,000-field load, 100 writes of one INT through gRPC: request to outcome.
//! - 100,000 INT fields (fifty devices of 2,000) read every second: CPU share and resident
//!   memory beside NeuronEX's published 57 % / 512 MB.
//!
//! `cargo bench -p iogate --bench s7_client`

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

mod common;

const RUN: Duration = Duration::from_secs(10);
const BIG_RUN: Duration = Duration::from_secs(20);

fn main() -> anyhow::Result<()> {
    let install = repo().join("tests/s7/install.sh");
    let ok = Command::new("bash").arg(&install).status()?.success();
    anyhow::ensure!(ok, "{} failed", install.display());
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let mut rows = Vec::new();
    {
        let server = Snap7::start(20, 4000)?;
        for scenario in [
            Scenario::Block,
            Scenario::Scattered,
            Scenario::Gapped(None),
            Scenario::Gapped(Some(0)),
        ] {
            rows.extend(runtime.block_on(compare(&server, scenario))?);
        }
    }
    let server = Snap7::start(50, 4000)?;
    rows.push(runtime.block_on(big(&server))?);
    common::print_table(&rows);
    Ok(())
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn peer() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches/peer/s7.py")
}

/// Snap7's server with `dbs` data blocks of `size` bytes; killed when dropped.
struct Snap7 {
    child: Child,
    port: u16,
}

impl Snap7 {
    fn start(dbs: usize, size: usize) -> anyhow::Result<Snap7> {
        use std::io::BufRead;
        let mut child = Command::new(common::python())
            .arg(peer())
            .args(["server", &dbs.to_string(), &size.to_string()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()?;
        let out = child
            .stdout
            .take()
            .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
        let mut line = String::new();
        std::io::BufReader::new(out).read_line(&mut line)?;
        let port = line.trim().parse()?;
        Ok(Snap7 { child, port })
    }
}

impl Drop for Snap7 {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Scenario {
    Block,
    Scattered,
    /// 500 INTs 8 bytes apart, the link's `max_gap` (none: the default).
    Gapped(Option<u32>),
}

impl Scenario {
    fn name(self) -> &'static str {
        match self {
            Scenario::Block => "block",
            Scenario::Scattered => "scattered",
            Scenario::Gapped(_) => "gapped",
        }
    }

    fn title(self) -> &'static str {
        match self {
            Scenario::Block => "1,000 fields of one DB",
            Scenario::Scattered => "200 scattered fields",
            Scenario::Gapped(None) => "500 fields 8 bytes apart, max_gap 32 (default)",
            Scenario::Gapped(Some(_)) => "500 fields 8 bytes apart, max_gap 0",
        }
    }

    /// More of the link's settings.
    fn link(self) -> String {
        match self {
            Scenario::Gapped(Some(gap)) => format!(", max_gap: {gap}"),
            _ => String::new(),
        }
    }

    /// The profile's field lines.
    fn fields(self) -> String {
        let mut out = String::new();
        match self {
            Scenario::Block => {
                for k in 0..1000 {
                    out.push_str(&format!(
                        "  - {{ name: v{k}, type: INT, direction: inout, address: DB1.DBW{} }}\n",
                        2 * k
                    ));
                }
            }
            Scenario::Gapped(_) => {
                for k in 0..500 {
                    out.push_str(&format!(
                        "  - {{ name: v{k}, type: INT, direction: input, address: DB1.DBW{} }}\n",
                        8 * k
                    ));
                }
            }
            Scenario::Scattered => {
                for db in 1..=10 {
                    for k in 0..20 {
                        out.push_str(&format!(
                            "  - {{ name: v{db}_{k}, type: REAL, direction: input, address: DB{db}.DBD{} }}\n",
                            k * 100
                        ));
                    }
                }
            }
        }
        out
    }
}

/// Snap7's client on the scenario: cycles a second and PDUs a cycle.
fn reference(port: u16, scenario: Scenario) -> anyhow::Result<(f64, u32)> {
    let out = Command::new(common::python())
        .arg(peer())
        .args([
            "client",
            &port.to_string(),
            scenario.name(),
            &RUN.as_secs_f64().to_string(),
        ])
        .output()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let mut words = text.split_whitespace();
    let cycles: f64 = words.next().unwrap_or("0").parse()?;
    let pdus: u32 = words.next().unwrap_or("0").parse()?;
    Ok((cycles / RUN.as_secs_f64(), pdus))
}

/// A gateway with `devices` (name, field lines, refresh rate) on one S7 link to `port`.
fn gateway(
    name: &str,
    port: u16,
    devices: &[(String, String, &str)],
    link: &str,
) -> anyhow::Result<common::Gateway> {
    let dir = common::temp_dir(name)?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut listed = String::new();
    for (device, fields, refresh) in devices {
        std::fs::write(
            profiles.join(format!("{device}.yaml")),
            format!("name: P{device}\nprotocol: s7\nfields:\n{fields}"),
        )?;
        listed.push_str(&format!(
            "  - {{ name: {device}, profile: P{device}, link: plc, refresh_rate: {refresh} }}\n"
        ));
    }
    let config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - name: plc\n    s7: {{ host: 127.0.0.1, port: {port}, pdu_size: 960{link} }}\ndevices:\n{listed}",
        profiles.display()
    );
    common::start(&dir, &config)
}

/// The device's cycles so far.
async fn cycles(client: &mut iogate_client::Client, device: &str) -> anyhow::Result<u64> {
    let d = client.device(device).await?;
    Ok(d.diagnostics.map_or(0, |d| d.io_cycles))
}

/// Waits until every device has been read.
async fn until_read(client: &mut iogate_client::Client, devices: &[&str]) -> anyhow::Result<()> {
    let deadline = Instant::now() + Duration::from_secs(30);
    for d in devices {
        while cycles(client, d).await? == 0 {
            anyhow::ensure!(Instant::now() < deadline, "{d} is not read");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
    Ok(())
}

async fn compare(server: &Snap7, scenario: Scenario) -> anyhow::Result<Vec<common::Row>> {
    let (snap7_rate, snap7_pdus) = reference(server.port, scenario)?;
    let devices = [("bench".to_owned(), scenario.fields(), "0ms")];
    let gateway = gateway(scenario.name(), server.port, &devices, &scenario.link())?;
    let pid = gateway.child.id();
    let mut client = iogate_client::Client::connect(&format!("http://{}", gateway.grpc)).await?;
    until_read(&mut client, &["bench"]).await?;
    let (_, plan) = common::http::get_once(gateway.http, "/api/v1/links/plc/plan").await?;
    let pdus = String::from_utf8_lossy(&plan).matches("    job ").count();
    let (c0, cpu0, wall) = (
        cycles(&mut client, "bench").await?,
        common::cpu_seconds(pid),
        Instant::now(),
    );
    tokio::time::sleep(RUN).await;
    let elapsed = wall.elapsed().as_secs_f64();
    let rate = (cycles(&mut client, "bench").await? - c0) as f64 / elapsed;
    let cpu = (common::cpu_seconds(pid) - cpu0) / elapsed;
    let rss = common::rss_kib(pid) as f64 / 1024.0;
    let mut rows = vec![common::Row {
        measure: format!(
            "S7, {}: cycles a second (PDUs a cycle); gateway CPU, memory",
            scenario.title()
        ),
        iogate: format!(
            "{rate:.0} ({pdus}); {:.0} % of a core, {rss:.0} MiB",
            cpu * 100.0
        ),
        peer: format!("Snap7 client {snap7_rate:.0} ({snap7_pdus})"),
        ratio: rate / snap7_rate,
        goal: "at least 1.0".into(),
    }];
    println!(
        "{}: iogate {rate:.0} cycles/s in {pdus} PDUs, Snap7 {snap7_rate:.0} in {snap7_pdus}; CPU {:.0} %, RSS {rss:.0} MiB",
        scenario.title(),
        cpu * 100.0
    );
    if scenario == Scenario::Block {
        rows.push(writes(&mut client).await?);
    }
    Ok(rows)
}

/// 100 writes of one INT under the load: request to outcome, as a gRPC client sees it.
async fn writes(client: &mut iogate_client::Client) -> anyhow::Result<common::Row> {
    let mut took = Vec::new();
    for k in 0..100i64 {
        let start = Instant::now();
        let generation = client
            .write("bench", "v0", iogate_client::Value::Int(k))
            .await?;
        loop {
            let status = client.write_status(generation).await?;
            if status.outcome != iogate_client::WriteOutcome::Pending {
                anyhow::ensure!(
                    status.outcome == iogate_client::WriteOutcome::Written,
                    "{status:?}"
                );
                break;
            }
            tokio::task::yield_now().await;
        }
        took.push(start.elapsed().as_secs_f64() * 1000.0);
    }
    let avg = took.iter().sum::<f64>() / took.len() as f64;
    let (min, max) = took
        .iter()
        .fold((f64::MAX, 0.0f64), |(a, b), &t| (a.min(t), b.max(t)));
    println!("writes under load: min {min:.2} ms, average {avg:.2} ms, max {max:.2} ms");
    Ok(common::Row {
        measure: "S7, 100 writes under the 1,000-field load: request to outcome min / avg / max"
            .into(),
        iogate: format!("{min:.1} / {avg:.1} / {max:.1} ms"),
        peer: "NeuronEX average 30 ms".into(),
        ratio: avg / 30.0,
        goal: "below NeuronEX's".into(),
    })
}

/// 100,000 fields read every second: fifty devices of 2,000 INTs, one DB each.
async fn big(server: &Snap7) -> anyhow::Result<common::Row> {
    let devices: Vec<(String, String, &str)> = (1..=50)
        .map(|db| {
            let fields: String = (0..2000)
                .map(|k| {
                    format!(
                        "  - {{ name: v{k}, type: INT, direction: input, address: DB{db}.DBW{} }}\n",
                        2 * k
                    )
                })
                .collect();
            (format!("d{db}"), fields, "1s")
        })
        .collect();
    let gateway = gateway("big", server.port, &devices, "")?;
    let pid = gateway.child.id();
    let mut client = iogate_client::Client::connect(&format!("http://{}", gateway.grpc)).await?;
    let names: Vec<&str> = devices.iter().map(|(n, _, _)| n.as_str()).collect();
    until_read(&mut client, &names).await?;
    let c0 = cycles(&mut client, "d1").await?;
    let (cpu0, wall) = (common::cpu_seconds(pid), Instant::now());
    tokio::time::sleep(BIG_RUN).await;
    let elapsed = wall.elapsed().as_secs_f64();
    let cpu = (common::cpu_seconds(pid) - cpu0) / elapsed;
    let rss = common::rss_kib(pid) as f64 / 1024.0;
    let rate = (cycles(&mut client, "d1").await? - c0) as f64 / elapsed;
    println!(
        "100,000 fields at 1 s: {rate:.2} cycles/s a device, CPU {:.1} %, RSS {rss:.0} MiB",
        cpu * 100.0
    );
    Ok(common::Row {
        measure: "S7, 100,000 fields read every second: CPU, memory".into(),
        iogate: format!(
            "{:.1} % of a core, {rss:.0} MiB ({rate:.2} cycles/s a device)",
            cpu * 100.0
        ),
        peer: "NeuronEX 57 %, 512 MB".into(),
        ratio: rss / 512.0,
        goal: "below NeuronEX's".into(),
    })
}
