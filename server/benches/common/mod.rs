//! `iogate serve` in its own process for the benchmarks: a config written to a temporary
//! directory, the listeners' addresses read from what the gateway prints, the process
//! killed when the handle is dropped.

pub mod http;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

/// A running gateway and where it listens (not every bench uses every listener).
#[allow(dead_code)]
pub struct Gateway {
    pub child: Child,
    pub http: SocketAddr,
    pub grpc: SocketAddr,
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The repository's `profiles/`.
#[allow(dead_code)]
pub fn profiles() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../profiles")
}

/// A fresh temporary directory for bench `name`.
pub fn temp_dir(name: &str) -> anyhow::Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("iogate-bench-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// Starts `iogate serve` on `config` (written to `dir`); its HTTP and gRPC listeners should
/// be on port 0, and are found in its output.
pub fn start(dir: &Path, config: &str) -> anyhow::Result<Gateway> {
    let path = dir.join("iogate.yaml");
    std::fs::write(&path, config)?;
    let mut child = Command::new(env!("CARGO_BIN_EXE_iogate"))
        .args(["serve", "--config"])
        .arg(&path)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()?;
    let stdout = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(stdout));
    let (mut http, mut grpc) = (None, None);
    while http.is_none() || grpc.is_none() {
        let line = lines
            .next()
            .ok_or_else(|| anyhow::anyhow!("the gateway ended"))??;
        if let Some(rest) = line.strip_prefix("REST API:") {
            let addr = rest.trim().trim_start_matches("http://");
            http = addr.split('/').next().and_then(|a| a.parse().ok());
        } else if let Some(rest) = line.strip_prefix("gRPC:") {
            grpc = rest.split_whitespace().next().and_then(|a| a.parse().ok());
        }
    }
    std::thread::spawn(move || for _ in lines {});
    Ok(Gateway {
        http: http.ok_or_else(|| anyhow::anyhow!("no HTTP address"))?,
        grpc: grpc.ok_or_else(|| anyhow::anyhow!("no gRPC address"))?,
        child,
    })
}

/// Builds the C program `benches/peer/{name}.c` against libmodbus (after
/// `benches/peer/install.sh` has installed the compiler and the library when missing);
/// `None` when that cannot be done here.
#[allow(dead_code)]
pub fn build_peer(name: &str) -> Option<PathBuf> {
    let peer = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("benches/peer");
    let _ = Command::new("bash")
        .arg(peer.join("install.sh"))
        .stdout(Stdio::null())
        .status();
    let out = std::env::temp_dir().join(format!("iogate-peer-{name}-{}", std::process::id()));
    let flags = Command::new("pkg-config")
        .args(["--cflags", "--libs", "libmodbus"])
        .output()
        .ok()
        .filter(|o| o.status.success())?;
    let flags = String::from_utf8_lossy(&flags.stdout).to_string();
    let built = Command::new("cc")
        .arg("-O2")
        .arg(peer.join(format!("{name}.c")))
        .arg("-o")
        .arg(&out)
        .args(flags.split_whitespace())
        .status()
        .ok()?;
    built.success().then_some(out)
}

/// Resident memory of process `pid` in KiB (0 when it cannot be read).
#[allow(dead_code)]
pub fn rss_kib(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|n| n.parse().ok()))
        })
        .unwrap_or(0)
}

/// CPU time (user + system) process `pid` has used, in seconds (10 ms steps).
#[allow(dead_code)]
pub fn cpu_seconds(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|stat| {
            // After the command's name in parentheses: state is field 3, utime 14, stime 15.
            let rest = stat.rsplit_once(')')?.1;
            let fields: Vec<&str> = rest.split_whitespace().collect();
            let ticks: f64 =
                fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
            Some(ticks / 100.0)
        })
        .unwrap_or(0.0)
}

/// Serves `device` (a tokio-modbus service, cloned for each master) on a free loopback
/// port, as a Modbus TCP device independent of the gateway; answers the port.
#[allow(dead_code)]
pub async fn modbus_device<S>(device: S) -> anyhow::Result<u16>
where
    S: tokio_modbus::server::Service<
            Request = tokio_modbus::prelude::SlaveRequest<'static>,
            Response = tokio_modbus::prelude::Response,
            Exception = tokio_modbus::prelude::ExceptionCode,
        > + Clone
        + Send
        + Sync
        + 'static,
    S::Future: Send,
{
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let port = listener.local_addr()?.port();
    let server = tokio_modbus::server::tcp::Server::new(listener);
    tokio::spawn(async move {
        let on_connected = move |stream, addr| {
            let device = device.clone();
            async move {
                tokio_modbus::server::tcp::accept_tcp_connection(stream, addr, move |_| {
                    Ok(Some(device.clone()))
                })
            }
        };
        let _ = server.serve(&on_connected, |_| {}).await;
    });
    Ok(port)
}

/// A free loopback port (bound, then let go).
#[allow(dead_code)]
pub fn free_port() -> anyhow::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}

/// A row of the suite's table: what was measured, iogate's figure, the peer's or the limit,
/// their ratio and the goal for it.
#[allow(dead_code)]
pub struct Row {
    pub measure: String,
    pub iogate: String,
    pub peer: String,
    pub ratio: f64,
    pub goal: String,
}

/// Prints `rows` as one Markdown table.
#[allow(dead_code)]
pub fn print_table(rows: &[Row]) {
    println!("| measure | iogate | peer or limit | ratio | goal |");
    println!("| --- | --- | --- | --- | --- |");
    for r in rows {
        println!(
            "| {} | {} | {} | {:.2} | {} |",
            r.measure, r.iogate, r.peer, r.ratio, r.goal
        );
    }
}

#[allow(dead_code)]
#[path = "../../tests/common/python.rs"]
mod python;
#[allow(unused_imports)]
pub use python::python;
