//! The bounds the service keeps on what clients declare at run time (the README's table of
//! bounds): links, devices and standing transactions, each counted for `/metrics` with its
//! refusals (429, `RESOURCE_EXHAUSTED`).

use crate::declare::{DeclareError, MAX_DECLARED_DEVICES, MAX_DECLARED_LINKS};

use super::{Service, ServiceError};

/// Standing transactions that may be declared at run time (those of the config file aside).
pub(crate) const MAX_DECLARED_TRANSACTIONS: usize = 256;

/// The bound's name of what `DeclareError::TooMany` names.
fn bound_of(what: &str) -> (&'static str, usize) {
    match what {
        "links" => ("declared_links", MAX_DECLARED_LINKS),
        "devices" => ("declared_devices", MAX_DECLARED_DEVICES),
        _ => ("declared_transactions", MAX_DECLARED_TRANSACTIONS),
    }
}

impl Service {
    /// Copies what the declarations hold into their bounds' metrics (at a scrape).
    pub(crate) fn count_bounds(&self) {
        let links = self.cache.links();
        let links = links.iter().filter(|l| l.config().line == 0).count();
        let devices = self.cache.devices();
        let devices = devices.iter().filter(|d| d.config.line == 0).count();
        let transactions = self.standing().all();
        let transactions = transactions.iter().filter(|s| s.line() == 0).count();
        for (what, used) in [
            ("links", links),
            ("devices", devices),
            ("transactions", transactions),
        ] {
            let (name, limit) = bound_of(what);
            self.metrics.bound(name, limit).set_used(used);
        }
        let fields: usize = self
            .cache
            .devices()
            .iter()
            .map(|d| d.profile.fields.len())
            .sum();
        let history = crate::write_log::FIELD_HISTORY;
        let outcomes = self.metrics.bound("write_outcomes", fields * history);
        outcomes.set_used(self.cache.writes.kept());
        let scans = self.metrics.bound("scans", self.cache.links().len());
        scans.set_used(self.running_scans());
        self.doors.count_bounds(&self.metrics);
    }

    /// `result`, a refusal at a bound counted.
    pub(crate) fn counted<T>(&self, result: Result<T, DeclareError>) -> Result<T, ServiceError> {
        if let Err(DeclareError::TooMany(what, _)) = &result {
            let (name, limit) = bound_of(what);
            self.metrics.bound(name, limit).refused();
        }
        Ok(result?)
    }
}
