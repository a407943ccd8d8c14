//! OPC UA servers as devices (`protocol: opcua`): a link is an endpoint (`opcua:` with its
//! `url`), a device's fields are the server's variables (`node:` or `browse_path:`). Each
//! device is a subscription whose publishing interval is its refresh rate, one monitored
//! item per field; a server without subscriptions (or `subscribe: false`) is read every
//! refresh instead. Writes are Write service calls, the server's status code their
//! outcome. Namespace indexes the profile writes are resolved through their URIs, learned
//! from the first session: a server that restarts with its namespaces in another order
//! still gets the right nodes.

pub(crate) mod config;
pub mod import;
mod limits;
pub(crate) mod node;
mod resolve;
mod session;
mod subscribe;
mod write;

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use opcua::types::{NodeId, VariantScalarTypeId};

use super::WriteItem;
use super::{Driver, Read, Session};
use crate::cache::{Device, FieldError, Link};
use crate::config::{LinkConfig, Transport};
use crate::link::LinkFault;
use crate::metrics::Metrics;
use crate::profile::Words;
use limits::Service;
pub(crate) use session::Connection;

/// The OPC UA client driver.
pub(crate) struct OpcUa;

/// The key of its links' settings and the word of its profiles' `protocol`.
pub(crate) const PROTOCOL: &str = "opcua";

/// Why a session could not open or ended, as the library or the server said it.
#[derive(Debug, thiserror::Error)]
pub(crate) enum UaError {
    /// The session's open failed.
    #[error("{0}")]
    Open(String),
    /// The session ended (the connection closed, the server gone or halted).
    #[error("{0}")]
    Ended(String),
    /// The device's subscription could not be made.
    #[error("creating a subscription: {0}")]
    Subscription(String),
}

/// Its words in configuration.
const WORDS: Words = Words {
    protocol: PROTOCOL,
    point_key: "node",
    point_alternative: Some("browse_path"),
    link_key: PROTOCOL,
    link_at: "url",
    check_point: node::check,
    point_identity: |p| p.address.clone(),
    default_length: 64,
    example: "ns=3;s=Line1.Speed",
    scaled: false,
    field_keys: &[],
    device_keys: &[],
};

/// What is kept of a device between sessions.
pub(crate) struct Plan {
    /// Each field's node on the server in the session `generation` (or why it has none).
    nodes: Vec<Result<NodeId, String>>,
    /// Which session `nodes` and `watched` belong to (0: none yet).
    generation: u64,
    /// The URI of each namespace index the profile writes, from the first session.
    uris: HashMap<u16, String>,
    /// The device's subscription in session `generation`.
    watched: Option<subscribe::Watched>,
    /// Whether the device is read by subscription (else by reads every refresh).
    subscribe: bool,
    /// The variant type the server holds each field's value in, as last seen.
    types: Arc<Mutex<Vec<Option<VariantScalarTypeId>>>>,
}

impl Driver for OpcUa {
    type Plan = Plan;
    type Session = Connection;
    const NAME: &'static str = PROTOCOL;
    const STALE_WHILE_AWAY: bool = true;
    /// A session takes several requests (endpoints, secure channel, session, activation,
    /// the namespace array) and, with security, asymmetric cryptography; the first secure
    /// one makes the application's key pair.
    const OPEN_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(15);

    const WORDS: Option<&'static Words> = Some(&WORDS);
    type Settings = config::Settings;

    const READ_SETTINGS: super::ReadSettings<config::Settings> = config::read;

    const IMPORT: Option<super::Import> = Some(super::Import {
        from: PROTOCOL,
        options: &["--node"],
        source: "one endpoint URL",
    });

    fn import(url: &str, options: &super::ImportOptions<'_>, out: Option<&std::path::Path>) -> u8 {
        let root = super::option(options, "--node");
        import::run(url, root, out)
    }

    fn check(config: &LinkConfig, report: &mut crate::yaml::Report) {
        let Transport::Driver(d) = &config.transport else {
            return;
        };
        if let Some(settings) = config::read(&config.name, d, report) {
            for problem in config::check_files(&config.name, &settings) {
                report.push(d.settings.line, format!("link {}", config.name), problem);
            }
        }
    }

    fn warn(config: &LinkConfig, report: &mut crate::yaml::Report) {
        let Transport::Driver(d) = &config.transport else {
            return;
        };
        let mut quiet = crate::yaml::Report::new(report.file());
        if config::read(&config.name, d, &mut quiet).is_some_and(|s| s.accept_host_mismatch) {
            report.push(
                d.settings.line,
                format!("link {}", config.name),
                "opcua.accept_host_mismatch: the server's certificate is accepted whatever host names it carries (it must still be trusted)",
            );
        }
    }

