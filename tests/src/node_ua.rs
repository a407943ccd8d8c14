//! An independent OPC UA server for the client driver's interoperability tests: node-opcua
//! (`tests/opcua/node/server.js`, installed by `tests/opcua/node/install.sh`), with the
//! operation limits, variables and certificate a test asks for.

use std::path::PathBuf;

use crate::{PATIENCE, Piped, repo_file, spawn_piped};

/// A running node-opcua server (killed when dropped).
pub struct NodeUa {
    _piped: Piped,
    /// The port it listens on.
    pub port: u16,
    /// Its endpoint URL on the loopback.
    pub url: String,
    /// Its PKI directory (its own certificate in `own/certs/certificate.pem`).
    pub pki: PathBuf,
}

impl NodeUa {
    /// Starts it with `args` (see `server.js`: `--limits N`, `--hide-limits`, `--many N`,
    /// `--twice`, `--secure`), its PKI in `pki`, and waits until it listens.
    pub async fn start(pki: PathBuf, args: &[&str]) -> anyhow::Result<NodeUa> {
        crate::run_installer("opcua/node/install.sh")?;
        let mut command = tokio::process::Command::new("node");
        command
            .arg(repo_file("opcua/node/server.js"))
            .args(args)
            .arg("--pki")
            .arg(&pki)
            .stderr(std::process::Stdio::null());
        let mut piped = spawn_piped(command)?;
        let port = tokio::time::timeout(PATIENCE, async {
            loop {
                let line = piped
                    .lines
                    .next_line()
                    .await?
                    .ok_or_else(|| anyhow::anyhow!("node-opcua ended before it listened"))?;
                if let Some(port) = line.strip_prefix("ready ") {
                    return anyhow::Ok(port.trim().parse::<u16>()?);
                }
            }
        })
        .await??;
        Ok(NodeUa {
            _piped: piped,
            port,
            url: format!("opc.tcp://127.0.0.1:{port}/UA/Peer"),
            pki,
        })
    }
}
