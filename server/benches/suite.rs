//! iogate against its peers and limits, in one run, as one table of ratios:
//!
//! 1. Emulated serial lines (a device on a pseudo-terminal that answers when the request and
//!    its answer would have crossed the wire, with the device's own 3.5-character silence)
//!    at 9600, 19200 and 115200 baud, FC03 × 10 and × 125 registers: `iogate serve` polling
//!    the device as fast as the line allows, a libmodbus master (C, built here) on the same
//!    kind of line, and the wire limit with every silence kept.
//! 2. A bare pseudo-terminal (the device answers at once): per-transaction time of iogate
//!    (keeping the 1.75 ms silence of a 115200-baud line) against libmodbus's plus that
//!    silence.
//! 3. The precise timer: how late 1.75 ms waits end, against tokio's timer.
//! 4. REST: a whole device (10 fields) and one field against `/livez` on the same server.
//! 5. Fan-out: 1,000 gRPC subscribers (10 connections), 1,000 SSE subscribers and 10,000
//!    gRPC subscribers (40 connections) to one field, a change every 100 ms, from the write
//!    to the last subscriber having it; the gateway's CPU per change.
//! 6. Footprint: resident memory with 10,000 and 50,000 fields.
//!
//! The gateway and libmodbus run in their own processes; devices and clients in this one.
//! Median of `IOGATE_BENCH_ROUNDS` rounds (default 3) for the line figures.
//!
//! `cargo bench -p iogate --bench suite`

use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use iogate::config::{Parity, SerialSettings};
use iogate::link::rtu_frame::crc16;
use iogate::link::timing::LineTiming;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

mod common;
#[path = "parts/fan_out.rs"]
mod fan_out;
#[path = "parts/footprint.rs"]
mod footprint;
#[path = "parts/modbus_server.rs"]
mod modbus_server;
#[path = "parts/scale.rs"]
mod scale;
use common::Row;
use fan_out::{Front, fan_out};
use footprint::footprints;

fn timing(baud: u32) -> LineTiming {
    LineTiming::new(&SerialSettings {
        port: String::new(),
        baud,
        parity: Parity::None,
        data_bits: 8,
        stop_bits: 1,
        framing: Default::default(),
    })
}

/// Waits until `at` on this thread: sleeping until shortly before, then on the clock.
fn wait_until(at: Instant) {
    let margin = Duration::from_micros(300);
    if let Some(sleep) = at.checked_duration_since(Instant::now() + margin) {
        std::thread::sleep(sleep);
    }
    while Instant::now() < at {
        std::hint::spin_loop();
    }
}

/// A Modbus RTU device (slave 1, holding registers) on its own thread, behind a new
/// pseudo-terminal whose other end is opened by path as a real port is. With a line, each
/// answer is written when it would have finished arriving: the request's wire time, the
/// device's silence, the answer's wire time after the request came in.
struct Device {
    path: String,
    answers: Arc<Mutex<Vec<Instant>>>,
    stop: Arc<AtomicBool>,
}

