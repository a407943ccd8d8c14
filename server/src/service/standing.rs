//! Standing transactions: a read repeated every `refresh_interval` after the previous one
//! finished, or a write re-sent every `polling_period` from the start of the previous one,
//! while enabled; or run when triggered. Each has a task of the gateway, and its latest
//! outcome in a `watch` channel, so it is read and streamed like a field.

use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, SystemTime};

use tokio::sync::{Notify, watch};
use tokio::time::{Instant, sleep_until};

use super::{Service, ServiceError};
use crate::config::transactions::StandingConfig;
use crate::transaction::{Outcome, Plan, TransactionSpec};

/// How long after start (or declaration) a standing read first runs by itself.
pub(crate) const FIRST_CYCLIC_READ: Duration = Duration::from_secs(2);

/// The latest state of a standing transaction.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct StandingStatus {
    pub(crate) enabled: bool,
    pub(crate) last: Option<Outcome>,
    pub(crate) runs: u64,
    pub(crate) failures: u64,
    pub(crate) updated: Option<SystemTime>,
    /// Where a run under way is (source document 002's states): 1 waiting for the link,
    /// 2 taken by its task, 3 on the line; `None` between runs.
    pub(crate) phase: Option<i32>,
}

impl StandingStatus {
    /// The write block's `state` now: a run's phase while one is under way, else the last
    /// run's outcome (0 before the first).
    pub(crate) fn state(&self) -> i32 {
        self.phase.unwrap_or_else(|| {
            self.last
                .as_ref()
                .map_or(crate::transaction::state::NOT_ACTIVE, |o| o.state)
        })
    }
}

/// A standing transaction.
#[derive(Debug)]
pub(crate) struct Standing {
    pub(crate) name: String,
    pub(crate) link: String,
    pub(crate) period: Duration,
    pub(crate) is_write: bool,
    spec: Mutex<TransactionSpec>,
    status: watch::Sender<StandingStatus>,
    /// Wakes the task: enabled, values changed, or a trigger.
    wake: Notify,
    /// The config file's line, 0 for one declared at run time.
    line: u64,
    /// Stops its task when it is removed (a child of the gateway's token).
    stop: tokio_util::sync::CancellationToken,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Standing {
    /// The config file's line, 0 for one declared at run time.
    pub(crate) fn line(&self) -> u64 {
        self.line
    }

    pub(crate) fn spec(&self) -> TransactionSpec {
        lock(&self.spec).clone()
    }

    pub(crate) fn status(&self) -> StandingStatus {
        self.status.borrow().clone()
    }

    pub(crate) fn subscribe(&self) -> watch::Receiver<StandingStatus> {
        self.status.subscribe()
    }

    pub(crate) fn config(&self) -> StandingConfig {
        StandingConfig {
            name: self.name.clone(),
            link: self.link.clone(),
            spec: self.spec(),
            period: self.period,
            enabled: self.status().enabled,
            line: self.line,
        }
    }
}

/// The standing transactions of a gateway.
#[derive(Debug, Default)]
pub(crate) struct StandingSet(RwLock<Vec<Arc<Standing>>>);

impl StandingSet {
    pub(crate) fn all(&self) -> Vec<Arc<Standing>> {
        self.0.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    pub(crate) fn get(&self, name: &str) -> Option<Arc<Standing>> {
        self.all().into_iter().find(|s| s.name == name)
    }
}

/// Changes of standing transactions' states.
pub(crate) type StandingChanges =
    std::pin::Pin<Box<dyn futures_util::Stream<Item = (Arc<Standing>, StandingStatus)> + Send>>;

impl Service {
    /// Every standing transaction's current state, then each change, until shutdown.
    pub(crate) fn transaction_changes(&self) -> StandingChanges {
        use futures_util::StreamExt;
        let mut streams = tokio_stream::StreamMap::new();
        for (n, s) in self.standing.all().into_iter().enumerate() {
            let updates = tokio_stream::wrappers::WatchStream::new(s.subscribe())
                .map(move |status| (s.clone(), status));
            streams.insert(n, Box::pin(updates) as StandingChanges);
        }
        let shutdown = self.tasks().token().clone().cancelled_owned();
        Box::pin(streams.map(|(_, change)| change).take_until(shutdown))
    }

    pub(crate) fn standing(&self) -> &StandingSet {
        &self.standing
    }

    pub(crate) fn transaction(&self, name: &str) -> Result<Arc<Standing>, ServiceError> {
        self.standing
            .get(name)
            .ok_or_else(|| ServiceError::UnknownTransaction(crate::text::quote(name)))
    }

