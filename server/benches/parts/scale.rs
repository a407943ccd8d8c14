//! 100,000 fields two ways (see `benches/scale.rs`).

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio_modbus::prelude::{ExceptionCode, Request, Response, SlaveRequest};

use crate::common::{self, Row};

const DEVICES: usize = 1000;
const FIELDS: usize = 100;

/// One GET over a fresh connection: the status, how long the whole answer took, its size.
async fn get(addr: SocketAddr, path: &str) -> anyhow::Result<(u16, Duration, usize)> {
    let started = Instant::now();
    let (status, answer) = common::http::get_once(addr, path).await?;
    Ok((status, started.elapsed(), answer.len()))
}

fn percentile(sorted: &[Duration], q: f64) -> Duration {
    sorted[((sorted.len() as f64 * q) as usize).min(sorted.len() - 1)]
}

/// A Modbus TCP device of 1,000 holding registers (register n holds n).
#[derive(Clone)]
struct Thousand;

impl tokio_modbus::server::Service for Thousand {
    type Request = SlaveRequest<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Response, ExceptionCode>>;

    fn call(&self, req: SlaveRequest<'static>) -> Self::Future {
        std::future::ready(match req.request {
            Request::ReadHoldingRegisters(a, n) if usize::from(a) + usize::from(n) <= 1000 => {
                Ok(Response::ReadHoldingRegisters((a..a + n).collect()))
            }
            Request::ReadHoldingRegisters(..) => Err(ExceptionCode::IllegalDataAddress),
            _ => Err(ExceptionCode::IllegalFunction),
        })
    }
}

/// Starts the gateway on `config` and measures it; prints the rows under `title`, answers
/// the suite's rows (each figure against its goal), named by `short`.
fn measure(
    runtime: &tokio::runtime::Runtime,
    name: &str,
    title: &str,
    short: &str,
    config: &str,
) -> anyhow::Result<Vec<Row>> {
    let dir = common::temp_dir(name)?;
    let started = Instant::now();
    let gateway = common::start(&dir, config)?;
    let pid = gateway.child.id();
    let rows = runtime.block_on(async {
        loop {
            if let Ok((200, _, _)) = get(gateway.http, "/readyz").await {
                break;
            }
            anyhow::ensure!(started.elapsed() < Duration::from_secs(60), "never ready");
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let ready = started.elapsed();
        tokio::time::sleep(Duration::from_secs(5)).await;
        let cpu_before = common::cpu_seconds(pid);
        let window = Instant::now();
        tokio::time::sleep(Duration::from_secs(10)).await;
        let cpu = (common::cpu_seconds(pid) - cpu_before) / window.elapsed().as_secs_f64();
        let rss = common::rss_kib(pid);
        let answers = answer_times(gateway.http).await?;
        let connected = common::http::connected_devices(gateway.http).await?;
        let rows = report(title, short, (connected, ready, rss, cpu), answers);
        println!();
        anyhow::Ok(rows)
    })?;
    drop(gateway);
    Ok(rows)
}

/// Both cases: prints their figures, answers the suite's rows.
pub fn run(runtime: &tokio::runtime::Runtime) -> anyhow::Result<Vec<Row>> {
    // 1,000 simulated devices x 100 fields.
    let dir = common::temp_dir("scale-profiles")?;
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    let mut profile = String::from("name: Hundred\nprotocol: simulated\nfields:\n");
    for i in 0..FIELDS {
        let ty = ["REAL", "INT", "BOOL", "DINT"][i % 4];
        let direction = if i % 5 == 0 { "output" } else { "input" };
        profile.push_str(&format!(
            "  - {{ name: F{i}, type: {ty}, direction: {direction}, register: {{ address: {i}, kind: virtual }} }}\n"
        ));
    }
    std::fs::write(profiles.join("hundred.yaml"), profile)?;
    let mut thousand = String::from("name: Thousand\nprotocol: modbus-tcp\nfields:\n");
    for i in 0..1000 {
        thousand.push_str(&format!(
            "  - {{ name: R{i}, type: UINT, direction: input, register: {{ address: {i}, kind: holding_register }} }}\n"
        ));
    }
    std::fs::write(profiles.join("thousand.yaml"), thousand)?;
    let head = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\n",
        profiles.display()
    );
    let mut config = format!("{head}devices:\n");
    for d in 0..DEVICES {
        config.push_str(&format!(
            "  - {{ name: d{d}, profile: Hundred, refresh_rate: 100ms }}\n"
        ));
    }
    let mut rows = measure(
        runtime,
        "scale-sim",
        &format!(
            "{} fields ({DEVICES} simulated devices x {FIELDS}, every 100 ms)",
            DEVICES * FIELDS
        ),
        "100,000 simulated fields",
        &config,
    )?;

    // 100 Modbus TCP devices x 1,000 registers.
    let ports = runtime.block_on(async {
        let mut ports = Vec::new();
        for _ in 0..100 {
            ports.push(common::modbus_device(Thousand).await?);
        }
        anyhow::Ok(ports)
    })?;
    let mut config = format!("{head}links:\n");
    for (i, port) in ports.iter().enumerate() {
        config.push_str(&format!(
            "  - {{ name: l{i}, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n"
        ));
    }
    config.push_str("devices:\n");
    for i in 0..ports.len() {
        config.push_str(&format!(
            "  - {{ name: t{i}, profile: Thousand, link: l{i}, slave_id: 1, refresh_rate: 1s }}\n"
        ));
    }
    rows.extend(measure(
        runtime,
        "scale-tcp",
        "100000 fields (100 Modbus TCP devices x 1000 holding registers, tokio-modbus, every second)",
        "100,000 Modbus TCP fields",
        &config,
    )?);
    Ok(rows)
}

