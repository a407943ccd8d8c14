//! An independent S7 PLC for the S7 driver's tests: Snap7's server (python-snap7) holding
//! one value of every S7 type in data blocks, merkers, inputs, outputs, timers and counters
//! (`tests/s7/plc.py`), driven one command per line.

use tokio::io::AsyncWriteExt;

use crate::{PATIENCE, Piped, repo_file, spawn_piped};

/// A running PLC.
pub struct S7Plc {
    piped: Piped,
    /// The port it listens on.
    pub port: u16,
}

impl S7Plc {
    /// Starts the PLC (on `port`, else a free one) and waits until it listens.
    pub async fn start(port: Option<u16>) -> anyhow::Result<S7Plc> {
        crate::run_installer("s7/install.sh")?;
        let mut command = tokio::process::Command::new(crate::python());
        command.arg(repo_file("s7/plc.py"));
        if let Some(p) = port {
            command.args(["--port", &p.to_string()]);
        }
        let mut piped = spawn_piped(command)?;
        let line = tokio::time::timeout(PATIENCE, piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the PLC ended before it listened"))?;
        let port = line.trim().parse()?;
        Ok(S7Plc { piped, port })
    }

    /// One command and its answer.
    pub async fn cmd(&mut self, command: &str) -> anyhow::Result<String> {
        self.piped
            .stdin
            .write_all(format!("{command}\n").as_bytes())
            .await?;
        tokio::time::timeout(PATIENCE, self.piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the PLC ended"))
    }

    /// The bytes the PLC holds in an area (`DB 1`, `MK 0`...), in hex.
    pub async fn dump(&mut self, area: &str, start: u32, length: u32) -> anyhow::Result<String> {
        self.cmd(&format!("dump {area} {start} {length}")).await
    }

    /// Kills the server as the operating system would.
    pub async fn kill(mut self) -> anyhow::Result<()> {
        self.piped.child.kill().await?;
        let _ = self.piped.child.wait().await;
        Ok(())
    }
}
