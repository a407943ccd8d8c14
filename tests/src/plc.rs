//! An independent OPC UA server for the OPC UA client driver's tests: asyncua (Python) as a
//! PLC with a variable of every IEC type (`tests/opcua/plc.py`), driven one JSON command
//! per line.

use serde_json::{Value, json};
use tokio::io::AsyncWriteExt;

use crate::{PATIENCE, Piped, repo_file, spawn_piped};

/// A running PLC.
pub struct UaPlc {
    piped: Piped,
    /// Its endpoint URL.
    pub url: String,
    /// The index of its namespace, `urn:iogate:test:plc`.
    pub ns: u64,
}

impl UaPlc {
    /// Starts the PLC with `args` (`--port P`, `--reorder`, `--no-subscriptions`,
    /// `--security CERT KEY TRUSTED`) and waits until it listens.
    pub async fn start(args: &[&str]) -> anyhow::Result<UaPlc> {
        crate::opcua::install()?;
        let mut command = tokio::process::Command::new(crate::python());
        command.arg(repo_file("opcua/plc.py")).args(args);
        let mut piped = spawn_piped(command)?;
        let line = tokio::time::timeout(PATIENCE, piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the PLC ended before it listened"))?;
        let ready: Value = serde_json::from_str(&line)?;
        let url = ready["url"]
            .as_str()
            .ok_or_else(|| anyhow::anyhow!("no url in {line}"))?
            .to_owned();
        let ns = ready["ns"].as_u64().unwrap_or(0);
        Ok(UaPlc { piped, url, ns })
    }

    /// The port it listens on.
    pub fn port(&self) -> String {
        self.url
            .rsplit(':')
            .next()
            .and_then(|p| p.split('/').next())
            .unwrap_or_default()
            .to_owned()
    }

    /// One command and its answer.
    pub async fn cmd(&mut self, command: Value) -> anyhow::Result<Value> {
        let mut line = command.to_string();
        line.push('\n');
        self.piped.stdin.write_all(line.as_bytes()).await?;
        let answer = tokio::time::timeout(PATIENCE, self.piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the PLC ended"))?;
        let answer: Value = serde_json::from_str(&answer)?;
        anyhow::ensure!(answer.get("error").is_none(), "PLC: {answer}");
        Ok(answer)
    }

    /// Sets a variable (`Line1.NAME`) on the server, with a source timestamp of now.
    pub async fn set(&mut self, name: &str, value: Value) -> anyhow::Result<()> {
        self.cmd(json!({"cmd": "set", "name": name, "value": value}))
            .await
            .map(drop)
    }

    /// A variable's value on the server.
    pub async fn get(&mut self, name: &str) -> anyhow::Result<Value> {
        Ok(self.cmd(json!({"cmd": "get", "name": name})).await?["value"].clone())
    }

    /// Kills the server as the operating system would.
    pub async fn kill(mut self) -> anyhow::Result<()> {
        self.piped.child.kill().await?;
        Ok(())
    }
}
