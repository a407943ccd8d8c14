//! The IEC 60870-5-104 outstation (`iec104_server:`): the gateway as a controlled station
//! for SCADA masters, as its Modbus server is for Modbus ones. Every served field of every
//! device (any protocol) is an information object (`table.rs`, `served.rs`), answered on
//! general interrogation and sent spontaneously on change (`spontaneous.rs`); commands
//! become writes, confirmed and terminated by their outcomes (`station.rs`); each master's
//! connection keeps the standard's windows and timers (`master.rs`). At most
//! `max_connections` masters are served, `max_connections_per_client` from one address;
//! one more is closed at once, logged. The wire format is the 104 driver's
//! (`drivers::iec104`).

mod config;
#[cfg(any(fuzzing, test))]
pub(crate) mod fuzz;
mod master;
mod selection;
mod served;
mod spontaneous;
mod station;
mod status;
pub(crate) mod table;
mod values;

use std::path::Path;
use std::sync::Arc;

use futures_util::future::BoxFuture;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use crate::api::front_end::{FrontEnd, Listen, Prepare, Running, Start, Starting};
use crate::config::{Config, Section};
use crate::profile::Catalog;
use crate::service::{Action, Service, restarted_section};
use crate::yaml::{Node, Report};
pub(crate) use config::Iec104ServerConfig;
use served::{Served, Source};
use table::Table;

pub(crate) struct Iec104FrontEnd;

const NAME: &str = "iec104_server";

/// The section of `config`, when it has one.
fn section(config: &Config) -> Option<&Iec104ServerConfig> {
    config.sections.get(NAME)
}

/// The outstation's points for `config`'s devices, as `iogate map --iec104` prints them:
/// the table, or every problem of the map file.
pub(crate) fn plan(
    config: &Config,
    catalog: &Catalog,
    base: &Path,
) -> Option<Result<Table, Vec<String>>> {
    let section = section(config)?;
    let devices: Vec<(&str, &crate::profile::Profile)> = config
        .devices
        .iter()
        .filter_map(|d| {
            catalog
                .get(&d.profile)
                .map(|p| (d.name.as_str(), p.as_ref()))
        })
        .collect();
    Some(match &section.map {
        config::MapSource::Auto => Ok(Table::auto(devices, None)),
        config::MapSource::File(path) => {
            // Every problem at once: the file's own, then its entries' against the fields.
            let (entries, mut problems) = table::read_some(&base.join(path));
            match Table::of_entries(&entries, devices) {
                Err(more) => problems.extend(more),
                Ok(table) if problems.is_empty() => return Some(Ok(table)),
                Ok(_) => {}
            }
            Err(problems)
        }
    })
}

impl FrontEnd for Iec104FrontEnd {
    fn name(&self) -> &'static str {
        NAME
    }

    fn listener(&self) -> Option<&'static str> {
        Some("iec104")
    }

    fn health_schema(&self) -> Option<crate::service::doors::HealthSchema> {
        Some(crate::service::doors::HealthSchema {
            name: NAME,
            schema_name: "Iec104Health",
            schema: serde_json::to_value(<status::Iec104Health as utoipa::PartialSchema>::schema())
                .unwrap_or_default(),
            description: "The IEC 104 outstation, when one is configured: its masters connected and those in\ndata transfer (detail only).",
        })
    }

    fn has_section(&self) -> bool {
        true
    }

    fn read(&self, node: &Node, report: &mut Report) -> Option<Box<dyn Section>> {
        config::read(node, report).map(|s| Box::new(s) as Box<dyn Section>)
    }

    fn check_files(
        &self,
        config: &Config,
        catalog: &Catalog,
        base: &Path,
    ) -> Result<(), Vec<String>> {
        match plan(config, catalog, base) {
            Some(Err(problems)) => Err(problems.iter().map(|p| format!("map: {p}")).collect()),
            _ => Ok(()),
        }
    }

    fn banner(&self, service: &Service) -> Vec<String> {
        service
            .listening
            .bound("iec104")
            .map(|addr| format!("IEC 104:   {addr} (iogate map --iec104 prints the IOAs)"))
            .into_iter()
            .collect()
    }

    fn changed(&self, old: &Config, new: &Config) -> Option<(Action, Vec<String>)> {
        let unlined = |c: Option<&Iec104ServerConfig>| {
            c.cloned().map(|mut s| {
                s.line = 0;
                s
            })
        };
        let (old, new) = (unlined(section(old)), unlined(section(new)));
        (old != new).then(|| {
            restarted_section(
                &old,
                &new,
                "the IEC 104 outstation",
                |a, b| {
                    let file = |s: &Iec104ServerConfig| s.map_file.as_ref().map(|(p, _)| p.clone());
                    let same_file = file(a) == file(b) && a.map == b.map;
                    vec![
                        (same_file && a.map_file != b.map_file)
                            .then(|| "its map file's contents changed".to_owned()),
                    ]
                },
                "(its masters reconnect)",
                "the IEC 104 outstation is restarted: its masters reconnect and interrogate",
            )
        })
    }

    fn prepare<'a>(
        &'a self,
        p: &'a Prepare<'a>,
    ) -> BoxFuture<'a, Result<Option<Box<dyn Starting>>, String>> {
        Box::pin(async move {
            let Some(section) = section(p.config).cloned() else {
                return Ok(None);
            };
            let source = Source::read(&section.map, p.base).map_err(|p| p.join("; "))?;
            let was = p.old.and_then(section_listen);
            let key = "iec104_server.listen";
            let listen = Listen::prepare(p, section.listen, was, key, "--iec104").await?;
            Ok(Some(Box::new(Iec104Starting {
                section,
                source,
                listen,
            }) as Box<dyn Starting>))
        })
    }
}

