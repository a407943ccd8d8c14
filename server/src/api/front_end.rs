//! The contract of a front-end started from a section of its own and started again by a
//! reload when that section changes (MQTT, OPC UA). The composition root starts them, and
//! the reloader compares, stops and starts them, as one list ([`all`]) knowing none by
//! name. Adding such a front-end is its folder and its line in [`all`].

use std::any::Any;
use std::path::Path;
use std::sync::Arc;

use futures_util::future::BoxFuture;

use crate::config::Config;
use crate::service::{Action, Kind, Service};

/// What a stopped front-end hands to the one started after it (MQTT's next `bdSeq`).
pub(crate) type Carried = Option<Box<dyn Any + Send>>;

/// A kind of front-end.
pub(crate) trait FrontEnd: Send + Sync {
    /// Its section's key.
    fn name(&self) -> &'static str;

    /// The kind of a reload report's item about its section.
    fn kind(&self) -> Kind;

    /// How its section changed from `old` to `new`, as a reload's report says it (the
    /// action and its details); `None` when it did not. A change restarts the front-end.
    fn changed(&self, old: &Config, new: &Config) -> Option<(Action, Vec<String>)>;

    /// Reads what its section names outside the file (passwords, certificates), before
    /// anything is started or a reload applies anything: a problem is named and stops the
    /// start (or refuses the reload). `None` when the section is absent.
    fn prepare(&self, config: &Config, base: &Path) -> Result<Option<Box<dyn Starting>>, String>;
}

/// A front-end prepared and ready to start.
pub(crate) trait Starting: Send {
    fn start(
        self: Box<Self>,
        service: Arc<Service>,
        carried: Carried,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>>;
}

/// A front-end that runs.
pub(crate) trait Running: Send + Sync {
    /// Stops it (its sessions said goodbye to, its port released); what its successor
    /// carries on, or why it did not stop in time.
    fn stop(self: Box<Self>, service: Arc<Service>) -> BoxFuture<'static, Result<Carried, String>>;
}

/// Every front-end of this kind, in the order they start.
pub(crate) fn all() -> Vec<Box<dyn FrontEnd>> {
    vec![
        Box::new(super::mqtt::MqttFrontEnd),
        Box::new(super::opcua::OpcUaFrontEnd),
    ]
}

/// A running front-end with its name, as the composition root and the reloader hold it.
pub(crate) struct Held {
    pub(crate) name: &'static str,
    pub(crate) running: Box<dyn Running>,
}

/// Prepares and starts every configured front-end of the list.
pub(crate) async fn start_all(
    service: &Arc<Service>,
    config: &Config,
    base: &Path,
) -> Result<Vec<Held>, String> {
    let mut held = Vec::new();
    for front_end in all() {
        if let Some(starting) = front_end.prepare(config, base)? {
            let running = starting.start(service.clone(), None).await?;
            held.push(Held {
                name: front_end.name(),
                running,
            });
        }
    }
    Ok(held)
}
