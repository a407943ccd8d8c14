//! The pair under test: two gateway processes on one config but their node, the field
//! device behind a tap, and a client that writes to whichever node is active.

use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use iogate_tests::devices::temp_dir;
use iogate_tests::{GatewayProcess, PATIENCE, TestGateway};
use serde_json::{Value, json};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::field::{Field, PROFILE, device_of};

const BIN: &str = env!("CARGO_BIN_EXE_gateway");

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Node {
    A,
    B,
}

impl Node {
    pub fn index(self) -> usize {
        match self {
            Node::A => 0,
            Node::B => 1,
        }
    }

    pub fn other(self) -> Node {
        match self {
            Node::A => Node::B,
            Node::B => Node::A,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Node::A => "a",
            Node::B => "b",
        }
    }
}

/// Two gateway processes, `a` and `b`.
pub struct Pair {
    procs: [Option<GatewayProcess>; 2],
    /// Each node's directory and configuration, to start it again.
    homes: [(std::path::PathBuf, String); 2],
    pub bases: [String; 2],
    clients: [TestGateway; 2],
    pub field: Field,
}

impl Pair {
    /// Starts `a` (which becomes active) then `b` (standby), each reaching the broker at
    /// its port of `brokers`.
    pub async fn start(name: &str, brokers: [u16; 2], lease: u64) -> anyhow::Result<Pair> {
        Pair::start_with(name, brokers, lease, |_| "arbiter: mqtt".to_owned()).await
    }

    /// Starts the pair with the lease on `arbiter` (each node's `ha:` keys for it), and the
    /// handover on the brokers.
    pub async fn start_with(
        name: &str,
        brokers: [u16; 2],
        lease: u64,
        arbiter: impl Fn(Node) -> String,
    ) -> anyhow::Result<Pair> {
        let field = Field::start().await?;
        let dir = temp_dir(name);
        std::fs::create_dir_all(dir.join("profiles"))?;
        std::fs::write(dir.join("profiles/setpoints.yaml"), PROFILE)?;
        let config = |node: Node| {
            format!(
                "profiles: {profiles}\n{field}\
                 mqtt:\n  url: mqtt://127.0.0.1:{broker}\n  json: {{ prefix: plant }}\n\
                 \x20 sparkplug: {{ group_id: plant, edge_node_id: pair }}\n\
                 opcua: {{ listen: 127.0.0.1:0, pki_dir: {pki} }}\n\
                 ha: {{ node: {node}, lease: {lease}s, {arbiter} }}\n",
                pki = dir.join(node.name()).join("pki").display(),
                profiles = dir.join("profiles").display(),
                field = field.config(),
                broker = brokers[node.index()],
                node = node.name(),
                arbiter = arbiter(node),
            )
        };
        let mut procs = [None, None];
        for node in [Node::A, Node::B] {
            let home = dir.join(node.name());
            std::fs::create_dir_all(&home)?;
            let process = GatewayProcess::start(BIN, &home, &config(node)).await?;
            let base = process.gateway.base.clone();
            procs[node.index()] = Some(process);
            let client = TestGateway::remote(base);
            let want = node == Node::A;
            client
                .until("/api/v1/ha", "its role", |ha| {
                    (ha["role"] == "active") == want && ha["active"]["node"] == "a"
                })
                .await?;
        }
        let bases = procs.each_ref().map(|p| {
            p.as_ref()
                .map(|p| p.gateway.base.clone())
                .unwrap_or_default()
        });
        let clients = bases.clone().map(TestGateway::remote);
        let homes = [Node::A, Node::B].map(|n| (dir.join(n.name()), config(n)));
        Ok(Pair {
            procs,
            homes,
            bases,
            clients,
            field,
        })
    }

    /// `GET /api/v1/ha` of `node` (null when it does not answer).
    pub async fn ha(&self, node: Node) -> Value {
        match self.clients[node.index()].get("/api/v1/ha").await {
            Ok((200, body)) => body,
            _ => Value::Null,
        }
    }

    pub async fn until_ha(&self, node: Node, what: &str, check: impl Fn(&Value) -> bool) -> Value {
        self.clients[node.index()]
            .until("/api/v1/ha", what, check)
            .await
            .expect(what)
    }

