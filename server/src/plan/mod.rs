//! Fields to Modbus transactions: read batches per device (`read`), write groups (`write`),
//! the bus-time budget of a link (`budget`), and the `iogate plan` report (`report`).

mod budget;
pub(crate) mod eip;
mod read_batches;
mod report;
pub(crate) mod s7;
mod write_groups;

pub(crate) use budget::{cycle_time, transaction_time, utilisation};
pub(crate) use read_batches::{ReadBatch, read_batches, read_request};
pub use report::{link_plan, render, warnings};
pub(crate) use write_groups::{WriteItem, WriteOp, write_ops};

/// A profile from field lines, for the tests of this module.
#[cfg(test)]
pub(crate) fn test_profile(fields: &str) -> crate::profile::Profile {
    crate::profile::load_str("p.yaml", &format!("name: P\nfields:\n{fields}")).expect("profile")
}