    /// Declares a standing transaction (idempotent): the same declaration answers the
    /// existing one; another one under the same name is refused. Its task starts at once.
    pub(crate) fn ensure_transaction(
        self: &Arc<Self>,
        config: StandingConfig,
    ) -> Result<(Arc<Standing>, bool), ServiceError> {
        self.accepting()?;
        let checked = config.spec.check();
        if self.cache.link(&config.link).is_err() || checked.is_err() {
            let mut errors = checked.err().unwrap_or_default();
            if self.cache.link(&config.link).is_err() {
                errors.push(crate::transaction::params::ParamError::MissingRs485);
            }
            return Err(ServiceError::Transaction(errors));
        }
        let is_write = matches!(checked.map(|c| c.plan), Ok(Plan::Write(_)));
        let mut set = self.standing.0.write().unwrap_or_else(|e| e.into_inner());
        if let Some(existing) = set.iter().find(|s| s.name == config.name) {
            let have = existing.config();
            return if (&have.link, &have.spec, have.period)
                == (&config.link, &config.spec, config.period)
            {
                Ok((existing.clone(), false))
            } else {
                Err(ServiceError::TransactionConflict(config.name))
            };
        }
        let declared = set.iter().filter(|s| s.line == 0).count();
        if config.line == 0 && declared >= super::bounds::MAX_DECLARED_TRANSACTIONS {
            drop(set);
            let max = super::bounds::MAX_DECLARED_TRANSACTIONS;
            return self.counted(Err(crate::declare::DeclareError::TooMany(
                "transactions",
                max,
            )));
        }
        let standing = Arc::new(Standing {
            name: config.name,
            link: config.link,
            period: config.period,
            is_write,
            spec: Mutex::new(config.spec),
            status: watch::Sender::new(StandingStatus {
                enabled: config.enabled,
                last: None,
                runs: 0,
                failures: 0,
                updated: None,
                phase: None,
            }),
            wake: Notify::new(),
            line: config.line,
            stop: self.tasks().token().child_token(),
        });
        set.push(standing.clone());
        drop(set);
        if standing.line == 0 {
            self.declared.touch();
        }
        let (service, task) = (self.clone(), standing.clone());
        self.tasks()
            .spawn(async move { service.run_standing(task).await });
        Ok((standing, true))
    }

    /// Enables or disables a standing transaction.
    pub(crate) fn enable_transaction(
        &self,
        name: &str,
        enabled: bool,
    ) -> Result<Arc<Standing>, ServiceError> {
        let s = self.transaction(name)?;
        s.status.send_if_modified(|st| {
            let changed = st.enabled != enabled;
            st.enabled = enabled;
            changed
        });
        if s.line == 0 {
            self.declared.touch();
        }
        s.wake.notify_one();
        Ok(s)
    }

    /// Sets the values a standing write sends (checked as a one-shot would be).
    pub(crate) fn set_transaction_values(
        &self,
        name: &str,
        values: Vec<serde_json::Value>,
    ) -> Result<Arc<Standing>, ServiceError> {
        let s = self.transaction(name)?;
        let mut spec = s.spec();
        spec.values = Some(values);
        spec.check().map_err(ServiceError::Transaction)?;
        *lock(&s.spec) = spec;
        if s.line == 0 {
            self.declared.touch();
        }
        s.wake.notify_one();
        Ok(s)
    }

    /// Removes a standing transaction declared at run time: its task stops (a run in flight
    /// is finished by the link, its answer dropped) and its link can then be removed. One
    /// from the config file stays, as configured devices do.
    pub(crate) fn remove_transaction(&self, name: &str) -> Result<Arc<Standing>, ServiceError> {
        self.accepting()?;
        self.owning_field()?;
        let set = self.standing.0.write().unwrap_or_else(|e| e.into_inner());
        let at = set
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| ServiceError::UnknownTransaction(crate::text::quote(name)))?;
        if set[at].line != 0 {
            return Err(ServiceError::Declare(
                crate::declare::DeclareError::FromConfig {
                    what: "transaction",
                    name: set[at].name.clone(),
                },
            ));
        }
        drop(set);
        self.unstand(name)
            .ok_or_else(|| ServiceError::UnknownTransaction(crate::text::quote(name)))
    }

    /// Stops and removes the standing transaction `name` declared at run time.
    pub(super) fn unstand(&self, name: &str) -> Option<Arc<Standing>> {
        let mut set = self.standing.0.write().unwrap_or_else(|e| e.into_inner());
        let at = set.iter().position(|s| s.name == name && s.line == 0)?;
        let removed = set.remove(at);
        drop(set);
        removed.stop.cancel();
        self.declared.touch();
        tracing::info!(transaction = %removed.name, "transaction removed");
        Some(removed)
    }

