//! MQTT peers for the tests: a real Mosquitto broker on a free loopback port with its own
//! config in a temp dir, and paho-mqtt (Python) as an independent subscriber and publisher.
//! `tests/mqtt/install.sh` installs both when they are missing.

use std::path::PathBuf;
use std::process::Stdio;
use std::time::Duration;

use tokio::io::{AsyncWriteExt, BufReader, Lines};
use tokio::process::{Child, ChildStdin, ChildStdout, Command};

use crate::repo_file;

/// Runs the project's installer for the MQTT peers (idempotent).
pub fn install() -> anyhow::Result<()> {
    crate::run_installer("mqtt/install.sh")
}

fn mosquitto() -> PathBuf {
    let sbin = PathBuf::from("/usr/sbin/mosquitto");
    if sbin.exists() {
        sbin
    } else {
        PathBuf::from("mosquitto")
    }
}

/// A Mosquitto broker of the test's own; stopped when dropped.
pub struct Broker {
    pub port: u16,
    /// The TLS listener's port ([`Broker::start_tls`]).
    pub tls_port: Option<u16>,
    child: Option<Child>,
    config: PathBuf,
}

impl Broker {
    /// A broker without persistence.
    pub async fn start() -> anyhow::Result<Broker> {
        Broker::start_with(false).await
    }

    /// A broker that keeps sessions and queued messages (QoS 0 too) across its restarts,
    /// for subscribers that must not miss what is published while they reconnect.
    pub async fn start_persistent() -> anyhow::Result<Broker> {
        Broker::start_with(true).await
    }

    /// A broker with a second listener, `tls_port`, that speaks TLS with `server`'s
    /// certificate and requires a client certificate signed by `ca` (PEM texts).
    pub async fn start_tls(ca: &str, server: &crate::pki::Pem) -> anyhow::Result<Broker> {
        Broker::start_with_tls(false, Some((ca, server))).await
    }

    async fn start_with(persistent: bool) -> anyhow::Result<Broker> {
        Broker::start_with_tls(persistent, None).await
    }

    /// A broker with more lines of configuration (`max_packet_size 4096`: told to MQTT 5
    /// clients as the Maximum Packet Size; `max_inflight_messages 1`: as the Receive Maximum).
    pub async fn start_with_config(more: &str) -> anyhow::Result<Broker> {
        Broker::start_configured(false, None, more).await
    }

    async fn start_with_tls(
        persistent: bool,
        tls: Option<(&str, &crate::pki::Pem)>,
    ) -> anyhow::Result<Broker> {
        Broker::start_configured(persistent, tls, "").await
    }

    async fn start_configured(
        persistent: bool,
        tls: Option<(&str, &crate::pki::Pem)>,
        more: &str,
    ) -> anyhow::Result<Broker> {
        install()?;
        let dir = crate::devices::temp_dir("mosquitto");
        // A free port: bind, note, release (mosquitto binds it next).
        let port = std::net::TcpListener::bind("127.0.0.1:0")?
            .local_addr()?
            .port();
        let config = dir.join("mosquitto.conf");
        let persistence = if persistent {
            format!(
                "persistence true\npersistence_location {}/\nqueue_qos0_messages true\nmax_queued_messages 100000\n",
                dir.display()
            )
        } else {
            "persistence false\n".to_owned()
        };
        let (tls_port, tls_listener) = match tls {
            None => (None, String::new()),
            Some((ca, server)) => {
                let tls_port = std::net::TcpListener::bind("127.0.0.1:0")?
                    .local_addr()?
                    .port();
                std::fs::write(dir.join("ca.pem"), ca)?;
                std::fs::write(dir.join("server.pem"), &server.cert)?;
                std::fs::write(dir.join("server.key"), &server.key)?;
                (
                    Some(tls_port),
                    format!(
                        "listener {tls_port} 127.0.0.1\ncafile {d}/ca.pem\ncertfile {d}/server.pem\nkeyfile {d}/server.key\nrequire_certificate true\n",
                        d = dir.display()
                    ),
                )
            }
        };
        std::fs::write(
            &config,
            // Started as root, mosquitto drops to its own user, which cannot write this
            // directory: its persistence (kept sessions across a restart) and log would be
            // lost silently. `user root` keeps it as the user that started it (and does
            // nothing for any other user).
            format!(
                "user root\nallow_anonymous true\n{more}{persistence}listener {port} 127.0.0.1\n{tls_listener}log_dest file {}\nlog_type all\n",
                dir.join("mosquitto.log").display()
            ),
        )?;
        let mut broker = Broker {
            port,
            tls_port,
            child: None,
            config,
        };
        broker.resume().await?;
        Ok(broker)
    }