impl Device {
    fn start(line: Option<LineTiming>) -> anyhow::Result<Device> {
        let (tx, rx) = std::sync::mpsc::channel();
        let answers = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (log, done) = (answers.clone(), stop.clone());
        std::thread::spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
            {
                Ok(r) => r,
                Err(e) => return drop(tx.send(Err(e.to_string()))),
            };
            runtime.block_on(async move {
                use tokio_serial::SerialPort;
                let (mut device, holder) = match tokio_serial::SerialStream::pair() {
                    Ok(pair) => pair,
                    Err(e) => return drop(tx.send(Err(e.to_string()))),
                };
                let _ = tx.send(holder.name().ok_or_else(|| "no pty name".to_string()));
                let mut request = [0u8; 8];
                while !done.load(Ordering::Relaxed) {
                    match tokio::time::timeout(
                        Duration::from_millis(100),
                        device.read_exact(&mut request[..1]),
                    )
                    .await
                    {
                        Err(_) => continue,
                        Ok(Err(_)) => return,
                        Ok(Ok(_)) => {}
                    }
                    if device.read_exact(&mut request[1..]).await.is_err() {
                        return;
                    }
                    let arrived = Instant::now();
                    if request[1] != 3 {
                        continue;
                    }
                    let count = u16::from_be_bytes([request[4], request[5]]).min(125);
                    let mut answer = vec![request[0], 3, (count * 2) as u8];
                    for i in 0..count {
                        answer.extend_from_slice(&i.to_be_bytes());
                    }
                    answer.extend_from_slice(&crc16(&answer).to_le_bytes());
                    if let Some(line) = line {
                        wait_until(
                            arrived
                                + line.frame_time(request.len())
                                + line.silence()
                                + line.frame_time(answer.len()),
                        );
                    }
                    if device.write_all(&answer).await.is_err() {
                        return;
                    }
                    if let Ok(mut log) = log.lock() {
                        log.push(Instant::now());
                    }
                }
                drop(holder);
            });
        });
        let path = rx.recv()?.map_err(|e| anyhow::anyhow!("device: {e}"))?;
        Ok(Device {
            path,
            answers,
            stop,
        })
    }

    fn answered(&self) -> usize {
        self.answers.lock().map(|a| a.len()).unwrap_or(0)
    }

    /// Transactions per second from the answers' times, skipping the first `skip`.
    fn rate(&self, skip: usize) -> f64 {
        let answers = self.answers.lock().map(|a| a.clone()).unwrap_or_default();
        let times = &answers[skip.min(answers.len())..];
        if times.len() < 2 {
            return 0.0;
        }
        (times.len() - 1) as f64 / (times[times.len() - 1] - times[0]).as_secs_f64()
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// The wire limit for FC03 of `registers` at `baud`: an 8-byte request, its answer, and the
/// silence before each, in transactions per second.
fn limit_tps(baud: u32, registers: u16) -> f64 {
    1.0 / timing(baud)
        .transaction_time(8, 5 + 2 * usize::from(registers))
        .as_secs_f64()
}

/// How long to measure a line: 2 s and at least 12 transactions at the wire limit.
fn window(limit_tps: f64) -> Duration {
    Duration::from_secs_f64((12.0 / limit_tps).max(2.0))
}

/// A `profiles` directory in `dir`, apart from the config written beside it.
fn profiles_dir(dir: &Path) -> anyhow::Result<std::path::PathBuf> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    Ok(profiles)
}

fn write_profile(dir: &Path, registers: u16) -> anyhow::Result<()> {
    let mut profile = format!("name: Regs{registers}\nfields:\n");
    for i in 0..registers {
        profile.push_str(&format!(
            "  - {{ name: R{i}, type: UINT, direction: input, register: {{ address: {i}, kind: holding_register }} }}\n"
        ));
    }
    std::fs::write(dir.join(format!("regs{registers}.yaml")), profile)?;
    Ok(())
}

/// `iogate serve` polling the device every millisecond (more than the line carries).
fn iogate_on_line(baud: u32, registers: u16, line: Option<LineTiming>) -> anyhow::Result<f64> {
    let device = Device::start(line)?;
    let dir = common::temp_dir(&format!("line-{baud}-{registers}"))?;
    let profiles = profiles_dir(&dir)?;
    write_profile(&profiles, registers)?;
    let _gateway = common::start(
        &dir,
        &format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\nlinks:\n  - {{ name: bus, serial: {{ port: {}, baud: {baud} }} }}\ndevices:\n  - {{ name: d, profile: Regs{registers}, link: bus, slave_id: 1, refresh_rate: 1ms, timeout: 1s }}\n",
            profiles.display(),
            device.path
        ),
    )?;
    let limit = limit_tps(baud, registers);
    let warm = device.answered();
    let deadline = Instant::now() + Duration::from_secs(10);
    while device.answered() < warm + 3 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(10));
    }
    let skip = device.answered();
    std::thread::sleep(window(limit));
    Ok(device.rate(skip))
}

