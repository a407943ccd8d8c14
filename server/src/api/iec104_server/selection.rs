//! Select-before-execute across the outstation's masters: a select (S/E = 1) reserves its
//! command point for the master that made it, for `select_timeout`. While it holds, another
//! master's select or execute of that point is refused; the master's own execute must
//! carry the selected value and come within the timeout; a deactivation, an execute or the
//! master's connection ending gives the point back.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::time::Instant;

use crate::codec::Value;

/// Each master's number, to tell whose a selection is.
static MASTER: AtomicU64 = AtomicU64::new(1);

/// The outstation's selections, every master's: the point's IOA, by whom, until when.
#[derive(Clone, Default)]
pub(crate) struct Selections(Arc<Mutex<HashMap<u32, (u64, Instant)>>>);

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// One master's selections.
pub(crate) struct Selected {
    master: u64,
    all: Selections,
    mine: HashMap<u32, (Value, Instant)>,
    timeout: Duration,
}

impl Drop for Selected {
    fn drop(&mut self) {
        lock(&self.all.0).retain(|_, (by, _)| *by != self.master);
    }
}

const ANOTHER: &str = "the point is selected by another master";

impl Selected {
    pub(crate) fn new(all: Selections, timeout: Duration) -> Selected {
        Selected {
            master: MASTER.fetch_add(1, Ordering::Relaxed),
            all,
            mine: HashMap::new(),
            timeout,
        }
    }

    /// Another master's selection of `ioa` that still holds.
    fn held_by_another(&self, ioa: u32, now: Instant) -> bool {
        lock(&self.all.0)
            .get(&ioa)
            .is_some_and(|(by, until)| *by != self.master && now <= *until)
    }

    /// Selects `ioa` with `value` for this master.
    pub(crate) fn select(&mut self, ioa: u32, value: Value) -> Result<(), &'static str> {
        let now = Instant::now();
        let mut all = lock(&self.all.0);
        if all
            .get(&ioa)
            .is_some_and(|(by, until)| *by != self.master && now <= *until)
        {
            return Err(ANOTHER);
        }
        all.insert(ioa, (self.master, now + self.timeout));
        self.mine.insert(ioa, (value, now));
        Ok(())
    }

    /// Whether an execute of `ioa` with `value` may go: this master's selection of it (if
    /// any) within the timeout and of the same value, no other master's holding it.
    pub(crate) fn execute(&mut self, ioa: u32, value: &Value) -> Result<(), &'static str> {
        let now = Instant::now();
        if self.held_by_another(ioa, now) {
            return Err(ANOTHER);
        }
        let Some((chosen, at)) = self.give_back(ioa) else {
            return Ok(());
        };
        if now.duration_since(at) > self.timeout {
            return Err("the selection ended (select_timeout)");
        }
        if chosen != *value {
            return Err("the execute carries another value than the select");
        }
        Ok(())
    }

    /// Gives the selection of `ioa` back (a deactivation): whether there was one.
    pub(crate) fn deselect(&mut self, ioa: u32) -> bool {
        self.give_back(ioa).is_some()
    }

    fn give_back(&mut self, ioa: u32) -> Option<(Value, Instant)> {
        let mine = self.mine.remove(&ioa)?;
        let mut all = lock(&self.all.0);
        if all.get(&ioa).is_some_and(|(by, _)| *by == self.master) {
            all.remove(&ioa);
        }
        Some(mine)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn a_selection_is_its_masters_until_it_is_executed_given_back_or_timed_out() {
        let all = Selections::default();
        let timeout = Duration::from_secs(10);
        let mut a = Selected::new(all.clone(), timeout);
        let mut b = Selected::new(all.clone(), timeout);
        a.select(7, Value::Bool(true)).expect("a selects");
        assert_eq!(b.select(7, Value::Bool(false)), Err(ANOTHER));
        assert_eq!(b.execute(7, &Value::Bool(false)), Err(ANOTHER));
        assert_eq!(
            a.execute(7, &Value::Bool(false)),
            Err("the execute carries another value than the select")
        );
        // Given back by the refused execute: b may select now.
        b.select(7, Value::Bool(false)).expect("b selects");
        assert_eq!(a.execute(7, &Value::Bool(true)), Err(ANOTHER));
        tokio::time::advance(timeout + Duration::from_millis(1)).await;
        assert_eq!(
            b.execute(7, &Value::Bool(false)),
            Err("the selection ended (select_timeout)")
        );
        // A timed-out selection holds nobody off; a master gone gives its points back.
        b.select(8, Value::Bool(true)).expect("b selects 8");
        drop(b);
        a.execute(8, &Value::Bool(true))
            .expect("free once b is gone");
        assert!(a.select(9, Value::Bool(true)).is_ok() && a.deselect(9));
        assert!(!a.deselect(9));
    }
}
