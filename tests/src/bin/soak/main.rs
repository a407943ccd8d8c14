//! The soak: a release gateway in its own process with every link kind (RTU on a
//! pseudo-terminal, Modbus TCP, S7, OPC UA) and every front-end (REST, SSE, gRPC, the
//! Modbus server, MQTT through Mosquitto, the OPC UA server) busy at once for a chosen time,
//! writes going on, a fault every minute, and a report of what users would have lost:
//! wrong values, writes lost or out of order, memory and open files over time, `/readyz`
//! that lied. Run with `bash soak/run.sh MINUTES`; not part of the tests.
//!
//!     soak [--minutes M] [--fault-every SECONDS]

mod doors;
mod faults;
mod field;
mod gauge;
mod report;
mod tally;
mod writes;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iogate_tests::GatewayProcess;
use iogate_tests::mqtt::Broker;
use tokio_util::sync::CancellationToken;

use crate::doors::Ctx;
use crate::field::{Cable, Line, Plcs};

struct Args {
    minutes: f64,
    fault_every: Duration,
}

fn args() -> anyhow::Result<Args> {
    let mut a = Args {
        minutes: 10.0,
        fault_every: Duration::from_secs(60),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let value = it
            .next()
            .ok_or_else(|| anyhow::anyhow!("{flag} needs a value"))?;
        match flag.as_str() {
            "--minutes" => a.minutes = value.parse()?,
            "--fault-every" => a.fault_every = Duration::from_secs(value.parse()?),
            _ => anyhow::bail!("usage: soak [--minutes M] [--fault-every SECONDS]"),
        }
    }
    Ok(a)
}