/// The libmodbus master on the same kind of device.
fn libmodbus_on_line(
    program: &Path,
    baud: u32,
    registers: u16,
    line: Option<LineTiming>,
) -> anyhow::Result<f64> {
    let device = Device::start(line)?;
    let limit = limit_tps(baud, registers);
    let output = Command::new(program)
        .arg(&device.path)
        .arg(baud.to_string())
        .arg(registers.to_string())
        .arg(format!("{:.3}", window(limit).as_secs_f64()))
        .output()?;
    anyhow::ensure!(
        output.status.success(),
        "libmodbus master: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    // The first answer is the untimed one.
    Ok(device.rate(1))
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

fn lines(rounds: usize, rows: &mut Vec<Row>) -> anyhow::Result<()> {
    let libmodbus = common::build_peer("rtu_master");
    if libmodbus.is_none() {
        println!("(libmodbus not built: install gcc, pkg-config and libmodbus-dev to compare)");
    }
    for baud in [9600, 19_200, 115_200] {
        for registers in [10u16, 125] {
            let line = timing(baud);
            let limit = limit_tps(baud, registers);
            let mut ours = Vec::new();
            let mut theirs = Vec::new();
            for _ in 0..rounds {
                ours.push(iogate_on_line(baud, registers, Some(line))?);
                if let Some(program) = &libmodbus {
                    theirs.push(libmodbus_on_line(program, baud, registers, Some(line))?);
                }
            }
            let ours = median(ours);
            let peer = if theirs.is_empty() {
                format!("limit {limit:.1}")
            } else {
                format!(
                    "limit {limit:.1}; libmodbus {:.1} (skips the silence)",
                    median(theirs)
                )
            };
            println!("FC03 x{registers} at {baud} 8N1: iogate {ours:.1} tps, {peer}");
            rows.push(Row {
                measure: format!("FC03 x{registers} at {baud} 8N1, emulated line (tps)"),
                iogate: format!("{ours:.1}"),
                peer,
                ratio: ours / limit,
                goal: "≥ 0.98 of the limit".into(),
            });
        }
    }
    // A bare pty: the per-transaction time against libmodbus's plus the silence.
    if let Some(program) = &libmodbus {
        let silence = timing(115_200).silence().as_secs_f64();
        let mut ours = Vec::new();
        let mut theirs = Vec::new();
        for _ in 0..rounds {
            ours.push(1.0 / iogate_on_line(115_200, 10, None)?);
            theirs.push(1.0 / libmodbus_on_line(program, 115_200, 10, None)?);
        }
        let (ours, theirs) = (median(ours), median(theirs));
        println!(
            "bare pty, FC03 x10: iogate {:.0} µs (115200 silences), libmodbus {:.0} µs",
            ours * 1e6,
            theirs * 1e6
        );
        rows.push(Row {
            measure: "FC03 x10 on a bare pty, µs per transaction".into(),
            iogate: format!("{:.0} (1.75 ms silence kept)", ours * 1e6),
            peer: format!(
                "libmodbus {:.0} + silence 1750 = {:.0}",
                theirs * 1e6,
                (theirs + silence) * 1e6
            ),
            ratio: ours / (theirs + silence),
            goal: "≤ 1.00".into(),
        });
    }
    Ok(())
}

/// Lateness of 1.75 ms waits (the silence of a fast line), in µs at the median and p99:
/// `link::precise::Timer`, its timerfd alone, and tokio's timer.
async fn timer(rows: &mut Vec<Row>) -> anyhow::Result<()> {
    use iogate::link::precise::Timer;
    use tokio::time::Instant;
    const WAIT: Duration = Duration::from_micros(1750);
    async fn lateness(mut wait: impl AsyncFnMut(Instant)) -> (u128, u128) {
        let mut late = Vec::new();
        for _ in 0..500 {
            let deadline = Instant::now() + WAIT;
            wait(deadline).await;
            late.push(deadline.elapsed().as_micros());
        }
        late.sort();
        (late[250], late[495])
    }
    let mut t = Timer::new();
    let precise = lateness(async |d| t.sleep_until(d).await).await;
    let fd_alone = lateness(async |d| t.sleep_until_coarse(d).await).await;
    let tokio = lateness(async |d| tokio::time::sleep_until(d).await).await;
    println!(
        "1.75 ms waits, µs late (p50/p99): Timer {precise:?}, timerfd alone {fd_alone:?}, tokio {tokio:?}"
    );
    rows.push(Row {
        measure: "1.75 ms wait, µs late, p50 / p99".into(),
        iogate: format!("{} / {}", precise.0, precise.1),
        peer: format!(
            "tokio timer {} / {}; timerfd alone {} / {}",
            tokio.0, tokio.1, fd_alone.0, fd_alone.1
        ),
        ratio: precise.1 as f64 / 100.0,
        goal: "p99 ≤ 100 µs (ratio to 100 µs)".into(),
    });
    Ok(())
}

const REST_CONNECTIONS: usize = 64;
const REST_SLICE: Duration = Duration::from_secs(1);
const REST_SLICES: usize = 5;

async fn rest(rows: &mut Vec<Row>) -> anyhow::Result<()> {
    let dir = common::temp_dir("suite-rest")?;
    let profiles = profiles_dir(&dir)?;
    // Ten fields: four REAL, three INT, two BOOL, one STRING; inputs and outputs.
    let mut ten = String::from("name: Ten\nprotocol: simulated\nfields:\n");
    for (i, (ty, direction)) in [
        ("REAL", "input"),
        ("REAL", "input"),
        ("REAL", "output"),
        ("REAL", "input"),
        ("INT", "input"),
        ("INT", "output"),
        ("INT", "input"),
        ("BOOL", "input"),
        ("BOOL", "output"),
        ("STRING", "input"),
    ]
    .iter()
    .enumerate()
    {
        ten.push_str(&format!(
            "  - {{ name: F{i}, type: {ty}, direction: {direction}, register: {{ address: {i}, kind: virtual }} }}\n"
        ));
    }
    std::fs::write(profiles.join("ten.yaml"), ten)?;
    let gateway = common::start(
        &dir,
        &format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n  - {{ name: ten, profile: Ten, refresh_rate: 100ms }}\n",
            profiles.display()
        ),
    )?;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let addr = gateway.http;
    // Slices of each request in turn, so that a machine whose speed drifts during the run
    // (a shared one) weighs on all three alike; the median slice of each.
    let rate = |path| common::http::rate(addr, path, REST_CONNECTIONS, REST_SLICE);
    let (mut livez, mut device, mut field) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..REST_SLICES {
        livez.push(rate("/livez").await?);
        device.push(rate("/api/v1/devices/ten").await?);
        field.push(rate("/api/v1/devices/ten/fields/F0").await?);
    }
    let (livez, device, field) = (median(livez), median(device), median(field));
    println!("REST: /livez {livez:.0} req/s, device {device:.0}, field {field:.0}");
    for (what, r, goal) in [
        (
            "GET /api/v1/devices/ten (10 fields), req/s",
            device,
            "≥ 0.60",
        ),
        ("GET /api/v1/devices/ten/fields/F0, req/s", field, "≥ 0.85"),
    ] {
        rows.push(Row {
            measure: what.into(),
            iogate: format!("{r:.0}"),
            peer: format!("/livez {livez:.0}"),
            ratio: r / livez,
            goal: goal.into(),
        });
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let rounds = std::env::var("IOGATE_BENCH_ROUNDS")
        .ok()
        .and_then(|r| r.parse().ok())
        .unwrap_or(3usize)
        .max(1);
    let only = std::env::var("IOGATE_BENCH_ONLY").unwrap_or_default();
    let wanted = |part: &str| only.is_empty() || only.split(',').any(|o| o == part);
    let mut rows = Vec::new();
    if wanted("lines") {
        lines(rounds, &mut rows)?;
    }
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        if wanted("timer") {
            timer(&mut rows).await?;
        }
        if wanted("rest") {
            rest(&mut rows).await?;
        }
        if wanted("fanout") {
            rows.push(fan_out(Front::Grpc { per_channel: 100 }, 1000).await?);
            rows.push(fan_out(Front::Sse, 1000).await?);
            rows.push(fan_out(Front::Grpc { per_channel: 250 }, 10_000).await?);
        }
        anyhow::Ok(())
    })?;
    if wanted("footprint") {
        footprints(&mut rows)?;
    }
    if wanted("modbus_server") {
        rows.extend(modbus_server::run(&runtime)?);
    }
    if wanted("scale") {
        rows.extend(scale::run(&runtime)?);
    }
    println!();
    common::print_table(&rows);
    Ok(())
}