    pub async fn until_active(&self, node: Node) -> Value {
        self.until_ha(node, "the node active", |ha| ha["role"] == "active")
            .await
    }

    /// The address of `node`'s OPC UA server.
    pub async fn opcua(&self, node: Node) -> String {
        self.listening(node, "opcua").await
    }

    /// The URL of `node`'s gRPC server.
    pub async fn grpc(&self, node: Node) -> String {
        format!("http://{}", self.listening(node, "grpc").await)
    }

    /// Where `node`'s `server` listens.
    async fn listening(&self, node: Node, server: &str) -> String {
        let (_, config) = self.clients[node.index()]
            .get("/api/v1/config")
            .await
            .expect("config");
        config["listening"]
            .as_array()
            .and_then(|l| l.iter().find(|s| s["server"] == server))
            .and_then(|s| s["address"].as_str())
            .map(str::to_owned)
            .unwrap_or_else(|| panic!("no {server} server in {config}"))
    }

    /// `GET /api/v1/writes/<generation>` on `node`.
    pub async fn write_record(&self, node: Node, generation: u64) -> (u16, Value) {
        self.clients[node.index()]
            .get(&format!("/api/v1/writes/{generation}"))
            .await
            .expect("the write's record")
    }

    /// `PUT path` of a declaration on `node`: created.
    pub async fn declare(&self, node: Node, path: &str, body: Value) {
        let (status, answer) = self.clients[node.index()]
            .send(reqwest::Method::PUT, path, body.to_string())
            .await
            .expect("declare");
        assert_eq!(status, 201, "{path}: {answer}");
    }

    /// Waits until `path` answers 200 on `node`.
    pub async fn until_path(&self, node: Node, path: &str, what: &str) -> Value {
        self.clients[node.index()]
            .until(path, what, |_| true)
            .await
            .expect(what)
    }

    /// Starts `node` again after a kill, and waits until it is the standby.
    pub async fn restart(&mut self, node: Node) {
        let (home, config) = &self.homes[node.index()];
        let process = GatewayProcess::start(BIN, home, config)
            .await
            .expect("restart");
        let base = process.gateway.base.clone();
        self.procs[node.index()] = Some(process);
        self.bases[node.index()] = base.clone();
        self.clients[node.index()] = TestGateway::remote(base);
        let other = node.other().name();
        self.until_ha(node, "the standby again", |ha| {
            ha["role"] == "standby" && ha["active"]["node"] == other
        })
        .await;
    }

    /// The process id of `node`.
    pub fn pid(&self, node: Node) -> u32 {
        self.procs[node.index()]
            .as_ref()
            .and_then(GatewayProcess::pid)
            .expect("a running node")
    }

    /// Every write `from` said was written, found on the other node with its outcome and
    /// value: all that settled before `killed` less the active's gathering of records
    /// (20 ms, with margin); those settled later may be lost with the node. The number
    /// checked.
    pub async fn assert_handed_over(&self, log: &WriteLog, from: Node, killed: Instant) -> usize {
        let margin = Duration::from_millis(100);
        let (mut checked, mut lost) = (0, 0);
        for e in log
            .entries
            .iter()
            .filter(|e| e.node == from && e.outcome.as_deref() == Some("written"))
        {
            let (status, record) = self.write_record(from.other(), e.generation).await;
            // Lost with the node, or found pending and ended by the takeover.
            if e.settled + margin >= killed && (status == 404 || record["status"] != "written") {
                lost += 1;
                continue;
            }
            assert_eq!(
                status,
                200,
                "write {} of node {} on the other: {record}",
                e.generation,
                from.name()
            );
            assert_eq!(
                record["status"],
                "written",
                "settled {:?} before the kill: {record}",
                killed.saturating_duration_since(e.settled)
            );
            assert_eq!(record["value"], e.value, "{record}");
            checked += 1;
        }
        eprintln!(
            "handed over: {checked} written records found; {lost} settled in the last {margin:?} before the kill not"
        );
        checked
    }

    /// SIGKILL of `node`'s process.
    pub async fn kill(&mut self, node: Node) {
        if let Some(p) = self.procs[node.index()].take() {
            p.kill().await.expect("kill");
        }
    }
}