    /// Starts the broker again on its port, after [`Broker::pause`].
    pub async fn resume(&mut self) -> anyhow::Result<()> {
        let child = Command::new(mosquitto())
            .arg("-c")
            .arg(&self.config)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .kill_on_drop(true)
            .spawn()?;
        self.child = Some(child);
        let port = self.port;
        crate::eventually("mosquitto listening", || async move {
            tokio::net::TcpStream::connect(("127.0.0.1", port))
                .await
                .is_ok()
        })
        .await
    }

    /// Stops the broker as an operator does (SIGTERM: it saves its sessions and closes every
    /// connection), keeping its port and files for [`Broker::resume`].
    pub async fn pause(&mut self) {
        if let Some(mut child) = self.child.take() {
            if let Some(pid) = child.id() {
                let _ = Command::new("kill")
                    .arg("-TERM")
                    .arg(pid.to_string())
                    .status()
                    .await;
            }
            let _ = tokio::time::timeout(Duration::from_secs(10), child.wait()).await;
            let _ = child.kill().await;
        }
    }

    pub async fn stop(mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill().await;
        }
    }

    /// The broker's process id (for its CPU time and resident size in `/proc`).
    pub fn pid(&self) -> Option<u32> {
        self.child.as_ref().and_then(|c| c.id())
    }
}

/// paho-mqtt subscribed to a topic filter; messages come as JSON values.
pub struct Peer {
    child: Child,
    stdin: ChildStdin,
    lines: Lines<BufReader<ChildStdout>>,
    /// Messages read while waiting for something else, given out first.
    pending: std::collections::VecDeque<Message>,
}

#[derive(Debug, Clone)]
pub struct Message {
    pub topic: String,
    /// The payload as text (hex for Sparkplug messages).
    pub payload: String,
    pub retain: bool,
    /// A Sparkplug message as pysparkplug decoded it: {type, seq, timestamp, metrics}.
    pub sparkplug: serde_json::Value,
    /// Why pysparkplug could not decode a Sparkplug message.
    pub decode_error: Option<String>,
}

impl Message {
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.payload).unwrap_or(serde_json::Value::Null)
    }
}

impl Peer {
    pub async fn subscribe(broker: &Broker, filter: &str) -> anyhow::Result<Peer> {
        Peer::start(broker, filter, None).await
    }

    /// A subscriber with a session the broker keeps (client id `id`, not clean): what is
    /// published while it reconnects waits for it.
    pub async fn subscribe_kept(broker: &Broker, filter: &str, id: &str) -> anyhow::Result<Peer> {
        Peer::start(broker, filter, Some(id)).await
    }

    /// A subscriber of the broker on `port` (one that another part starts and stops).
    pub async fn subscribe_port(port: u16, filter: &str) -> anyhow::Result<Peer> {
        Peer::start_on(port, filter, None).await
    }

    async fn start(broker: &Broker, filter: &str, id: Option<&str>) -> anyhow::Result<Peer> {
        Peer::start_on(broker.port, filter, id).await
    }

    async fn start_on(port: u16, filter: &str, id: Option<&str>) -> anyhow::Result<Peer> {
        let mut command = Command::new(crate::python());
        command
            .arg(repo_file("mqtt/client.py"))
            .arg(port.to_string())
            .arg(filter);
        if let Some(id) = id {
            command.arg(id);
        }
        let crate::Piped {
            child,
            stdin,
            lines,
        } = crate::spawn_piped(command)?;
        let mut peer = Peer {
            child,
            stdin,
            lines,
            pending: std::collections::VecDeque::new(),
        };
        let first = peer.line().await?;
        anyhow::ensure!(first["subscribed"] == true, "paho: {first}");
        Ok(peer)
    }

    async fn line(&mut self) -> anyhow::Result<serde_json::Value> {
        let line = tokio::time::timeout(crate::PATIENCE, self.lines.next_line())
            .await
            .map_err(|_| anyhow::anyhow!("no message from paho within {:?}", crate::PATIENCE))??
            .ok_or_else(|| anyhow::anyhow!("paho ended"))?;
        Ok(serde_json::from_str(&line)?)
    }

    /// The next message.
    pub async fn next(&mut self) -> anyhow::Result<Message> {
        match self.pending.pop_front() {
            Some(m) => Ok(m),
            None => self.read().await,
        }
    }

    async fn read(&mut self) -> anyhow::Result<Message> {
        let v = self.line().await?;
        Ok(Message {
            topic: v["topic"].as_str().unwrap_or_default().to_owned(),
            payload: v["payload"].as_str().unwrap_or_default().to_owned(),
            retain: v["retain"] == true,
            sparkplug: v["sparkplug"].clone(),
            decode_error: v["decode_error"].as_str().map(str::to_owned),
        })
    }

    /// The first message for which `f` holds (others are skipped).
    pub async fn until(&mut self, f: impl Fn(&Message) -> bool) -> anyhow::Result<Message> {
        let deadline = tokio::time::Instant::now() + crate::PATIENCE;
        loop {
            anyhow::ensure!(tokio::time::Instant::now() < deadline, "no such message");
            let m = self.next().await?;
            if f(&m) {
                return Ok(m);
            }
        }
    }

