//! The Modbus TCP server's map: IEC located addresses (source document 003) in the address
//! spaces of source document 001 (`space`), fields and diagnostics bound to them (`bind`),
//! how a value shows in a location's registers (`value`), and the gateway memory behind
//! the unbound output and memory locations (`memory`).

pub(crate) mod bind;
pub(crate) mod memory;
pub mod report;
pub(crate) mod space;
pub(crate) mod value;

pub(crate) use bind::{Binding, Diag, Plan, Target, plan, plan_after};
pub(crate) use space::{Space, Table};
