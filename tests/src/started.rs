//! Gateways started on a bus of slaves or from files, and what waits on a gateway: a
//! condition that comes true, an event stream read line by line.

use std::future::Future;
use std::path::{Path, PathBuf};

use std::time::Duration;

use crate::{PATIENCE, TestGateway, devices, profiles_dir};

/// Waits until `check` is true, polling every 20 ms, for at most [`PATIENCE`].
pub async fn eventually<F, Fut>(what: &str, mut check: F) -> anyhow::Result<()>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = bool>,
{
    let deadline = tokio::time::Instant::now() + PATIENCE;
    loop {
        if check().await {
            return Ok(());
        }
        if tokio::time::Instant::now() > deadline {
            anyhow::bail!("timed out waiting for: {what}");
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Reads a Server-Sent Events response event by event.
pub struct SseReader {
    stream:
        std::pin::Pin<Box<dyn futures_util::Stream<Item = reqwest::Result<bytes::Bytes>> + Send>>,
    buffer: String,
}

impl SseReader {
    pub async fn open(gateway: &TestGateway, path: &str) -> anyhow::Result<SseReader> {
        let response = gateway.client.get(gateway.url(path)).send().await?;
        anyhow::ensure!(
            response.status().is_success(),
            "status {} for {path}",
            response.status()
        );
        Ok(SseReader {
            stream: Box::pin(response.bytes_stream()),
            buffer: String::new(),
        })
    }

    /// The next event's name and JSON data; `None` when the stream ended.
    pub async fn next(&mut self) -> anyhow::Result<Option<(String, serde_json::Value)>> {
        use futures_util::StreamExt;
        loop {
            if let Some(end) = self.buffer.find("\n\n") {
                let block: String = self.buffer.drain(..end + 2).collect();
                let mut name = String::from("message");
                let mut data = String::new();
                for line in block.lines() {
                    if let Some(v) = line.strip_prefix("event:") {
                        name = v.trim().to_owned();
                    } else if let Some(v) = line.strip_prefix("data:") {
                        data.push_str(v.trim());
                    }
                }
                if data.is_empty() {
                    continue; // a keep-alive comment
                }
                return Ok(Some((name, serde_json::from_str(&data)?)));
            }
            match tokio::time::timeout(PATIENCE, self.stream.next()).await {
                Err(_) => anyhow::bail!("no event within {PATIENCE:?}"),
                Ok(None) => return Ok(None),
                Ok(Some(chunk)) => self.buffer.push_str(&String::from_utf8_lossy(&chunk?)),
            }
        }
    }

    /// Skips events until one satisfies `want`.
    pub async fn until(
        &mut self,
        mut want: impl FnMut(&str, &serde_json::Value) -> bool,
    ) -> anyhow::Result<serde_json::Value> {
        loop {
            match self.next().await? {
                Some((name, data)) if want(&name, &data) => return Ok(data),
                Some(_) => {}
                None => anyhow::bail!("the stream ended"),
            }
        }
    }
}

/// A serial link `bus` on `port` at 115200 baud, as config text.
pub fn link_yaml(port: &Path) -> String {
    format!(
        "links:\n  - {{ name: bus, serial: {{ port: {}, baud: 115200 }} }}\n",
        port.display()
    )
}

/// A gateway on a bus served on a pseudo-terminal, the pty's other end held, the bus task,
/// and the pty's path.
pub type OnBus = (
    TestGateway,
    tokio_serial::SerialStream,
    tokio::task::JoinHandle<()>,
    PathBuf,
);

/// Starts a gateway whose link `bus` opens a pty that `bus` answers on, with the
/// repository's profiles and `profiles` (file name, text) beside them, and `devices` (YAML
/// list items).
pub async fn bus_gateway(
    name: &str,
    bus: &devices::RtuBus,
    profiles: &[(&str, &str)],
    devices: &str,
) -> OnBus {
    bus_gateway_with(name, bus, profiles, devices, "").await
}

/// [`bus_gateway`] with more config text (`extra`, top-level sections) after the devices.
pub async fn bus_gateway_with(
    name: &str,
    bus: &devices::RtuBus,
    profiles: &[(&str, &str)],
    devices: &str,
    extra: &str,
) -> OnBus {
    let dir = devices::temp_dir(name);
    let profile_dir = dir.join("profiles");
    std::fs::create_dir_all(&profile_dir).expect("dir");
    for entry in std::fs::read_dir(profiles_dir()).expect("profiles") {
        let path = entry.expect("entry").path();
        std::fs::copy(&path, profile_dir.join(path.file_name().expect("name"))).expect("copy");
    }
    for (file, text) in profiles {
        std::fs::write(profile_dir.join(file), text).expect("profile");
    }
    let port = dir.join("ttyBUS");
    let (device_end, holder) = devices::pty_at(&port).expect("pty");
    let task = bus.serve(device_end);
    let gw = TestGateway::start(&format!(
        "profiles: {}\n{}devices:\n{devices}{extra}",
        profile_dir.display(),
        link_yaml(&port)
    ))
    .await
    .expect("gateway");
    (gw, holder, task, port)
}

/// A directory named after `name` with `profiles/` holding `profiles` (file name, text)
/// and `iogate.yaml` holding `config`; answers the directory and the config's path.
pub fn config_files(name: &str, profiles: &[(&str, &str)], config: &str) -> (PathBuf, PathBuf) {
    let dir = devices::temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles")).expect("profiles dir");
    for (file, text) in profiles {
        std::fs::write(dir.join("profiles").join(file), text).expect("profile");
    }
    let path = dir.join("iogate.yaml");
    std::fs::write(&path, config).expect("config");
    (dir, path)
}

/// A gateway started from the config file at `path` (so that it can be reloaded).
pub async fn start_file(path: &Path) -> TestGateway {
    let setup = iogate::app::Setup::from_file(path).expect("valid config");
    TestGateway::start_setup(setup).await.expect("gateway")
}