    pub async fn publish(&mut self, topic: &str, payload: &str) -> anyhow::Result<()> {
        self.send(serde_json::json!({"topic": topic, "payload": payload, "qos": 1}))
            .await
    }

    /// Publishes a retained message (QoS 1).
    pub async fn publish_retained(&mut self, topic: &str, payload: &str) -> anyhow::Result<()> {
        self.send(serde_json::json!({"topic": topic, "payload": payload, "qos": 1, "retain": true}))
            .await
    }

    /// Waits until the peer is subscribed again (after the broker restarted): publishes a
    /// marker to `marker` (which its filter must match) and waits for it to come back; what
    /// comes before it is kept for [`Peer::next`].
    pub async fn resync(&mut self, marker: &str) -> anyhow::Result<()> {
        let token = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos())
            .to_string();
        let deadline = tokio::time::Instant::now() + crate::PATIENCE;
        loop {
            anyhow::ensure!(
                tokio::time::Instant::now() < deadline,
                "the peer did not subscribe again"
            );
            self.publish(marker, &token).await?;
            let mut seen = Vec::new();
            let back = tokio::time::timeout(Duration::from_millis(500), async {
                loop {
                    let m = self.read().await?;
                    if m.topic == marker && m.payload == token {
                        return anyhow::Ok(());
                    }
                    seen.push(m);
                }
            })
            .await;
            self.pending.extend(seen);
            if let Ok(result) = back {
                return result;
            }
        }
    }

    /// Publishes a Sparkplug NCMD or DCMD encoded by pysparkplug: `metrics` are
    /// `{"name", "datatype" (as BOOLEAN, INT16, ...), "value"}`.
    pub async fn command(&mut self, topic: &str, metrics: serde_json::Value) -> anyhow::Result<()> {
        self.send(serde_json::json!({"topic": topic, "command": metrics, "qos": 0}))
            .await
    }

    /// The same, published retained (QoS 1): a stored message, not a command.
    pub async fn command_retained(
        &mut self,
        topic: &str,
        metrics: serde_json::Value,
    ) -> anyhow::Result<()> {
        self.send(serde_json::json!({"topic": topic, "command": metrics, "qos": 1, "retain": true}))
            .await
    }

    async fn send(&mut self, line: serde_json::Value) -> anyhow::Result<()> {
        self.stdin.write_all(format!("{line}\n").as_bytes()).await?;
        self.stdin.flush().await?;
        Ok(())
    }

    pub async fn stop(mut self) {
        let _ = tokio::time::timeout(Duration::from_secs(2), self.child.kill()).await;
    }
}

/// A TCP gate to a broker: while shut, a connection through it is closed at once (as if the
/// broker were away); while open, it is passed both ways. A test opens it when its own
/// peers are ready, so the gateway reaches the broker only then.
pub struct Gate {
    pub port: u16,
    open: std::sync::Arc<std::sync::atomic::AtomicBool>,
    task: tokio::task::JoinHandle<()>,
}

impl Gate {
    /// A gate to the broker on `broker`, open.
    pub async fn to(broker: u16) -> anyhow::Result<Gate> {
        use std::sync::atomic::Ordering;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let port = listener.local_addr()?.port();
        let open = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
        let gate = open.clone();
        let task = tokio::spawn(async move {
            while let Ok((mut client, _)) = listener.accept().await {
                if !gate.load(Ordering::SeqCst) {
                    continue; // dropped: closed at once
                }
                tokio::spawn(async move {
                    if let Ok(mut upstream) =
                        tokio::net::TcpStream::connect(("127.0.0.1", broker)).await
                    {
                        let _ = tokio::io::copy_bidirectional(&mut client, &mut upstream).await;
                    }
                });
            }
        });
        Ok(Gate { port, open, task })
    }

    pub fn shut(&self) {
        self.open.store(false, std::sync::atomic::Ordering::SeqCst);
    }

    pub fn open(&self) {
        self.open.store(true, std::sync::atomic::Ordering::SeqCst);
    }
}

impl Drop for Gate {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// A gateway configuration with the simulated device `sim` and a Sparkplug B edge node
/// (group `plant1`, node `line1`, writes on, every change reported) on the broker at `port`,
/// as client `<client>-<port>`; `extra` is appended (more of the `mqtt:` section).
pub fn sparkplug_config(client: &str, port: u16, extra: &str) -> String {
    format!(
        "devices:
  - {{ name: sim, profile: SimIo, refresh_rate: 50ms }}
mqtt:
  url: mqtt://127.0.0.1:{port}
  client_id: {client}-{port}
  sparkplug: {{ group_id: plant1, edge_node_id: line1 }}
  report: {{ min_interval: 1ms, max_interval: 1h }}
  writes: true
{extra}"
    )
}
