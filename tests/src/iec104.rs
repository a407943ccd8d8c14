//! Independent IEC 60870-5-104 peers on c104 (lib60870's Python binding): a controlled
//! station for the IEC 104 driver's tests, serving common address 1 (`tests/iec104/rtu.py`)
//! on a free port of 127.0.0.1, driven one command per line (`set IOA VALUE`, `invalid
//! IOA`), saying each command it executes; and a controlling station, a SCADA master, for
//! the outstation's (`tests/iec104/master.py`), saying every object it receives.

/// A station's profile for the driver's tests: every kind of monitored point the RTU
/// serves (and one IOA it does not), and commands with and without select and
/// termination.
pub const STATION_PROFILE: &str = r#"name: Station
protocol: iec104
fields:
  - { name: breaker, type: BOOL, direction: input, ioa: 100 }
  - { name: switch, type: BOOL, direction: input, ioa: 101 }
  - { name: flow, type: REAL, direction: input, ioa: 102 }
  - { name: level, type: INT, direction: input, ioa: 103 }
  - { name: ratio, type: REAL, direction: input, ioa: 104 }
  - { name: energy, type: DINT, direction: input, ioa: 105 }
  - { name: tap, type: SINT, direction: input, ioa: 106 }
  - { name: bits, type: DWORD, direction: input, ioa: 107 }
  - { name: pressure, type: REAL, direction: input, ioa: 108, asdu: M_ME_TF_1 }
  - { name: missing, type: REAL, direction: input, ioa: 999 }
  - { name: current, type: REAL, direction: input, ioa: 109, scale: 0.1 }
  - { name: trip, type: REAL, direction: output, ioa: 204, scale: 0.1, raw_type: INT }
  - { name: slow, type: BOOL, direction: output, ioa: 205 }
  - { name: setpoint, type: REAL, direction: output, ioa: 200, select: true, termination: true }
  - { name: enable, type: BOOL, direction: output, ioa: 201 }
  - { name: enable_terminated, type: BOOL, direction: output, ioa: 203, termination: true }
  - { name: limit, type: INT, direction: output, ioa: 202 }
"#;

/// A Modbus pump's profile for the outstation's tests: outputs and inputs of each kind.
pub const PUMP_PROFILE: &str = r#"name: Pump
fields:
  - { name: run, type: BOOL, direction: output, register: { address: 0, kind: coil } }
  - { name: alarm, type: BOOL, direction: input, register: { address: 0, kind: discrete_input } }
  - { name: speed, type: INT, direction: output, register: { address: 0, kind: holding_register } }
  - { name: temp, type: REAL, direction: input, register: { address: 0, kind: input_register, word_count: 2 } }
  - { name: status, type: WORD, direction: input, register: { address: 2, kind: input_register } }
  - { name: limit, type: REAL, direction: output, register: { address: 2, kind: holding_register, word_count: 2 } }
"#;

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
