//! Independent IEC 60870-5-104 peers on c104 (lib60870's Python binding): a controlled
//! station for the IEC 104 driver's tests, serving common address 1 (`tests/iec104/rtu.py`)
//! on a free port of 127.0.0.1, driven one command per line (`set IOA VALUE`, `invalid
//! IOA`), saying each command it executes; and a controlling station, a SCADA master, for
//! the outstation's (`tests/iec104/master.py`), saying every object it receives.

use tokio::io::AsyncWriteExt;

use crate::{PATIENCE, Piped, python, repo_file, run_installer, spawn_piped};

/// A running station.
pub struct Rtu {
    piped: Piped,
    pub port: u16,
}

impl Rtu {
    pub async fn start() -> anyhow::Result<Rtu> {
        Rtu::start_on(None).await
    }

    /// Starts the station on `port` (a free one when `None`).
    pub async fn start_on(port: Option<u16>) -> anyhow::Result<Rtu> {
        run_installer("iec104/install.sh")?;
        let mut command = tokio::process::Command::new(python());
        command.arg(repo_file("iec104/rtu.py"));
        command.args(port.map(|p| p.to_string()));
        let mut piped = spawn_piped(command)?;
        let line = tokio::time::timeout(PATIENCE, piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the station ended before it listened"))?;
        let port = line.trim().parse()?;
        Ok(Rtu { piped, port })
    }

    /// The station's next line.
    pub async fn said(&mut self) -> anyhow::Result<String> {
        tokio::time::timeout(PATIENCE, self.piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the station ended"))
    }

    /// The station's next line if it says one within `within`.
    pub async fn said_within(&mut self, within: std::time::Duration) -> Option<String> {
        tokio::time::timeout(within, self.piped.lines.next_line())
            .await
            .ok()?
            .ok()?
    }

    /// Sends the station a command line and waits until it says it sent the point.
    pub async fn cmd(&mut self, line: &str) -> anyhow::Result<()> {
        self.piped
            .stdin
            .write_all(format!("{line}\n").as_bytes())
            .await?;
        self.piped.stdin.flush().await?;
        loop {
            if self.said().await?.starts_with("sent") {
                return Ok(());
            }
        }
    }

    /// Kills the station as the operating system would.
    pub async fn kill(mut self) -> anyhow::Result<()> {
        self.piped.child.kill().await?;
        let _ = self.piped.child.wait().await;
        Ok(())
    }
}

/// A running SCADA master, connected to an outstation with STARTDT, a general
/// interrogation and a clock synchronisation.
pub struct Master {
    piped: Piped,
}

impl Master {
    pub async fn connect(addr: std::net::SocketAddr) -> anyhow::Result<Master> {
        run_installer("iec104/install.sh")?;
        let mut command = tokio::process::Command::new(python());
        command.arg(repo_file("iec104/master.py"));
        command.args([addr.ip().to_string(), addr.port().to_string()]);
        let mut master = Master {
            piped: spawn_piped(command)?,
        };
        while master.said().await? != "ready" {}
        Ok(master)
    }

    /// The master's next line (`m IOA TYPE VALUE QUALITY COT STAMP` for an object).
    pub async fn said(&mut self) -> anyhow::Result<String> {
        tokio::time::timeout(PATIENCE, self.piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the master ended"))
    }

    /// Sends a line (`gi`, `cmd IOA TYPE VALUE [select]`, `mute`, `unmute`) and returns
    /// its answer, keeping the objects received meanwhile in `seen`.
    pub async fn ask(&mut self, line: &str, seen: &mut Vec<String>) -> anyhow::Result<String> {
        self.piped
            .stdin
            .write_all(format!("{line}\n").as_bytes())
            .await?;
        self.piped.stdin.flush().await?;
        let word = line
            .split_whitespace()
            .next()
            .unwrap_or_default()
            .to_owned();
        loop {
            let said = self.said().await?;
            if said.starts_with(&format!("{word} ")) {
                return Ok(said);
            }
            seen.push(said);
        }
    }
}