    fn plan(device: &Device) -> Plan {
        let n = device.profile.fields.len();
        Plan {
            nodes: Vec::new(),
            generation: 0,
            uris: HashMap::new(),
            watched: None,
            subscribe: true,
            types: Arc::new(Mutex::new(vec![None; n])),
        }
    }

    async fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        _metrics: &Arc<Metrics>,
    ) -> Result<Connection, LinkFault> {
        let settings = Self::settings(config)?;
        session::open(settings, link).await
    }
}

/// The server's word on a field, published.
fn refuse(device: &Device, idx: usize, why: impl Into<String>) {
    device.publish(idx, Err(FieldError::Device(why.into())));
}

impl Session for Connection {
    type Plan = Plan;

    async fn read(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Read, LinkFault> {
        let started = tokio::time::Instant::now();
        self.fresh(device, plan).await?;
        if plan.subscribe {
            let dropped = self.dropped.load(std::sync::atomic::Ordering::Relaxed);
            match plan.watched.as_ref().map(|w| w.health(dropped)) {
                // The subscription vouches for every value it has not changed.
                Some(Ok(())) => self.ended(),
                Some(Err(why)) => {
                    // Its values are not vouched for until the new one reports them.
                    tracing::warn!(device = %device.name(), "{}", why.says());
                    device.doubt_reads(&FieldError::Device(why.says().to_owned()));
                    subscribe::watch(self, device, plan).await?;
                }
                None => subscribe::watch(self, device, plan).await?,
            }
        }
        if !plan.subscribe {
            self.read_all(device, plan).await?;
        }
        Ok(Read::Answered(started.elapsed()))
    }

    async fn write(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Plan,
        items: Vec<WriteItem>,
    ) -> Result<Option<FieldError>, LinkFault> {
        self.fresh(device, plan).await?;
        write::items(self, device, plan, items).await?;
        Ok(None)
    }

    /// Closes the session on the server (CloseSession, then CloseSecureChannel), as the
    /// gateway stops or the link is reopened.
    async fn close(mut self) {
        let session = self.session.clone();
        let _ = tokio::time::timeout(std::time::Duration::from_secs(1), session.disconnect()).await;
        self.closed = true;
    }

    async fn lost(&mut self) -> LinkFault {
        let why = self.lost_now().await;
        LinkFault::lost(UaError::Ended(why))
    }
}

impl Connection {
    /// Resolves the device's nodes in this session, the first time it is asked of it (a new
    /// session: a new subscription too).
    async fn fresh(&self, device: &Arc<Device>, plan: &mut Plan) -> Result<(), LinkFault> {
        if plan.generation != self.generation {
            resolve::nodes(self, device, plan).await?;
            plan.watched = None;
            plan.subscribe = self.settings.subscribe;
        }
        Ok(())
    }

    /// Reads every resolved field of the device once (the fallback without subscriptions).
    async fn read_all(&self, device: &Device, plan: &Plan) -> Result<(), LinkFault> {
        use opcua::types::{ReadValueId, TimestampsToReturn};
        let wanted: Vec<(usize, ReadValueId)> = plan
            .nodes
            .iter()
            .enumerate()
            .filter_map(|(i, n)| n.as_ref().ok().map(|n| (i, ReadValueId::from(n.clone()))))
            .collect();
        let ids: Vec<ReadValueId> = wanted.iter().map(|(_, r)| r.clone()).collect();
        let session = &self.session;
        let answered = limits::in_requests(self, Service::Read, &ids, |ids| {
            session.read(ids, TimestampsToReturn::Source, 0.0)
        })
        .await;
        for (asked, got) in answered {
            let wanted = &wanted[asked];
            let values = match got {
                Ok(values) => values,
                Err(e) => {
                    if let Some(fault) = self.fault(&e) {
                        return Err(fault);
                    }
                    for (i, _) in wanted {
                        refuse(device, *i, e.status().to_string());
                    }
                    continue;
                }
            };
            let mut types = subscribe::lock(&plan.types);
            let now = crate::cache::Stamp::now();
            for ((idx, _), dv) in wanted.iter().zip(values.iter()) {
                subscribe::publish(device, &mut types, *idx, dv, now);
            }
        }
        Ok(())
    }
}
