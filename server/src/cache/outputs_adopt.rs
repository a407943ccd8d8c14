//! A device's outputs on the standby of a pair: what the active was asked for, taken from
//! the records it ships, so that the node taking over knows every output's desired value
//! (shown beside what the device holds, kept by `write_mode: reconcile`) without writing
//! any of them: nothing here is pending, and a replay writes only what was asked of this
//! node in its own epoch.

use super::{Outputs, lock};
use crate::write_log::{Origin, WriteRecord, WriteStatus};

impl Outputs {
    /// Takes field `idx`'s record from the other node: a newer write makes its value the
    /// desired one; the newest write's outcome says whether the device holds it or the
    /// value was forgotten; a replay the active left says the output is not written again.
    pub(crate) fn adopt(&self, idx: usize, record: &WriteRecord) {
        let mut slots = lock(&self.slots);
        let Some(slot) = slots.get_mut(idx) else {
            return;
        };
        let newest = slot.last_generation.unwrap_or(0);
        if record.generation > newest {
            slot.last_generation = Some(record.generation);
            if record.origin != Origin::Replay {
                slot.latest = record.value.clone();
                (slot.reached, slot.left) = (false, false);
            }
        } else if record.generation < newest {
            return;
        }
        match record.status {
            WriteStatus::Written => slot.reached = true,
            WriteStatus::Superseded if record.origin == Origin::Replay => slot.left = true,
            _ => {}
        }
        if record.forgets {
            slot.latest = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;
    use std::time::SystemTime;

    use super::*;
    use crate::codec::Value;
    use crate::write_log::WriteLog;

    fn record(generation: u64, value: i64, status: WriteStatus, origin: Origin) -> WriteRecord {
        WriteRecord {
            generation,
            device: "d".into(),
            field: "f".into(),
            value: Some(Value::Int(value)),
            status,
            origin,
            attempts: 1,
            error: None,
            requested: SystemTime::now(),
            finished: None,
            forgets: false,
        }
    }

    #[test]
    fn the_standby_knows_each_desired_value_and_has_nothing_to_write() {
        let outputs = Outputs::new(1, Arc::new(WriteLog::default()));
        outputs.set_rewrites(true);
        let g = crate::role::first_generation(4);
        outputs.adopt(0, &record(g, 7, WriteStatus::Pending, Origin::Client));
        outputs.adopt(0, &record(g, 7, WriteStatus::Written, Origin::Client));
        assert_eq!(outputs.latest(0), Some(Value::Int(7)));
        assert_eq!(outputs.last_generation(0), Some(g));
        assert!(!outputs.has_pending(), "a handed-over value is not a write");
        assert!(outputs.take().is_empty());
        assert_eq!(outputs.replayable(), vec![(0, Value::Int(7), true)]);
        // An older record arriving late changes nothing; a refusal forgets the value.
        outputs.adopt(0, &record(g - 1, 3, WriteStatus::Written, Origin::Client));
        assert_eq!(outputs.latest(0), Some(Value::Int(7)));
        let mut refused = record(g + 1, 9, WriteStatus::Failed, Origin::Client);
        refused.forgets = true;
        outputs.adopt(0, &refused);
        assert_eq!(outputs.latest(0), None);
    }
}