fn section_listen(config: &Config) -> Option<std::net::SocketAddr> {
    section(config).map(|s| s.listen)
}

struct Iec104Starting {
    section: Iec104ServerConfig,
    source: Source,
    listen: Listen,
}

impl Starting for Iec104Starting {
    fn start(
        self: Box<Self>,
        start: Start,
    ) -> BoxFuture<'static, Result<Box<dyn Running>, String>> {
        Box::pin(async move {
            let service = start.service;
            let Iec104Starting {
                section,
                source,
                listen,
            } = *self;
            let serving = service.clone();
            let serve =
                move |listener, stop| serve(listener, serving, Arc::new(section), source, stop);
            listen
                .serve(
                    "iec104_server.listen",
                    "iec104",
                    &service,
                    |a| a.to_string(),
                    serve,
                )
                .await
        })
    }
}

/// Accepts masters until `stop`; keeps the table over the devices as they come and go.
async fn serve(
    listener: TcpListener,
    service: Arc<Service>,
    section: Arc<Iec104ServerConfig>,
    source: Source,
    stop: CancellationToken,
) {
    let first = Served::of(&service, &source, None);
    if let Source::Entries(entries) = &source {
        for e in entries.iter().filter(|e| first.table.get(e.ioa).is_none()) {
            tracing::warn!(ioa = e.ioa, field = %format!("{}.{}", e.device, e.field), "IEC 104 map entry not served: no such running device or field");
        }
    }
    let (table_tx, table) = watch::channel(Arc::new(first));
    let metrics = service.metrics.kept(status::Iec104Metrics::new);
    let door: Arc<dyn crate::service::doors::Door> = Arc::new(status::Iec104Door(metrics.clone()));
    service.doors.attach(door.clone());
    let mut devices = service.watch_devices();
    let selections = selection::Selections::default();
    let all = service
        .metrics
        .bound("iec104_connections", section.max_connections);
    let per_client = (service.metrics).per_client(
        "iec104_connections_per_client",
        section.max_connections_per_client,
    );
    loop {
        let accepted = tokio::select! {
            _ = stop.cancelled() => break,
            Ok(()) = devices.changed() => {
                let next = Served::of(&service, &source, Some(&table_tx.borrow()));
                table_tx.send_replace(Arc::new(next));
                continue;
            }
            a = listener.accept() => a,
        };
        let (io, peer) = match accepted {
            Ok(a) => a,
            Err(e) => {
                tracing::warn!(error = %e, "cannot accept an IEC 104 connection");
                tokio::time::sleep(std::time::Duration::from_millis(50)).await;
                continue;
            }
        };
        // Both places, or neither (a place taken is given back when dropped).
        let Some(slot) = per_client
            .take(peer.ip())
            .and_then(|c| Some((c, all.take()?)))
        else {
            tracing::info!(%peer, "IEC 104 master refused: max_connections or max_connections_per_client reached");
            drop(io);
            continue;
        };
        let _ = io.set_nodelay(true);
        let master = master::Master {
            io,
            peer,
            config: section.clone(),
            service: service.clone(),
            served: table.clone(),
            metrics: metrics.clone(),
            selections: selections.clone(),
        };
        tracing::info!(%peer, "IEC 104 master connected");
        let stop = stop.clone();
        service.tasks().spawn(async move {
            master.serve(stop).await;
            drop(slot);
        });
    }
    // A restarted outstation's successor may have attached its own already.
    service.doors.detach_if(NAME, &door);
}
