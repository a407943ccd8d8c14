//! The OPC UA server as one of the list of front-ends (`api::front_end`): its section
//! compared, started on its address, stopped (its sessions end).

use std::path::PathBuf;
use std::sync::Arc;

use futures_util::future::BoxFuture;

use super::changed_keys;
use super::config::OpcUaConfig;
use crate::api::front_end::{Carried, FrontEnd, Prepare, Running, Start, Starting};
use crate::config::{Config, Section};
use crate::service::{Action, Service, restarted_section};
use crate::yaml::{Node, Report};

pub(crate) struct OpcUaFrontEnd;

impl FrontEnd for OpcUaFrontEnd {
    fn name(&self) -> &'static str {
        "opcua"
    }

    fn listener(&self) -> Option<&'static str> {
        Some("opcua")
    }

    fn has_section(&self) -> bool {
        true
    }

    fn read(&self, node: &Node, report: &mut Report) -> Option<Box<dyn Section>> {
        super::config::read(node, report).map(|s| Box::new(s) as Box<dyn Section>)
    }

    fn banner(&self, service: &Service) -> Vec<String> {
        let Some(addr) = service.listening.bound("opcua") else {
            return Vec::new();
        };
        vec![format!(
            "OPC UA:    opc.tcp://{addr}/ (namespace {})",
            super::NAMESPACE
        )]
    }

    fn changed(&self, old: &Config, new: &Config) -> Option<(Action, Vec<String>)> {
        let (old, new) = (section(old).cloned(), section(new).cloned());
        let unlined = |c: &Option<OpcUaConfig>| {
            c.clone().map(|mut o| {
                o.line = 0;
                o
            })
        };
        (unlined(&old) != unlined(&new)).then(|| {
            restarted_section(
                &old,
                &new,
                "the OPC UA server",
                changed_keys,
                "(its sessions end)",
                "the OPC UA server is restarted: its sessions end and clients reconnect",
            )
        })
    }

    fn prepare<'a>(
        &'a self,
        p: &'a Prepare<'a>,
    ) -> BoxFuture<'a, Result<Option<Box<dyn Starting>>, String>> {
        let starting = section(p.config).cloned().map(|section| {
            Box::new(OpcUaStarting {
                section,
                base: p.base.to_owned(),
            }) as Box<dyn Starting>
        });
        Box::pin(std::future::ready(Ok(starting)))
    }
}

/// The OPC UA section of `config`, when it has one.
fn section(config: &Config) -> Option<&OpcUaConfig> {
    config.sections.get("opcua")
}

struct OpcUaStarting {
    section: OpcUaConfig,
    base: PathBuf,
}

impl Starting for OpcUaStarting {
    fn start(
        self: Box<Self>,
        start: Start,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>> {
        let service = start.service;
        Box::pin(async move {
            super::start(&service, &self.section, &self.base)
                .await
                .map(|r| Box::new(r) as Box<dyn Running>)
        })
    }
}

impl Running for super::Running {
    fn stop(
        self: Box<Self>,
        _service: Arc<Service>,
    ) -> BoxFuture<'static, Result<Carried, String>> {
        Box::pin(async move { super::Running::stop(*self).await.map(|()| None) })
    }
}
