//! Fixtures for the end-to-end tests: a gateway started on port 0 from real YAML files.

use std::path::{Path, PathBuf};
use std::time::Duration;

use iogate::app::{self, Running, Setup};

pub mod arbiters;
pub mod bacnet;
pub mod browser;
pub mod cable;
pub mod devices;
pub mod eip;
pub mod iec104;
pub mod line;
pub mod mqtt;
pub mod node_ua;
pub mod opcua;
pub mod pki;
pub mod plc;
pub mod process;
pub mod s7;
mod started;
pub mod tap;
pub mod udp_cable;
pub mod wireshark;

pub use started::{
    OnBus, SseReader, bus_gateway, bus_gateway_with, config_files, eventually, link_yaml,
    start_file,
};

/// How long a test waits for what it needs (a condition, a message, an answer) before it
/// fails. The waits end as soon as what they wait for comes: this is a bound against a
/// hang, not a timing, so it is generous, as a loaded machine (a build beside the tests,
/// two cores) can take many times the usual for a broker's restart and a client's
/// reconnect.
pub const PATIENCE: Duration = Duration::from_secs(60);

/// A file of the tests crate (`tests/` in the repository): a peer's script, an installer.
pub fn repo_file(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// Runs one of the tests crate's installers (`mqtt/install.sh`, ...), which install a
/// peer when it is missing and do nothing otherwise.
pub fn run_installer(script: &str) -> anyhow::Result<()> {
    let status = std::process::Command::new("bash")
        .arg(repo_file(script))
        .status()
        .map_err(|e| anyhow::anyhow!("running tests/{script}: {e}"))?;
    anyhow::ensure!(status.success(), "tests/{script} failed: {status}");
    Ok(())
}

/// The tests' own Python (`tests/.venv`, made once from `tests/python/requirements.txt` by
/// `tests/python/venv.sh`), which runs every Python peer; the user's own Python is not used.
pub fn python() -> PathBuf {
    static MADE: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    MADE.get_or_init(|| {
        let out = std::process::Command::new("bash")
            .arg(repo_file("python/venv.sh"))
            .stderr(std::process::Stdio::inherit())
            .output()
            .expect("running tests/python/venv.sh");
        assert!(
            out.status.success(),
            "tests/python/venv.sh failed: {}",
            out.status
        );
        PathBuf::from(String::from_utf8_lossy(&out.stdout).trim())
    })
    .clone()
}

/// A helper process (one of the tests' Python peers) talking one line at a time: its
/// handle (killed when dropped), its standard input, and its standard output's lines.
pub struct Piped {
    pub child: tokio::process::Child,
    pub stdin: tokio::process::ChildStdin,
    pub lines: tokio::io::Lines<tokio::io::BufReader<tokio::process::ChildStdout>>,
}

/// Starts `command` with piped standard input and output.
pub fn spawn_piped(mut command: tokio::process::Command) -> anyhow::Result<Piped> {
    use tokio::io::AsyncBufReadExt;
    let mut child = command
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()?;
    let stdin = child.stdin.take().ok_or_else(|| anyhow::anyhow!("stdin"))?;
    let stdout = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("stdout"))?;
    Ok(Piped {
        child,
        stdin,
        lines: tokio::io::BufReader::new(stdout).lines(),
    })
}

/// The repository's `profiles/` directory.
pub fn profiles_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../profiles")
}

/// The directory of test fixtures.
pub fn fixtures_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

/// A gateway running in this process, serving HTTP on a free loopback port.
/// What tests may declare at run time: the usual serial ports, the tests' pseudo-terminals
/// (under the temporary directory) and missing paths, and loopback TCP.
pub fn test_policy() -> iogate::config::security::DeclarePolicy {
    let mut policy = iogate::config::security::DeclarePolicy::default();
    policy
        .serial_ports
        .push(format!("{}/*", std::env::temp_dir().display()));
    policy.serial_ports.push("/nonexistent/*".into());
    policy.tcp_hosts = iogate::config::security::HostRule::parse("127.0.0.0/8")
        .into_iter()
        .collect();
    policy
}

