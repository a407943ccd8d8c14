//! An active/standby pair of gateways as one: the client is given both nodes' addresses,
//! talks to the active, and follows it when it changes. A standby refuses writes with
//! `UNAVAILABLE` and names the active (`iogate-active-grpc`); a lost node does not answer
//! at all; either way the client asks both nodes which is active and goes there.

use std::time::Duration;

use iogate_proto::pb;

use super::{Client, Error};

/// How long the client looks for the active of its pair before it gives up: more than
/// two leases of the longest lease a pair may have (60 s) would be too long for a caller;
/// this covers a takeover of the default 3 s lease with room.
pub const FOLLOW_PATIENCE: Duration = Duration::from_secs(15);

/// This node in its pair, as `GetHa` answers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HaStatus {
    /// The node's name; empty for a gateway alone.
    pub node: String,
    /// `active` or `standby`.
    pub role: String,
    /// Whether it is one node of a pair.
    pub paired: bool,
    /// The newest lease epoch it knows of.
    pub epoch: u64,
    /// The node holding the lease (empty when none is known).
    pub active_node: String,
    /// The active's gRPC address, when it is known.
    pub active_grpc: Option<String>,
}

impl From<pb::HaStatus> for HaStatus {
    fn from(s: pb::HaStatus) -> Self {
        HaStatus {
            active_grpc: s.active_addresses.get("grpc").map(|a| with_scheme(a)),
            node: s.node,
            role: s.role,
            paired: s.paired,
            epoch: s.epoch,
            active_node: s.active_node,
        }
    }
}

/// A gRPC address as the pair announces it (`host:port`) made a URL.
fn with_scheme(address: &str) -> String {
    if address.contains("://") {
        address.to_owned()
    } else {
        format!("http://{address}")
    }
}

impl Client {
    /// Connects to the active of the pair whose nodes answer at `urls` (one address is a
    /// gateway alone, or one node). Waits up to [`FOLLOW_PATIENCE`] for one to be active.
    pub async fn connect_pair(urls: &[String]) -> Result<Client, Error> {
        let Some(first) = urls.first() else {
            return Err(Error::Invalid("no gateway address given".into()));
        };
        if urls.len() == 1 {
            return Client::connect(first).await;
        }
        let found = active_of(urls, FOLLOW_PATIENCE).await?;
        let mut client = Client::connect(&found).await?;
        client.urls = urls.to_vec();
        Ok(client)
    }

    /// This node in its pair.
    pub async fn ha(&mut self) -> Result<HaStatus, Error> {
        let status = self.inner.get_ha(pb::GetHaRequest {}).await?;
        Ok(status.into_inner().into())
    }

    /// Goes to the active of the pair (after a call failed `UNAVAILABLE`): asks each node,
    /// follows what a standby says, and answers whether the client moved or not.
    pub async fn follow_active(&mut self) -> Result<(), Error> {
        if self.urls.len() < 2 {
            return Ok(());
        }
        let found = active_of(&self.urls, FOLLOW_PATIENCE).await?;
        let urls = std::mem::take(&mut self.urls);
        *self = Client::connect(&found).await?;
        self.urls = urls;
        Ok(())
    }

    /// Whether `e` is a refusal the pair's other node may not give: a standby's, or a node
    /// that does not answer, when the client knows a pair.
    pub(crate) fn should_follow(&self, e: &Error) -> bool {
        self.urls.len() > 1
            && matches!(e, Error::Status { code, .. } if *code == tonic::Code::Unavailable)
    }
}

/// The URL of the node of `urls` that says it is active (or that a standby names active
/// and says so itself), within `patience`.
async fn active_of(urls: &[String], patience: Duration) -> Result<String, Error> {
    let deadline = tokio::time::Instant::now() + patience;
    let mut last = String::from("no node answered");
    loop {
        for url in urls {
            match ask(url).await {
                Ok(status) if status.role == "active" => return Ok(url.clone()),
                Ok(status) => {
                    if let Some(active) = status.active_grpc.filter(|a| !urls.contains(a))
                        && ask(&active).await.is_ok_and(|s| s.role == "active")
                    {
                        return Ok(active);
                    }
                    last = format!("{url} is {}", status.role);
                }
                Err(e) => last = format!("{url}: {e}"),
            }
        }
        if tokio::time::Instant::now() >= deadline {
            return Err(Error::Invalid(format!(
                "no active gateway among {} after {patience:?} ({last})",
                urls.join(", ")
            )));
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

async fn ask(url: &str) -> Result<HaStatus, Error> {
    let connect = tokio::time::timeout(Duration::from_secs(2), async {
        let mut client = Client::connect(url).await?;
        client.ha().await
    });
    connect
        .await
        .map_err(|_| Error::Invalid(format!("{url} did not answer within 2 s")))?
}