/// The gateway's config; `n` changes a refresh rate (what a reload applies).
fn config(dir: &Path, line: &Line, cable: &Cable, plcs: &Plcs, broker: u16, n: u32) -> String {
    let refresh = if n.is_multiple_of(2) { 50 } else { 60 };
    let mut c = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {profiles}\nlinks:\n\
         \x20 - {{ name: rs485, serial: {{ port: {port}, baud: 115200 }} }}\n\
         \x20 - {{ name: plc, tcp: {{ host: 127.0.0.1, port: {tcp} }} }}\n\
         \x20 - name: s7\n    s7: {{ host: 127.0.0.1, port: {s7}, timeout: 1s }}\n\
         \x20 - name: ua\n    opcua: {{ url: \"opc.tcp://127.0.0.1:{ua}/plc\", pki_dir: {pki} }}\n\
         devices:\n",
        profiles = dir.join("profiles").display(),
        port = line.port.display(),
        tcp = cable.port,
        s7 = plcs.s7.port,
        ua = plcs.ua_port,
        pki = dir.join("pki-client").display(),
    );
    for s in field::SLAVES {
        c.push_str(&format!(
            "  - {{ name: rtu{s}, profile: SoakReg, link: rs485, slave_id: {s}, refresh_rate: 100ms, timeout: 50ms }}\n"
        ));
    }
    c.push_str(&format!(
        "  - {{ name: tcp1, profile: SoakReg, link: plc, slave_id: 1, refresh_rate: {refresh}ms }}\n\
         \x20 - {{ name: press, profile: SoakS7, link: s7, refresh_rate: 100ms }}\n\
         \x20 - {{ name: line1, profile: SoakUa, link: ua, refresh_rate: 100ms }}\n\
         modbus_server: {{ listen: 127.0.0.1:0, auto: true }}\n\
         mqtt:\n  url: mqtt://127.0.0.1:{broker}\n  json: {{ prefix: soak }}\n  buffer: {{ dir: buffer }}\n  reconnect_max: 1s\n\
         opcua:\n  listen: 127.0.0.1:0\n  pki_dir: {}\n",
        dir.join("pki-server").display()
    ));
    c
}

/// Where the gateway's server `name` listens, from `GET /api/v1/config`.
async fn listening(gw: &iogate_tests::TestGateway, name: &str) -> anyhow::Result<String> {
    let (_, status) = gw.get("/api/v1/config").await?;
    status["listening"]
        .as_array()
        .and_then(|l| l.iter().find(|s| s["server"] == name))
        .and_then(|s| s["address"].as_str())
        .map(str::to_owned)
        .ok_or_else(|| anyhow::anyhow!("no {name} server in {status}"))
}

/// The field side and the gateway's config file.
struct Rig {
    dir: PathBuf,
    path: PathBuf,
    line: Line,
    cable: Arc<Cable>,
    plcs: Plcs,
    broker: Broker,
}

impl Rig {
    async fn start() -> anyhow::Result<Rig> {
        iogate_tests::mqtt::install()?;
        let dir = iogate_tests::devices::temp_dir("soak");
        let rig = Rig {
            path: dir.join("iogate.yaml"),
            line: Line::new(&dir),
            cable: Arc::new(Cable::new().await?),
            plcs: Plcs::start().await?,
            broker: Broker::start().await?,
            dir,
        };
        let ns = rig.plcs.ua.as_ref().map_or(2, |p| p.ns);
        std::fs::create_dir_all(rig.dir.join("profiles"))?;
        for (file, text) in field::profiles(ns) {
            std::fs::write(rig.dir.join("profiles").join(file), text)?;
        }
        std::fs::write(&rig.path, rig.config(0))?;
        Ok(rig)
    }

    fn config(&self, n: u32) -> String {
        let port = self.broker.port;
        config(&self.dir, &self.line, &self.cable, &self.plcs, port, n)
    }

    /// Faults in turn until `end` is near.
    async fn faults(&mut self, ctx: &Ctx, args: &Args, started: Instant, end: Instant) {
        let mut n = 0;
        while Instant::now() + args.fault_every < end {
            tokio::time::sleep(args.fault_every / 2).await;
            let snapshot = self.config(n + 1);
            let config_text = move |_: u32| snapshot.clone();
            let mut f = faults::Field {
                line: &mut self.line,
                cable: &self.cable,
                plcs: &mut self.plcs,
                broker: &mut self.broker,
                config: &self.path,
                config_text: &config_text,
            };
            faults::inject(ctx, &mut f, n, args.fault_every / 3).await;
            n += 1;
            report::progress(ctx, started, n);
            tokio::time::sleep(args.fault_every / 6).await;
        }
        if let Some(rest) = end.checked_duration_since(Instant::now()) {
            tokio::time::sleep(rest).await;
        }
    }
}

/// The clients at every door, started.
async fn clients(ctx: &Ctx, rig: &Rig) -> anyhow::Result<tokio::task::JoinSet<()>> {
    let mut tasks = tokio::task::JoinSet::new();
    tasks.spawn(doors::rest(ctx.clone()));
    tasks.spawn(doors::sse(ctx.clone()));
    tasks.spawn(doors::grpc(ctx.clone()));
    let modbus = listening(&ctx.gw, "modbus").await?;
    tasks.spawn(doors::modbus(ctx.clone(), modbus));
    tasks.spawn(doors::mqtt(ctx.clone(), rig.broker.port));
    tasks.spawn(doors::opcua(
        ctx.clone(),
        listening(&ctx.gw, "opcua").await?,
    ));
    Ok(tasks)
}

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    let args = args()?;
    let mut rig = Rig::start().await?;
    let bin = std::env::current_exe()?.with_file_name("gateway");
    let gateway = GatewayProcess::start_file(&bin.to_string_lossy(), &rig.path).await?;
    let pid = gateway.pid().ok_or_else(|| anyhow::anyhow!("no pid"))?;
    rig.line.plug()?;
    let base = gateway.gateway.base.clone();
    eprintln!(
        "gateway at {base} (pid {pid}), files in {}",
        rig.dir.display()
    );
    let mut gw = iogate_tests::TestGateway::remote(base);
    gw.grpc = format!("http://{}", listening(&gw, "grpc").await?);
    let ctx = Ctx {
        gw: Arc::new(gw),
        expected: Arc::new(field::expected()),
        tally: Arc::default(),
        stop: CancellationToken::new(),
    };
    let targets = writes::Targets {
        cable: rig.cable.clone(),
        bus: rig.line.bus.clone(),
        rtu: Arc::default(),
    };
    let mut tasks = clients(&ctx, &rig).await?;
    let gauge = tokio::spawn(gauge::watch(ctx.clone(), pid));
    let writer = tokio::spawn(writes::writer(ctx.clone(), targets.clone()));
    let started = Instant::now();
    let end = started + Duration::from_secs_f64(args.minutes * 60.0);
    rig.faults(&ctx, &args, started, end).await;
    ctx.stop.cancel();
    let last = writer.await.unwrap_or(0);
    // Every fault undone: the last writes reach their devices.
    tokio::time::sleep(Duration::from_secs(10)).await;
    writes::verify(&ctx, last, &targets);
    let samples = gauge.await.unwrap_or_default();
    report::links(&ctx).await;
    while tasks.join_next().await.is_some() {}
    let ok = report::print(&ctx, started.elapsed(), &samples);
    gateway.kill().await?;
    if ok {
        Ok(())
    } else {
        anyhow::bail!("the soak found what users would lose")
    }
}