/// The setup of a test gateway from config text: loopback listeners on free ports, the
/// repository's profiles unless the config names its own, the tests' declare policy.
pub fn test_setup(config_yaml: &str) -> anyhow::Result<Setup> {
    setup_on(config_yaml, "127.0.0.1:0".parse()?)
}

fn setup_on(config_yaml: &str, http: std::net::SocketAddr) -> anyhow::Result<Setup> {
    iogate::drivers::register();
    let mut config =
        iogate::config::parse("test.yaml", config_yaml).map_err(|p| anyhow::anyhow!("{p}"))?;
    config.http = http;
    config.grpc = "127.0.0.1:0".parse()?;
    if let Some(server) = config.modbus_server.as_mut()
        && server.listen.is_some()
    {
        server.listen = Some("127.0.0.1:0".parse()?);
    }
    if config.security == iogate::config::security::SecurityConfig::default() {
        config.security.declare = test_policy();
    }
    if config.profiles.is_none() {
        config.profiles = Some(profiles_dir());
    }
    Setup::from_config(config, Path::new(".")).map_err(|p| anyhow::anyhow!("{p}"))
}

/// A gateway in a process of its own (the tests crate's `gateway` binary), so that a test
/// can kill it as the operating system would.
pub struct GatewayProcess {
    child: tokio::process::Child,
    pub gateway: TestGateway,
}

impl GatewayProcess {
    /// Starts `bin` (the `gateway` binary's path) on `config_yaml`, written to `dir`, and
    /// waits until it is ready.
    pub async fn start(bin: &str, dir: &Path, config_yaml: &str) -> anyhow::Result<Self> {
        let path = dir.join("iogate.yaml");
        std::fs::write(&path, config_yaml)?;
        GatewayProcess::spawn(tokio::process::Command::new(bin).arg(&path)).await
    }

    /// Starts `bin` on the config file at `path` as it is (its own listeners; reloads
    /// read it again), and waits until it is ready.
    pub async fn start_file(bin: &str, path: &Path) -> anyhow::Result<Self> {
        GatewayProcess::spawn(tokio::process::Command::new(bin).arg("--file").arg(path)).await
    }

    async fn spawn(command: &mut tokio::process::Command) -> anyhow::Result<Self> {
        use tokio::io::AsyncBufReadExt;
        let mut child = command
            .stdout(std::process::Stdio::piped())
            .kill_on_drop(true)
            .spawn()?;
        let stdout = child
            .stdout
            .take()
            .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
        let mut lines = tokio::io::BufReader::new(stdout).lines();
        let line = tokio::time::timeout(PATIENCE, lines.next_line())
            .await
            .map_err(|_| anyhow::anyhow!("the gateway process did not start"))??
            .ok_or_else(|| anyhow::anyhow!("the gateway process ended"))?;
        let addr = line
            .strip_prefix("http ")
            .ok_or_else(|| anyhow::anyhow!("unexpected first line: {line}"))?;
        let gateway = TestGateway::remote(format!("http://{addr}"));
        gateway.until_ready().await?;
        Ok(GatewayProcess { child, gateway })
    }

    /// The process id (for its CPU time and resident size in `/proc`).
    pub fn pid(&self) -> Option<u32> {
        self.child.id()
    }

    /// SIGKILL: no shutdown, nothing flushed, the sockets closed by the kernel.
    pub async fn kill(mut self) -> anyhow::Result<()> {
        self.child.kill().await?;
        Ok(())
    }
}

pub struct TestGateway {
    pub base: String,
    /// The gRPC endpoint, e.g. `http://127.0.0.1:40123`.
    pub grpc: String,
    pub client: reqwest::Client,
    /// The Modbus TCP server's address, when the config has one.
    pub modbus: Option<std::net::SocketAddr>,
    /// The OPC UA server's address, when the config has one.
    pub opcua: Option<std::net::SocketAddr>,
    /// The IEC 104 outstation's address, when the config has one.
    pub iec104: Option<std::net::SocketAddr>,
    running: Option<Running>,
}

