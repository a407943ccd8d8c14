//! What the outstation serves right now: the point table over the running devices, the
//! order a general (and a counter) interrogation answers in (by type, then address, so
//! that one ASDU carries many objects), and the current value of a point read from the
//! cache. Made again when devices come or go; an automatic map keeps the addresses it gave.

use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::sync::Arc;

use tokio::time::Instant;

use super::config::MapSource;
use super::table::{Entry, Point, Table};
use crate::cache::Device;
use crate::cache::sample::Quality;
use crate::codec::Value;
use crate::drivers::iec104::types::Kind;
use crate::service::Service;

pub(crate) struct Served {
    pub(crate) table: Table,
    devices: HashMap<String, Arc<Device>>,
    /// Monitor points but counters, by type then address; counters the same.
    pub(crate) general: Vec<usize>,
    pub(crate) counters: Vec<usize>,
}

/// Where the points come from: every field, or a map file's entries (read when prepared).
#[derive(Debug, Clone)]
pub(crate) enum Source {
    Auto,
    Entries(Vec<Entry>),
}

impl Source {
    /// The source the section names, its file read from `base`.
    pub(crate) fn read(map: &MapSource, base: &std::path::Path) -> Result<Source, Vec<String>> {
        match map {
            MapSource::Auto => Ok(Source::Auto),
            MapSource::File(path) => {
                let path: PathBuf = base.join(path);
                super::table::read_file(&path).map(Source::Entries)
            }
        }
    }
}

impl Served {
    /// The points over the service's devices now; `before` the table served until now.
    pub(crate) fn of(service: &Service, source: &Source, before: Option<&Served>) -> Served {
        let devices = service.devices();
        let named = devices.iter().map(|d| (d.name(), d.profile.as_ref()));
        let table = match source {
            Source::Auto => Table::auto(named, before.map(|b| &b.table)),
            Source::Entries(entries) => {
                // A device the file names that is not running is left out (said at start);
                // an entry that no longer fits its field (a profile reloaded) alone.
                let running: HashSet<&str> = devices.iter().map(|d| d.name()).collect();
                let present: Vec<Entry> = entries
                    .iter()
                    .filter(|e| running.contains(e.device.as_str()))
                    .cloned()
                    .collect();
                let (table, problems) = Table::of_some_entries(&present, named);
                for p in problems {
                    tracing::warn!(problem = %p, "an IEC 104 map entry is not served");
                }
                table
            }
        };
        let order = |counters: bool| {
            let mut order: Vec<usize> = (0..table.points.len())
                .filter(|&i| {
                    let p = &table.points[i];
                    !p.is_command() && (p.kind() == Kind::Counter) == counters
                })
                .collect();
            order.sort_by_key(|&i| (table.points[i].asdu.0, table.points[i].ioa));
            order
        };
        let (general, counters) = (order(false), order(true));
        let devices = devices
            .into_iter()
            .map(|d| (d.name().to_owned(), d))
            .collect();
        Served {
            table,
            devices,
            general,
            counters,
        }
    }

    pub(crate) fn point(&self, i: usize) -> &Point {
        &self.table.points[i]
    }

    pub(crate) fn device(&self, name: &str) -> Option<Arc<Device>> {
        self.devices.get(name).map(|d| d.current())
    }

    /// The current value of point `i`, its quality and when it was read.
    pub(crate) fn current(
        &self,
        i: usize,
    ) -> (Option<Value>, Quality, Option<std::time::SystemTime>) {
        let p = self.point(i);
        match self.device(&p.device) {
            Some(device) if p.idx < device.profile.fields.len() => {
                let sample = device.sample(p.idx);
                let quality = device.quality(&sample, Instant::now());
                (sample.value, quality, sample.updated.map(|(_, at)| at))
            }
            _ => (None, Quality::Bad, None),
        }
    }
}