    /// Stops and removes a standing transaction, whether declared or configured (a reload
    /// took it out of the config file, or changed it).
    pub(crate) fn drop_transaction(&self, name: &str) -> Option<Arc<Standing>> {
        let mut set = self.standing.0.write().unwrap_or_else(|e| e.into_inner());
        let at = set.iter().position(|s| s.name == name)?;
        let removed = set.remove(at);
        drop(set);
        removed.stop.cancel();
        Some(removed)
    }

    /// Runs a standing transaction now; ignored while one of its runs is in flight. A
    /// disabled one is refused (it would run nothing), not answered as if it ran.
    pub(crate) fn trigger_transaction(&self, name: &str) -> Result<Arc<Standing>, ServiceError> {
        let s = self.transaction(name)?;
        if !s.status().enabled {
            return Err(ServiceError::TransactionDisabled(s.name.clone()));
        }
        s.wake.notify_waiters();
        Ok(s)
    }

    /// Runs `spec` once, its phase (1, 2, 3) told in the status as the request moves on;
    /// `None` when the transaction was removed meanwhile.
    async fn run_tracked(
        &self,
        s: &Standing,
        spec: &crate::transaction::TransactionSpec,
        token: &tokio_util::sync::CancellationToken,
    ) -> Option<Result<crate::transaction::Outcome, ServiceError>> {
        use crate::cache::Stage;
        use crate::transaction::state;
        let (stage, mut told) = watch::channel(Stage::Queued);
        let phase = |at: Stage| match at {
            Stage::Queued => state::WAITING,
            Stage::Taken => state::ACCESS,
            Stage::Sent => state::IN_PROGRESS,
        };
        s.status.send_modify(|st| st.phase = Some(state::WAITING));
        let run = self.transact_staged(&s.link, spec, Some(stage));
        tokio::pin!(run);
        loop {
            tokio::select! {
                _ = token.cancelled() => return None,
                outcome = &mut run => return Some(outcome),
                Ok(()) = told.changed() => {
                    let at = phase(*told.borrow_and_update());
                    s.status.send_modify(|st| st.phase = Some(at));
                }
            }
        }
    }

    async fn run_standing(self: Arc<Self>, s: Arc<Standing>) {
        let token = s.stop.clone();
        // Source document 004: the first cyclic read about 2 s after start (of the gateway
        // for a configured read, of its declaration for a declared one). A write starts at
        // once, as the write block does while `enable` is held. Period 0: only when
        // triggered (or, for a write, when its values are set or it is enabled).
        let mut next = match (s.period.is_zero(), s.is_write) {
            (true, _) => None,
            (false, true) => Some(Instant::now()),
            (false, false) => Some(Instant::now() + FIRST_CYCLIC_READ),
        };
        loop {
            if !s.status().enabled {
                tokio::select! {
                    _ = token.cancelled() => return,
                    _ = s.wake.notified() => {}
                }
                // Enabled: a write sends at once (as its block does when `enable` goes
                // TRUE), a cyclic read reads at once; a read of period 0 waits for a trigger.
                if s.status().enabled && (s.is_write || !s.period.is_zero()) {
                    next = Some(Instant::now());
                }
                continue;
            }
            let due = async {
                match next {
                    Some(at) => sleep_until(at).await,
                    None => std::future::pending::<()>().await,
                }
            };
            tokio::select! {
                _ = token.cancelled() => return,
                _ = due => {}
                _ = s.wake.notified() => {}
            }
            if !s.status().enabled {
                continue;
            }
            let started = Instant::now();
            let spec = s.spec();
            let Some(outcome) = self.run_tracked(&s, &spec, &token).await else {
                return;
            };
            let ok = matches!(&outcome, Ok(o) if o.actual);
            s.status.send_modify(|st| {
                st.phase = None;
                st.runs += 1;
                if !ok {
                    st.failures += 1;
                }
                // The read block's output 1 keeps the last value read correctly; the error
                // is said beside it.
                // A run refused before it was sent (a busy link) leaves the last outcome.
                let kept = st.last.as_ref().and_then(|o| o.value);
                if let Ok(o) = &outcome {
                    let mut o = o.clone();
                    if !o.actual && !s.is_write {
                        o.value = kept;
                    }
                    st.last = Some(o);
                }
                st.updated = Some(SystemTime::now());
            });
            self.metrics.transaction_run(&s.name, ok);
            if matches!(outcome, Err(ServiceError::ShuttingDown)) {
                return;
            }
            // Writes repeat from the start of the previous one, reads after it finished.
            next = match (s.period.is_zero(), s.is_write) {
                (true, _) => None,
                (false, true) => Some(started + s.period),
                (false, false) => Some(Instant::now() + s.period),
            };
        }
    }
}
