//! `iogate map`: the bindings as a table, or as an ST `VAR_GLOBAL` block of `AT`
//! declarations for a remote runtime.

use std::fmt::Write as _;

use super::Plan;

/// The map as a table: location, Modbus table and address, device.field, type, access.
pub fn render(plan: &Plan) -> String {
    let mut out = format!(
        "Modbus TCP map ({} address space, {} bindings)\n{:<11} {:<17} {:>7}  {:<32} {:<6} {}\n",
        plan.space.kind.name(),
        plan.bindings.len(),
        "LOCATION",
        "TABLE",
        "ADDRESS",
        "DEVICE.FIELD",
        "TYPE",
        "ACCESS"
    );
    for b in &plan.bindings {
        let _ = writeln!(
            out,
            "{:<11} {:<17} {:>7}  {:<32} {:<6} {}{}",
            b.at.to_string(),
            b.slot.table.name(),
            b.slot.address,
            format!("{}.{}", b.device, b.name),
            b.ty.name(),
            if b.writable { "rw" } else { "r" },
            if b.auto { "  (auto)" } else { "" }
        );
    }
    for field in &plan.unbound {
        let _ = writeln!(
            out,
            "not bound: {field} (no location of its kind left, or no kind)"
        );
    }
    out
}

/// The map as ST: one located global per binding, named `device_field`.
pub fn st(plan: &Plan) -> String {
    let mut out = String::from("VAR_GLOBAL\n");
    for b in &plan.bindings {
        let _ = writeln!(
            out,
            "    {} AT {} : {};  (* {} {} *)",
            crate::profile::keywords::identifier(&[&b.device, &b.name]),
            b.at,
            b.ty.name(),
            b.slot.table.name(),
            b.slot.address
        );
    }
    out.push_str("END_VAR\n");
    out
}
