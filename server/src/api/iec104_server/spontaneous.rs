//! Spontaneous data for one master: a field's change goes to the points showing it, unless
//! it stays within the field's deadband of what was reported last and its quality is the
//! same. A point waiting to be sent holds only its newest value (a master that falls behind
//! gets the latest of each point, not a backlog), so what waits is bounded by the table.
//! The first value seen of a point, and every change while data transfer is stopped, is
//! what the next change is compared with; the master's interrogation reports them.

use std::collections::VecDeque;
use std::time::SystemTime;

use super::served::Served;
use crate::cache::sample::Quality;
use crate::codec::Value;

/// A value, its quality and when it was read.
pub(crate) type Reading = (Option<Value>, Quality, Option<SystemTime>);

#[derive(Default)]
pub(crate) struct Spontaneous {
    /// What each point last reported (or was first seen with).
    last: Vec<Option<(Option<Value>, Quality)>>,
    /// The newest reading of each point waiting to be sent.
    waiting: Vec<Option<Reading>>,
    /// The waiting points of each monitor type, in the order they changed.
    queues: Vec<(u8, VecDeque<usize>)>,
    turn: usize,
}

impl Spontaneous {
    /// Everything forgotten, for a table of `n` points.
    pub(crate) fn reset(&mut self, n: usize) {
        *self = Spontaneous {
            last: vec![None; n],
            waiting: vec![None; n],
            ..Spontaneous::default()
        };
    }

    /// Point `i` of `served` now reads `reading`; `started`: data transfer is on.
    pub(crate) fn changed(&mut self, served: &Served, i: usize, reading: Reading, started: bool) {
        let (Some(last), Some(_)) = (self.last.get_mut(i), self.waiting.get(i)) else {
            return;
        };
        let now = (reading.0.clone(), reading.1);
        let Some(before) = last.as_ref() else {
            *last = Some(now);
            return;
        };
        if !started {
            *last = Some(now);
            return;
        }
        let point = served.point(i);
        if before.1 == now.1 && point.deadband.within(before.0.as_ref(), now.0.as_ref()) {
            return;
        }
        if self.waiting[i].replace(reading).is_none() {
            let ty = point.asdu.0;
            match self.queues.iter_mut().find(|(t, _)| *t == ty) {
                Some((_, q)) => q.push_back(i),
                None => self.queues.push((ty, VecDeque::from([i]))),
            }
        }
    }

    /// Up to `most` waiting points of one type (the types take turns), each with its
    /// reading, now counted as reported.
    pub(crate) fn take(
        &mut self,
        most: impl Fn(u8) -> usize,
    ) -> Option<(u8, Vec<(usize, Reading)>)> {
        let n = self.queues.len();
        for step in 0..n {
            let at = (self.turn + step) % n;
            let (ty, queue) = &mut self.queues[at];
            if queue.is_empty() {
                continue;
            }
            let ty = *ty;
            let mut out = Vec::new();
            while out.len() < most(ty) {
                let Some(i) = queue.pop_front() else { break };
                if let Some(reading) = self.waiting[i].take() {
                    self.last[i] = Some((reading.0.clone(), reading.1));
                    out.push((i, reading));
                }
            }
            self.turn = at + 1;
            return Some((ty, out));
        }
        None
    }

    /// Whether any point waits.
    pub(crate) fn any(&self) -> bool {
        self.queues.iter().any(|(_, q)| !q.is_empty())
    }
}
