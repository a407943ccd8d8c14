//! An independent Logix controller for the EtherNet/IP driver's tests: cpppo's simulator
//! (`tests/eip/plc.py`) serving the tags it is started with, and pylogix (another
//! implementation) to read what the gateway wrote.

use crate::{PATIENCE, Piped, repo_file, spawn_piped};

/// A running controller.
pub struct LogixPlc {
    piped: Piped,
    /// The port it listens on.
    pub port: u16,
}

impl LogixPlc {
    /// Starts the controller with `tags` (`Speed=REAL`, `Counts=DINT[10]`), on `port` or a
    /// free one, and waits until it listens.
    pub async fn start(port: Option<u16>, tags: &[&str]) -> anyhow::Result<LogixPlc> {
        let mut args: Vec<String> = Vec::new();
        if let Some(p) = port {
            args.extend(["--port".to_owned(), p.to_string()]);
        }
        args.extend(tags.iter().map(|t| (*t).to_owned()));
        Self::spawn("eip/plc.py", &args).await
    }

    /// Starts the tag directory controller (`tests/eip/directory_plc.py`, the services a
    /// client lists tags with) with `args` (`--extra N`, `--stuck`).
    pub async fn directory(args: &[&str]) -> anyhow::Result<LogixPlc> {
        let args: Vec<String> = args.iter().map(|a| (*a).to_owned()).collect();
        Self::spawn("eip/directory_plc.py", &args).await
    }

    async fn spawn(script: &str, args: &[String]) -> anyhow::Result<LogixPlc> {
        crate::run_installer("eip/install.sh")?;
        let mut command = tokio::process::Command::new(crate::python());
        command.arg(repo_file(script)).args(args);
        let mut piped = spawn_piped(command)?;
        let line = tokio::time::timeout(PATIENCE, piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the controller ended before it listened"))?;
        let port = line.trim().parse()?;
        Ok(LogixPlc { piped, port })
    }

    /// The controller's next line after its port (the directory controller prints each
    /// Forward Close and UnRegister Session it is sent).
    pub async fn said(&mut self) -> anyhow::Result<String> {
        tokio::time::timeout(PATIENCE, self.piped.lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the controller ended"))
    }

    /// Kills the controller as the operating system would.
    pub async fn kill(mut self) -> anyhow::Result<()> {
        self.piped.child.kill().await?;
        let _ = self.piped.child.wait().await;
        Ok(())
    }

    /// A tag as cpppo's own client prints it (`Name == ['text']: 'OK'`): for STRINGs, which
    /// pylogix reads as Logix structures only.
    pub async fn print(&self, tag: &str) -> anyhow::Result<String> {
        let out = tokio::process::Command::new(crate::python())
            .args(["-m", "cpppo.server.enip.client", "--print", "--address"])
            .arg(format!("127.0.0.1:{}", self.port))
            .arg(tag)
            .output()
            .await?;
        Ok(String::from_utf8_lossy(&out.stdout).into_owned())
    }

    /// Writes `TAG=VALUE` pairs with pylogix (a bit of an integer, `Flags.4=true`, with
    /// pylogix's own Read-Modify-Write Tag); each tag's status.
    pub async fn write(&self, pairs: &[&str]) -> anyhow::Result<serde_json::Value> {
        self.pylogix("eip/write.py", pairs).await
    }

    /// The tags' values as pylogix reads them (JSON: each tag's value, or its error).
    pub async fn read(&self, tags: &[&str]) -> anyhow::Result<serde_json::Value> {
        self.pylogix("eip/read.py", tags).await
    }

    /// The controller's tags as pylogix lists them (`tests/eip/tag_list.py`: `tags` and
    /// `udts`).
    pub async fn tag_list(&self) -> anyhow::Result<serde_json::Value> {
        self.pylogix("eip/tag_list.py", &[]).await
    }

    /// A pylogix script's JSON, given this controller's port and `args`.
    async fn pylogix(&self, script: &str, args: &[&str]) -> anyhow::Result<serde_json::Value> {
        let out = tokio::process::Command::new(crate::python())
            .arg(repo_file(script))
            .arg(self.port.to_string())
            .args(args)
            .output()
            .await?;
        anyhow::ensure!(
            out.status.success(),
            "pylogix: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        Ok(serde_json::from_slice(&out.stdout)?)
    }
}
