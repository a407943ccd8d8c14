//! The front-end contract: every door of the gateway (HTTP with REST, SSE and the web
//! page; gRPC; the Modbus TCP and serial servers; MQTT; OPC UA) implements [`FrontEnd`],
//! and is one entry of the list (`crate::front_ends::all`). The composition root prepares
//! and starts them, the reloader asks each whether a new configuration restarts it,
//! prepares the ones that restart before anything is applied, then stops and starts them
//! ([`restart`]), knowing none by name.

mod listener;

use std::any::Any;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;

use futures_util::future::BoxFuture;

use crate::config::{Config, Section};
use crate::service::doors::HealthSchema;
use crate::service::{Action, Service};
use crate::tls::Tls;
use crate::yaml::{Node, Report};

pub(crate) use listener::Listen;

/// What a stopped front-end hands to the one started after it (MQTT's next `bdSeq`).
pub(crate) type Carried = Option<Box<dyn Any + Send>>;

/// A kind of front-end.
pub(crate) trait FrontEnd: Send + Sync {
    /// Its name: its section's key when it has a section of its own, else the name its
    /// listener has in `GET /api/v1/config`.
    fn name(&self) -> &'static str;

    /// Its name in the listening table (`GET /api/v1/config`), when it listens on a port.
    fn listener(&self) -> Option<&'static str> {
        None
    }

    /// Its `/readyz` detail as the OpenAPI document describes it, when it gives one.
    fn health_schema(&self) -> Option<HealthSchema> {
        None
    }

    /// Whether it reads a top-level section named as it is ([`FrontEnd::read`]).
    fn has_section(&self) -> bool {
        false
    }

    /// Reads its section as written (`node`, never `null`), every problem with its line.
    fn read(&self, _node: &Node, _report: &mut Report) -> Option<Box<dyn Section>> {
        None
    }

    /// Reads what its section names outside the file (passwords, a map), as `check` does:
    /// every problem is named, each on its own, and stops the start.
    fn check_files(
        &self,
        _config: &Config,
        _catalog: &crate::profile::Catalog,
        _base: &Path,
    ) -> Result<(), Vec<String>> {
        Ok(())
    }

    /// Its lines of the banner `serve` prints, when it runs; `banner_end`'s come after
    /// every front-end's.
    fn banner(&self, _service: &Service) -> Vec<String> {
        Vec::new()
    }

    fn banner_end(&self, _service: &Service) -> Vec<String> {
        Vec::new()
    }

    /// How its own section changed from `old` to `new`, as a reload's report says it (the
    /// action and its details); `None` when it did not.
    fn changed(&self, _old: &Config, _new: &Config) -> Option<(Action, Vec<String>)> {
        None
    }

    /// Whether a reload from `old` to `new` stops it and starts it again (a listener moved,
    /// TLS turned on or off, its section changed).
    fn restarts(&self, old: &Config, new: &Config) -> bool {
        self.changed(old, new).is_some()
    }

    /// Makes it ready to start, before anything is started or a reload applies anything:
    /// its listener bound, what its section names read. A problem is named and stops the
    /// start (or refuses the reload). `None` when the configuration has no such front-end.
    fn prepare<'a>(
        &'a self,
        prepare: &'a Prepare<'a>,
    ) -> BoxFuture<'a, Result<Option<Box<dyn Starting>>, String>>;
}

/// What a front-end is prepared with.
pub(crate) struct Prepare<'a> {
    /// The configuration it starts with.
    pub(crate) config: &'a Config,
    /// The configuration of the one running, on a reload.
    pub(crate) old: Option<&'a Config>,
    /// The running one's address, on a reload.
    pub(crate) now: Option<SocketAddr>,
    /// The config file's directory, for what its sections name.
    pub(crate) base: &'a Path,
}

/// What a front-end starts with.
pub(crate) struct Start {
    pub(crate) service: Arc<Service>,
    /// What the one it follows handed over.
    pub(crate) carried: Carried,
    /// The certificate HTTP and gRPC present, when TLS is on.
    pub(crate) tls: Option<Arc<Tls>>,
}

/// A front-end prepared and ready to start.
pub(crate) trait Starting: Send {
    fn start(self: Box<Self>, start: Start)
    -> BoxFuture<'static, Result<Box<dyn Running>, String>>;
}

/// A front-end that runs.
pub(crate) trait Running: Send + Sync {
    /// Stops it (its sessions said goodbye to, its port released); what its successor
    /// carries on, or why it did not stop in time.
    fn stop(self: Box<Self>, service: Arc<Service>) -> BoxFuture<'static, Result<Carried, String>>;

    /// The address its listener is bound to, when it has one.
    fn address(&self) -> Option<SocketAddr> {
        None
    }
}

/// A running front-end with its name, as the composition root and the reloader hold it.
pub(crate) struct Held {
    pub(crate) name: &'static str,
    pub(crate) running: Box<dyn Running>,
}

/// Stops the front-end `name` (if it runs) and starts `starting` (if any) in its place,
/// carrying on what it hands over.
pub(crate) async fn restart(
    service: &Arc<Service>,
    held: &mut Vec<Held>,
    name: &'static str,
    starting: Option<Box<dyn Starting>>,
    tls: Option<Arc<Tls>>,
) {
    let mut carried = None;
    if let Some(at) = held.iter().position(|h| h.name == name) {
        let old = held.remove(at);
        match old.running.stop(service.clone()).await {
            Ok(c) => carried = c,
            Err(e) => {
                tracing::warn!(front_end = name, error = %e, "restarted before the old one ended")
            }
        }
    }
    if let Some(starting) = starting {
        let start = Start {
            service: service.clone(),
            carried,
            tls,
        };
        match starting.start(start).await {
            Ok(running) => held.push(Held { name, running }),
            Err(e) => {
                tracing::error!(front_end = name, error = %e, "could not start with the reloaded configuration")
            }
        }
    }
}