/// One write the client asked for.
#[derive(Debug, Clone)]
pub struct Entry {
    pub value: u16,
    pub node: Node,
    pub generation: u64,
    /// When the node accepted it.
    pub at: Instant,
    /// Its final status as the node said (`written`, `superseded`, `failed`), if it said.
    pub outcome: Option<String>,
    /// When the client learnt it.
    pub settled: Instant,
}

#[derive(Debug, Default, Clone)]
pub struct WriteLog {
    pub entries: Vec<Entry>,
    /// Writes refused (a standby's 503, a dead node).
    pub refused: usize,
}

impl WriteLog {
    pub fn asked(&self) -> usize {
        self.entries.len() + self.refused
    }

    /// The values a node said were written.
    pub fn written(&self) -> Vec<u16> {
        self.entries
            .iter()
            .filter(|e| e.outcome.as_deref() == Some("written"))
            .map(|e| e.value)
            .collect()
    }
}

/// A client writing a new setpoint every 10 ms to whichever node takes it (odd values to
/// `pump`, even ones to `tank`), following each write to its outcome.
pub struct Writer {
    log: Arc<Mutex<WriteLog>>,
    stop: watch::Sender<bool>,
    task: JoinHandle<()>,
}

impl Writer {
    pub fn start(pair: &Pair) -> Writer {
        let log = Arc::new(Mutex::new(WriteLog::default()));
        let (stop, stopped) = watch::channel(false);
        let clients = pair.bases.clone().map(TestGateway::remote);
        let task = tokio::spawn(write(clients, log.clone(), stopped));
        Writer { log, stop, task }
    }

    fn log(&self) -> WriteLog {
        self.log.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Waits until `node` said `n` more writes were written than when asked.
    pub async fn until_written(&self, node: Node, n: usize) {
        let count = |log: &WriteLog| {
            log.entries
                .iter()
                .filter(|e| e.node == node && e.outcome.as_deref() == Some("written"))
                .count()
        };
        let start = count(&self.log());
        let deadline = Instant::now() + PATIENCE;
        while count(&self.log()) < start + n {
            assert!(
                Instant::now() < deadline,
                "node {} wrote too little: {:?}",
                node.name(),
                self.log().entries.last()
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    pub async fn stop(self) -> WriteLog {
        let _ = self.stop.send(true);
        let Writer { log, task, .. } = self;
        let _ = task.await;
        log.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

async fn write(clients: [TestGateway; 2], log: Arc<Mutex<WriteLog>>, stop: watch::Receiver<bool>) {
    let mut target = Node::A;
    let mut value: u16 = 0;
    let mut tick = tokio::time::interval(Duration::from_millis(10));
    while !*stop.borrow() {
        tick.tick().await;
        value += 1;
        let body = json!({ "value": value }).to_string();
        let client = &clients[target.index()];
        let path = format!("/api/v1/devices/{}/fields/sp", device_of(value));
        let at = Instant::now();
        let put = tokio::time::timeout(
            Duration::from_secs(2),
            client.send(reqwest::Method::PUT, &path, body),
        )
        .await;
        let Ok(Ok((202, accepted))) = put else {
            log.lock().unwrap_or_else(|e| e.into_inner()).refused += 1;
            target = target.other();
            continue;
        };
        let generation = accepted["generation"].as_u64().unwrap_or_default();
        let outcome = follow(client, generation).await;
        log.lock()
            .unwrap_or_else(|e| e.into_inner())
            .entries
            .push(Entry {
                value,
                node: target,
                generation,
                at,
                outcome,
                settled: Instant::now(),
            });
    }
}

/// The write's final status, while its node answers (at most 3 s).
async fn follow(client: &TestGateway, generation: u64) -> Option<String> {
    let deadline = Instant::now() + Duration::from_secs(3);
    while Instant::now() < deadline {
        match client.get(&format!("/api/v1/writes/{generation}")).await {
            Ok((200, w)) if w["status"] != "pending" => {
                return w["status"].as_str().map(str::to_owned);
            }
            Ok((200, _)) => tokio::time::sleep(Duration::from_millis(2)).await,
            _ => return None,
        }
    }
    None
}
