//! The front-ends that run, as the rest of the gateway sees them: each by its name, with
//! its detail for `/readyz`, its metric families and its own state for its own routes. The
//! core knows a front-end only through [`Door`]; what a front-end is, it says itself.

use std::any::Any;
use std::collections::BTreeMap;
use std::sync::{Arc, RwLock};

/// A running front-end's face toward the rest of the gateway.
pub(crate) trait Door: Any + Send + Sync {
    /// Its name: the key of its detail in `/readyz` and of its configuration section.
    fn name(&self) -> &'static str;

    /// Its detail in `/readyz`, when it gives one (a front-end never makes the gateway
    /// unready: it is detail only).
    fn health(&self) -> Option<serde_json::Value> {
        None
    }

    /// Appends its metric families (OpenMetrics text, without `# EOF`) to a scrape.
    fn encode_metrics(&self, out: &mut String) -> std::fmt::Result {
        let _ = out;
        Ok(())
    }

    /// Copies what its clients hold of its bounds into the gateway's metrics (before a
    /// scrape), for bounds whose places only it counts.
    fn count_bounds(&self, metrics: &crate::metrics::Metrics) {
        let _ = metrics;
    }
}

/// What the front-ends add to the API's description, made once by the composition root
/// from their list: the keys of their own sections (a reload report's kinds), the names
/// their listeners have in `GET /api/v1/config`, and the schemas of their `/readyz`
/// details.
#[derive(Debug, Clone, Default)]
pub(crate) struct Described {
    pub(crate) section_keys: Vec<&'static str>,
    pub(crate) listeners: Vec<&'static str>,
    pub(crate) health: Vec<HealthSchema>,
}

/// A front-end's `/readyz` detail as the OpenAPI document describes it: under its name,
/// a schema of its own (`schema_name`), with what it means.
#[derive(Debug, Clone)]
pub(crate) struct HealthSchema {
    pub(crate) name: &'static str,
    pub(crate) schema_name: &'static str,
    pub(crate) schema: serde_json::Value,
    pub(crate) description: &'static str,
}

/// The front-ends running now, by name.
#[derive(Default)]
pub(crate) struct Doors(RwLock<BTreeMap<&'static str, Arc<dyn Door>>>);

impl Doors {
    /// `door` runs (replacing one of its name).
    pub(crate) fn attach(&self, door: Arc<dyn Door>) {
        self.0
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .insert(door.name(), door);
    }

    /// The front-end `name` no longer runs.
    pub(crate) fn detach(&self, name: &str) {
        self.0
            .write()
            .unwrap_or_else(|e| e.into_inner())
            .remove(name);
    }

    /// The front-end `name` no longer runs, when `door` is what runs under that name (not
    /// a successor that attached itself before this one ended).
    pub(crate) fn detach_if(&self, name: &str, door: &Arc<dyn Door>) {
        let mut doors = self.0.write().unwrap_or_else(|e| e.into_inner());
        if doors.get(name).is_some_and(|d| Arc::ptr_eq(d, door)) {
            doors.remove(name);
        }
    }

    /// The running front-end `name` as its own type (for its own routes).
    pub(crate) fn get<T: Door>(&self, name: &str) -> Option<Arc<T>> {
        let door = self
            .0
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .get(name)
            .cloned()?;
        (door as Arc<dyn Any + Send + Sync>).downcast::<T>().ok()
    }

    /// Every running front-end's detail for `/readyz`, by name.
    pub(crate) fn health(&self) -> BTreeMap<String, serde_json::Value> {
        self.all()
            .iter()
            .filter_map(|d| Some((d.name().to_owned(), d.health()?)))
            .collect()
    }

    /// Every running front-end's metric families, in name order.
    pub(crate) fn encode_metrics(&self, out: &mut String) -> std::fmt::Result {
        for door in self.all() {
            door.encode_metrics(out)?;
        }
        Ok(())
    }

    /// Every running front-end's bounds, counted into `metrics`.
    pub(crate) fn count_bounds(&self, metrics: &crate::metrics::Metrics) {
        for door in self.all() {
            door.count_bounds(metrics);
        }
    }

    fn all(&self) -> Vec<Arc<dyn Door>> {
        self.0
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .values()
            .cloned()
            .collect()
    }
}

impl std::fmt::Debug for Doors {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = self
            .0
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .keys()
            .copied()
            .collect();
        f.debug_tuple("Doors").field(&names).finish()
    }
}
