//! The OPC UA server as one of the list of front-ends (`api::front_end`): its section
//! compared, started on its address, stopped (its sessions end).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use futures_util::future::BoxFuture;

use super::changed_keys;
use crate::api::front_end::{Carried, FrontEnd, Running, Starting};
use crate::config::Config;
use crate::config::opcua::OpcUaConfig;
use crate::service::{Action, Kind, Service, restarted_section};

pub(crate) struct OpcUaFrontEnd;

impl FrontEnd for OpcUaFrontEnd {
    fn name(&self) -> &'static str {
        "opcua"
    }

    fn kind(&self) -> Kind {
        Kind::Opcua
    }

    fn changed(&self, old: &Config, new: &Config) -> Option<(Action, Vec<String>)> {
        let section = |c: &Config| {
            c.opcua.clone().map(|mut o| {
                o.line = 0;
                o
            })
        };
        (section(old) != section(new)).then(|| {
            restarted_section(
                &old.opcua,
                &new.opcua,
                "the OPC UA server",
                changed_keys,
                "(its sessions end)",
                "the OPC UA server is restarted: its sessions end and clients reconnect",
            )
        })
    }

    fn prepare(&self, config: &Config, base: &Path) -> Result<Option<Box<dyn Starting>>, String> {
        Ok(config.opcua.clone().map(|section| {
            Box::new(OpcUaStarting {
                section,
                base: base.to_owned(),
            }) as Box<dyn Starting>
        }))
    }
}

struct OpcUaStarting {
    section: OpcUaConfig,
    base: PathBuf,
}

impl Starting for OpcUaStarting {
    fn start(
        self: Box<Self>,
        service: Arc<Service>,
        _carried: Carried,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>> {
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