impl TestGateway {
    /// Starts the gateway from config text, with the repository's profiles.
    pub async fn start(config_yaml: &str) -> anyhow::Result<TestGateway> {
        TestGateway::start_on(config_yaml, "127.0.0.1:0".parse()?).await
    }

    /// Starts the gateway from config text with its HTTP listener on `http` (a restart on
    /// the port a previous gateway had).
    pub async fn start_on(
        config_yaml: &str,
        http: std::net::SocketAddr,
    ) -> anyhow::Result<TestGateway> {
        TestGateway::start_setup(setup_on(config_yaml, http)?).await
    }

    /// Waits until `/readyz` answers 200.
    async fn until_ready(&self) -> anyhow::Result<()> {
        let ready = self.url("/readyz");
        let client = self.client.clone();
        eventually("gateway ready", || {
            let ready = ready.clone();
            let client = client.clone();
            async move {
                client
                    .get(&ready)
                    .send()
                    .await
                    .is_ok_and(|r| r.status().is_success())
            }
        })
        .await
    }

    /// A gateway running in another process (see [`GatewayProcess`]), asked over HTTP.
    pub fn remote(base: String) -> TestGateway {
        TestGateway {
            base,
            grpc: String::new(),
            client: reqwest::Client::new(),
            modbus: None,
            opcua: None,
            iec104: None,
            running: None,
        }
    }

    /// Starts the built-in demo's simulated devices (`sim` and `plant`) and servers, without
    /// its field line (the tests that use it declare links and devices of their own).
    pub async fn demo() -> anyhow::Result<TestGateway> {
        let setup = Setup::demo_simulated().map_err(|p| anyhow::anyhow!("{p}"))?;
        TestGateway::start_demo(setup).await
    }

    /// Starts the built-in demo as shipped: its field line with the simulated meter and I/O
    /// module as well.
    pub async fn demo_as_shipped() -> anyhow::Result<TestGateway> {
        let setup = Setup::demo().map_err(|p| anyhow::anyhow!("{p}"))?;
        TestGateway::start_demo(setup).await
    }

    /// Starts a demo setup on free ports.
    async fn start_demo(mut setup: Setup) -> anyhow::Result<TestGateway> {
        setup.config.http = "127.0.0.1:0".parse()?;
        setup.config.grpc = "127.0.0.1:0".parse()?;
        if let Some(server) = setup.config.modbus_server.as_mut()
            && server.listen.is_some()
        {
            server.listen = Some("127.0.0.1:0".parse()?);
        }
        if let Some(opcua) = setup.config.sections.listen_mut("opcua") {
            *opcua = "127.0.0.1:0".parse()?;
        }
        setup.config.security.declare = test_policy();
        TestGateway::start_setup(setup).await
    }

    /// Starts the gateway from a checked setup (a config file's, say).
    pub async fn start_setup(setup: Setup) -> anyhow::Result<TestGateway> {
        // Logs show with `RUST_LOG=iogate=debug cargo test -- --nocapture`.
        let _ = tracing_subscriber::fmt()
            .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
            .with_test_writer()
            .try_init();
        let running = app::start(setup).await?;
        let gateway = TestGateway {
            base: format!("http://{}", running.http_addr),
            grpc: format!("http://{}", running.grpc_addr),
            client: reqwest::Client::new(),
            modbus: running.modbus_addr,
            opcua: running.bound("opcua"),
            iec104: running.bound("iec104"),
            running: Some(running),
        };
        gateway.until_ready().await?;
        Ok(gateway)
    }

    /// A gRPC client connected to the gateway.
    pub async fn client(&self) -> anyhow::Result<iogate_client::Client> {
        Ok(iogate_client::Client::connect(&self.grpc).await?)
    }

