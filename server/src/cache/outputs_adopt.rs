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
