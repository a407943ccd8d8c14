//! Independent BACnet/IP devices for the BACnet driver's tests: bacpypes3 serving one
//! object of each kind the driver reads (`tests/bacnet/device.py`) on 127.0.0.1, and the
//! original bacpypes, a second stack (`tests/bacnet/legacy_device.py`), on 127.0.0.2, each
//! at a free port, driven one command per line (`get`, `priority`, `set`, `flags`).

use tokio::io::AsyncWriteExt;

use crate::{PATIENCE, Piped, repo_file, spawn_piped};

/// A running device.
pub struct BacnetDevice {
    piped: Piped,
    /// The address it is bound to.
    pub host: &'static str,
    /// The UDP port it is bound to.
    pub port: u16,
    /// Its device object's instance.
    pub instance: u32,
}

impl BacnetDevice {
    /// Starts a bacpypes3 device of `instance` on 127.0.0.1 and waits until it is bound.
    pub async fn start(instance: u32) -> anyhow::Result<BacnetDevice> {
        let args = ["--instance", &instance.to_string(), "--name", "TestDevice"].map(String::from);
        Self::spawn("bacnet/device.py", &args, "127.0.0.1", instance).await
    }

    /// Starts a device of the original bacpypes, a second stack (`tests/bacnet/legacy_device.py`),
    /// of `instance` on 127.0.0.2, and waits until it is bound.
    pub async fn start_legacy(instance: u32) -> anyhow::Result<BacnetDevice> {
        let host = "127.0.0.2";
        let args = ["--instance", &instance.to_string(), "--host", host].map(String::from);
        Self::spawn("bacnet/legacy_device.py", &args, host, instance).await
    }

    /// As [`BacnetDevice::start_legacy`], a device without ReadPropertyMultiple.
    pub async fn start_without_rpm(instance: u32) -> anyhow::Result<BacnetDevice> {
        let host = "127.0.0.2";
        let mut args = ["--instance", &instance.to_string(), "--host", host]
            .map(String::from)
            .to_vec();
        args.push("--no-rpm".into());
        Self::spawn("bacnet/legacy_device.py", &args, host, instance).await
    }

    async fn spawn(
        script: &str,
        args: &[String],
        host: &'static str,
        instance: u32,
    ) -> anyhow::Result<BacnetDevice> {
        let mut command = tokio::process::Command::new(crate::python());
        command.arg(repo_file(script)).args(args);
        let mut piped = spawn_piped(command)?;
        let line = tokio::time::timeout(PATIENCE, piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the device ended before it was bound"))?;
        let port = line.trim().parse()?;
        Ok(BacnetDevice {
            piped,
            host,
            port,
            instance,
        })
    }

    /// One command and its answer.
    pub async fn cmd(&mut self, command: &str) -> anyhow::Result<String> {
        ask(&mut self.piped, command).await
    }

    /// A property of an object as the device holds it (`analog-output,1`, `presentValue`).
    pub async fn get(&mut self, object: &str, property: &str) -> anyhow::Result<String> {
        self.cmd(&format!("get {object} {property}")).await
    }

    /// Kills the device as the operating system would.
    pub async fn kill(mut self) -> anyhow::Result<()> {
        self.piped.child.kill().await?;
        let _ = self.piped.child.wait().await;
        Ok(())
    }
}

/// A BACnet router on `host` (`tests/bacnet/router.py`) with `count` devices behind it on a
/// virtual network, instances `base + 1` to `base + count`.
pub struct BacnetRouter {
    piped: Piped,
}

impl BacnetRouter {
    /// Starts the router on `host:port` and waits until its devices are up.
    pub async fn start(
        host: &str,
        port: u16,
        base: u32,
        count: usize,
    ) -> anyhow::Result<BacnetRouter> {
        let mut command = tokio::process::Command::new(crate::python());
        command.arg(repo_file("bacnet/router.py")).args([
            "--host",
            host,
            "--port",
            &port.to_string(),
            "--base",
            &base.to_string(),
            "--count",
            &count.to_string(),
        ]);
        let mut piped = spawn_piped(command)?;
        let line = tokio::time::timeout(PATIENCE, piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the router ended before it was ready"))?;
        anyhow::ensure!(line.trim() == "ready", "the router said {line}");
        Ok(BacnetRouter { piped })
    }

    /// One command and its answer.
    pub async fn cmd(&mut self, command: &str) -> anyhow::Result<String> {
        ask(&mut self.piped, command).await
    }
}

/// One command to a peer driven a line at a time, and its answer (an `error` answer is one).
async fn ask(piped: &mut Piped, command: &str) -> anyhow::Result<String> {
    piped
        .stdin
        .write_all(format!("{command}\n").as_bytes())
        .await?;
    let answer = tokio::time::timeout(PATIENCE, piped.lines.next_line())
        .await??
        .ok_or_else(|| anyhow::anyhow!("the peer ended"))?;
    anyhow::ensure!(!answer.starts_with("error"), "{command}: {answer}");
    Ok(answer)
}