    pub fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    /// GET a path; answers the status and JSON body.
    pub async fn get(&self, path: &str) -> anyhow::Result<(u16, serde_json::Value)> {
        let response = self.client.get(self.url(path)).send().await?;
        json_of(response).await
    }

    /// Sends a body with a method; answers the status and JSON body.
    pub async fn send(
        &self,
        method: reqwest::Method,
        path: &str,
        body: impl Into<reqwest::Body>,
    ) -> anyhow::Result<(u16, serde_json::Value)> {
        let response = self
            .client
            .request(method, self.url(path))
            .header("content-type", "application/json")
            .body(body)
            .send()
            .await?;
        json_of(response).await
    }

    /// Waits until the JSON at `path` satisfies `check`; answers that JSON.
    pub async fn until(
        &self,
        path: &str,
        what: &str,
        check: impl Fn(&serde_json::Value) -> bool,
    ) -> anyhow::Result<serde_json::Value> {
        let deadline = tokio::time::Instant::now() + PATIENCE;
        loop {
            let last = self.get(path).await;
            if let Ok((200, body)) = &last
                && check(body)
            {
                return Ok(body.clone());
            }
            if tokio::time::Instant::now() > deadline {
                anyhow::bail!("timed out waiting for {what}; last answer: {last:?}");
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Asks for a write of `value` to `device`'s `field` through the REST API: the API's
    /// refusal (`Err`, its status and answer), or the write's record once it has an
    /// outcome.
    pub async fn write_outcome(
        &self,
        device: &str,
        field: &str,
        value: serde_json::Value,
    ) -> anyhow::Result<Result<serde_json::Value, String>> {
        let body = serde_json::json!({ "value": value }).to_string();
        let path = format!("/api/v1/devices/{device}/fields/{field}");
        let (status, w) = self.send(reqwest::Method::PUT, &path, body).await?;
        if !(200..300).contains(&status) {
            return Ok(Err(format!("{status} {w}")));
        }
        let generation = w["generation"].as_u64().unwrap_or_default();
        let outcome = self
            .until(&format!("/api/v1/writes/{generation}"), "an outcome", |w| {
                w["status"] != "pending"
            })
            .await?;
        Ok(Ok(outcome))
    }

    /// Waits until every field of `device` has been read (quality good); answers the
    /// device's JSON.
    pub async fn all_read(&self, device: &str) -> anyhow::Result<serde_json::Value> {
        self.until(
            &format!("/api/v1/devices/{device}"),
            "every field read",
            |b| {
                b["fields"]
                    .as_object()
                    .is_some_and(|f| f.values().all(|v| v["quality"] == "good"))
            },
        )
        .await
    }

    /// The Prometheus text at `/metrics`.
    pub async fn metrics(&self) -> anyhow::Result<String> {
        Ok(self
            .client
            .get(self.url("/metrics"))
            .send()
            .await?
            .text()
            .await?)
    }

    /// The running gateway's service layer, for tests that reach inside.
    pub fn service(&self) -> Option<&std::sync::Arc<iogate::service::Service>> {
        self.running.as_ref().map(|r| &r.service)
    }

    pub fn token(&self) -> Option<&tokio_util::sync::CancellationToken> {
        self.running.as_ref().map(Running::token)
    }

    /// Shuts the gateway down and waits for its tasks.
    pub async fn shutdown(mut self) {
        if let Some(running) = self.running.take() {
            running.shutdown().await;
        }
    }
}

impl Drop for TestGateway {
    fn drop(&mut self) {
        if let Some(running) = &self.running {
            running.token().cancel();
        }
    }
}

async fn json_of(response: reqwest::Response) -> anyhow::Result<(u16, serde_json::Value)> {
    let status = response.status().as_u16();
    let text = response.text().await?;
    // An answer with no body (204) is null.
    if text.is_empty() && status == 204 {
        return Ok((status, serde_json::Value::Null));
    }
    let json = serde_json::from_str(&text)
        .map_err(|e| anyhow::anyhow!("status {status}, body is not JSON ({e}): {text}"))?;
    Ok((status, json))
}