/// What the API's lists take: each path asked 30 times, its p50, p99 and size.
async fn answer_times(
    http: std::net::SocketAddr,
) -> anyhow::Result<Vec<(&'static str, Duration, Duration, usize)>> {
    let mut answers = Vec::new();
    for path in ["/api/v1/devices", "/api/v1/links"] {
        let mut times = Vec::new();
        let mut bytes = 0;
        for _ in 0..30 {
            let (status, took, len) = get(http, path).await?;
            anyhow::ensure!(status == 200, "{path}: {status}");
            times.push(took);
            bytes = len;
        }
        times.sort();
        answers.push((
            path,
            percentile(&times, 0.5),
            percentile(&times, 0.99),
            bytes,
        ));
    }
    Ok(answers)
}

/// Prints the rows under `title` and answers them, each figure against its goal.
fn report(
    title: &str,
    short: &str,
    (connected, ready, rss, cpu): (usize, Duration, u64, f64),
    answers: Vec<(&'static str, Duration, Duration, usize)>,
) -> Vec<Row> {
    println!("{title}:");
    println!("| measure | iogate | goal |");
    println!("| --- | --- | --- |");
    println!("| devices connected while measured | {connected} | all |");
    println!(
        "| start to ready | {:.0} ms | < 1 s |",
        ready.as_secs_f64() * 1e3
    );
    println!("| resident | {:.1} MiB | < 64 MB |", rss as f64 / 1024.0);
    println!("| CPU | {:.1} % of a core | < 15 % |", cpu * 100.0);
    let row = |measure: String, iogate: String, ratio: f64, goal: &str| Row {
        measure: format!("{short}: {measure}"),
        iogate,
        peer: format!("goal {goal}"),
        ratio,
        goal: "< 1.00".into(),
    };
    let mut rows = vec![
        row(
            "resident (MiB)".into(),
            format!("{:.1}", rss as f64 / 1024.0),
            rss as f64 * 1024.0 / 64e6,
            "64 MB",
        ),
        row(
            "CPU (% of a core)".into(),
            format!("{:.1} ({connected} devices connected)", cpu * 100.0),
            cpu / 0.15,
            "15 %",
        ),
        row(
            "start to ready (ms)".into(),
            format!("{:.0}", ready.as_secs_f64() * 1e3),
            ready.as_secs_f64(),
            "1 s",
        ),
    ];
    for (path, p50, p99, bytes) in answers {
        println!(
            "| `GET {path}` ({:.0} KiB) | p50 {:.1} ms, p99 {:.1} ms | < 50 ms |",
            bytes as f64 / 1024.0,
            p50.as_secs_f64() * 1e3,
            p99.as_secs_f64() * 1e3
        );
        rows.push(row(
            format!("`GET {path}` p99 (ms)"),
            format!(
                "{:.1} (p50 {:.1})",
                p99.as_secs_f64() * 1e3,
                p50.as_secs_f64() * 1e3
            ),
            p99.as_secs_f64() / 0.05,
            "50 ms",
        ));
    }
    rows
}
