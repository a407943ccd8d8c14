//! An independent OPC UA client for the tests: asyncua (Python), driven one JSON command
//! per line (`tests/opcua/client.py`); `tests/opcua/install.sh` installs it when missing.

use std::path::PathBuf;

use serde_json::{Value, json};
use tokio::io::{AsyncWriteExt, BufReader, Lines};
use tokio::process::{Child, ChildStdin, ChildStdout, Command};

use crate::repo_file;

/// Runs the project's installer for the OPC UA client (idempotent).
pub fn install() -> anyhow::Result<()> {
    crate::run_installer("opcua/install.sh")
}

/// How a session is opened.
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// `Basic256Sha256,SignAndEncrypt` and the client's certificate and key files.
    pub security: Option<(String, PathBuf, PathBuf)>,
    /// User name and password.
    pub user: Option<(String, String)>,
}

/// A session of asyncua with the gateway.
pub struct UaClient {
    _child: Child,
    stdin: ChildStdin,
    lines: Lines<BufReader<ChildStdout>>,
    /// The index of the iogate namespace.
    pub ns: u64,
}

impl UaClient {
    /// Connects; a refused connection is an error with asyncua's words.
    pub async fn connect(url: &str, options: &Options) -> anyhow::Result<UaClient> {
        install()?;
        let mut command = Command::new(crate::python());
        command.arg(repo_file("opcua/client.py")).arg(url);
        if let Some((security, cert, key)) = &options.security {
            command.arg(security).arg(cert).arg(key);
        }
        if let Some((user, password)) = &options.user {
            command.arg(user).arg(password);
        }
        let crate::Piped {
            child,
            stdin,
            mut lines,
        } = crate::spawn_piped(command)?;
        let first = read(&mut lines).await?;
        anyhow::ensure!(first["connected"] == true, "asyncua: {first}");
        Ok(UaClient {
            ns: first["ns"].as_u64().unwrap_or_default(),
            _child: child,
            stdin,
            lines,
        })
    }

    /// Sends one command and answers its JSON answer.
    pub async fn cmd(&mut self, command: Value) -> anyhow::Result<Value> {
        self.stdin
            .write_all(format!("{command}\n").as_bytes())
            .await?;
        self.stdin.flush().await?;
        let answer = read(&mut self.lines).await?;
        anyhow::ensure!(answer.get("error").is_none(), "asyncua: {answer}");
        Ok(answer)
    }

    /// Ends the session as a client should (CloseSession), and waits for the client.
    pub async fn close(self) -> anyhow::Result<()> {
        let UaClient {
            mut _child, stdin, ..
        } = self;
        drop(stdin);
        tokio::time::timeout(crate::PATIENCE, _child.wait()).await??;
        Ok(())
    }

    pub async fn read(&mut self, node: &str) -> anyhow::Result<Value> {
        self.cmd(json!({"cmd": "read", "node": node})).await
    }

    /// Reads a node of any namespace by its whole id (`i=2267`, `ns=1;s=x`).
    pub async fn read_absolute(&mut self, node: &str) -> anyhow::Result<Value> {
        self.cmd(json!({"cmd": "read", "node": node, "absolute": true}))
            .await
    }

    /// Writes `value` as a variant of `ty` (asyncua's VariantType name); answers the
    /// status code's name.
    pub async fn write(&mut self, node: &str, value: Value, ty: &str) -> anyhow::Result<String> {
        let answer = self
            .cmd(json!({"cmd": "write", "node": node, "value": value, "type": ty}))
            .await?;
        Ok(answer["status"].as_str().unwrap_or_default().to_owned())
    }
}

/// Whether a connection could be opened, and asyncua's words when not.
pub async fn refused(url: &str, options: &Options) -> anyhow::Result<String> {
    match UaClient::connect(url, options).await {
        Ok(_) => anyhow::bail!("the connection was accepted"),
        Err(e) => Ok(e.to_string()),
    }
}

async fn read(lines: &mut Lines<BufReader<ChildStdout>>) -> anyhow::Result<Value> {
    let line = tokio::time::timeout(crate::PATIENCE, lines.next_line())
        .await
        .map_err(|_| anyhow::anyhow!("no answer from asyncua within {:?}", crate::PATIENCE))??
        .ok_or_else(|| anyhow::anyhow!("asyncua ended"))?;
    Ok(serde_json::from_str(&line)?)
}
