//! The MQTT front-end as one of the list of front-ends (`api::front_end`): its section
//! compared, its files read, started, stopped with its next `bdSeq` carried on.

use std::any::Any;
use std::path::Path;
use std::sync::Arc;

use futures_util::future::BoxFuture;

use super::config::MqttConfig;
use super::{Prepared, changed_keys, prepare, spawn};
use crate::api::front_end::{Carried, FrontEnd, Prepare, Running, Start, Starting};
use crate::config::{Config, Section};
use crate::service::doors::HealthSchema;
use crate::service::{Action, Service, restarted_section};
use crate::yaml::{Node, Report};

pub(crate) struct MqttFrontEnd;

impl FrontEnd for MqttFrontEnd {
    fn name(&self) -> &'static str {
        "mqtt"
    }

    fn health_schema(&self) -> Option<HealthSchema> {
        Some(HealthSchema {
            name: "mqtt",
            schema_name: "MqttHealth",
            schema: serde_json::to_value(
                <super::state::MqttHealth as utoipa::PartialSchema>::schema(),
            )
            .unwrap_or_default(),
            description: "The MQTT front-end, when one is configured: a broker away does not make the gateway\nunready (its messages wait in the buffer), so this is detail only.",
        })
    }

    fn has_section(&self) -> bool {
        true
    }

    fn read(&self, node: &Node, report: &mut Report) -> Option<Box<dyn Section>> {
        super::config::read(node, report).map(|s| Box::new(s) as Box<dyn Section>)
    }

    fn changed(&self, old: &Config, new: &Config) -> Option<(Action, Vec<String>)> {
        let (old, new) = (section(old).cloned(), section(new).cloned());
        let unlined = |c: &Option<MqttConfig>| {
            c.clone().map(|mut m| {
                m.line = 0;
                m
            })
        };
        (unlined(&old) != unlined(&new)).then(|| {
            restarted_section(
                &old,
                &new,
                "the MQTT front-end",
                changed_keys,
                "(NDEATH, offline state)",
                "the MQTT connection is closed (NDEATH) and opened again (NBIRTH, next bdSeq); the buffer on disk is kept",
            )
        })
    }

    fn check_files(
        &self,
        config: &Config,
        _catalog: &crate::profile::Catalog,
        base: &Path,
    ) -> Result<(), Vec<String>> {
        match section(config) {
            Some(section) => prepare(section, base).map(drop).map_err(|e| vec![e]),
            None => Ok(()),
        }
    }

    fn prepare<'a>(
        &'a self,
        p: &'a Prepare<'a>,
    ) -> BoxFuture<'a, Result<Option<Box<dyn Starting>>, String>> {
        let prepared = match section(p.config) {
            None => Ok(None),
            Some(section) => prepare(section, p.base)
                .map(|prepared| Some(Box::new(MqttStarting(prepared)) as Box<dyn Starting>)),
        };
        Box::pin(std::future::ready(prepared))
    }
}

/// The MQTT section of `config`, when it has one.
pub(crate) fn section(config: &Config) -> Option<&MqttConfig> {
    config.sections.get("mqtt")
}

impl Section for MqttConfig {
    fn line(&self) -> u64 {
        self.line
    }
}

struct MqttStarting(Prepared);

impl Starting for MqttStarting {
    fn start(
        self: Box<Self>,
        start: Start,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>> {
        let Start {
            service, carried, ..
        } = start;
        // The Sparkplug `bdSeq` goes on from the stopped session's.
        let bd_seq = carried
            .and_then(|c| c.downcast::<u8>().ok())
            .map_or(0, |b| *b);
        let started = spawn(service, self.0, bd_seq)
            .map(|r| Box::new(r) as Box<dyn Running>)
            .map_err(|e| e.to_string());
        Box::pin(std::future::ready(started))
    }
}

impl Running for super::Running {
    fn stop(self: Box<Self>, service: Arc<Service>) -> BoxFuture<'static, Result<Carried, String>> {
        Box::pin(async move {
            let next = super::Running::stop(*self, &service).await?;
            Ok(Some(Box::new(next) as Box<dyn Any + Send>))
        })
    }
}
