//! The arbiters of a pair other than an MQTT broker, each in its own process on free
//! loopback ports: etcd (Debian's `etcd-server`, installed by `tests/etcd/install.sh`) and a
//! Kubernetes API server for Leases (`tests/kube/apiserver.py`, written from the API's
//! conventions, in the tests' own Python).

use std::process::Stdio;

use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};

use crate::devices::temp_dir;

fn free_port() -> anyhow::Result<u16> {
    Ok(std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port())
}

/// One etcd member, its data in a temp dir.
pub struct Etcd {
    pub port: u16,
    _child: Child,
}

impl Etcd {
    pub async fn start() -> anyhow::Result<Etcd> {
        crate::run_installer("etcd/install.sh")?;
        let dir = temp_dir("etcd");
        let (port, peer) = (free_port()?, free_port()?);
        let client = format!("http://127.0.0.1:{port}");
        let peer = format!("http://127.0.0.1:{peer}");
        let child = Command::new("etcd")
            .arg("--data-dir")
            .arg(dir.join("data"))
            .args(["--name", "arbiter", "--listen-client-urls", &client])
            .args(["--advertise-client-urls", &client])
            .args([
                "--listen-peer-urls",
                &peer,
                "--initial-advertise-peer-urls",
                &peer,
            ])
            .args(["--initial-cluster", &format!("arbiter={peer}")])
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.join("etcd.log"))?)
            .kill_on_drop(true)
            .spawn()?;
        let http = reqwest::Client::new();
        crate::eventually("etcd serving", || {
            let (http, url) = (http.clone(), format!("{client}/health"));
            async move { matches!(http.get(&url).send().await, Ok(r) if r.status().is_success()) }
        })
        .await?;
        Ok(Etcd {
            port,
            _child: child,
        })
    }
}

/// The Lease API server; every request needs `Bearer <token>`.
pub struct KubeApi {
    pub port: u16,
    pub token: String,
    _child: Child,
}

impl KubeApi {
    pub async fn start() -> anyhow::Result<KubeApi> {
        let token = "iogate-test-token".to_owned();
        let mut child = Command::new(crate::python())
            .arg(crate::repo_file("kube/apiserver.py"))
            .args(["--token", &token])
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .kill_on_drop(true)
            .spawn()?;
        let stdout = child
            .stdout
            .take()
            .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
        let mut line = String::new();
        tokio::time::timeout(crate::PATIENCE, BufReader::new(stdout).read_line(&mut line))
            .await??;
        let port = line.trim().parse()?;
        Ok(KubeApi {
            port,
            token,
            _child: child,
        })
    }
}
