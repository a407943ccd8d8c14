//! How `iogatectl` shows what it got: values, ages, tables, JSON; and how it reads a target.

use super::*;

/// `DEVICE`, `DEVICE.FIELD`, or a located address such as `%QX2.6` (a field the Modbus
/// server's map binds there).
pub(crate) fn split_target(target: &str) -> (&str, Option<&str>) {
    if target.starts_with('%') {
        return ("", Some(target));
    }
    match target.split_once('.') {
        Some((d, f)) => (d, Some(f)),
        None => (target, None),
    }
}

pub(crate) fn print_json(value: &impl Serialize) -> anyhow::Result<()> {
    println!("{}", serde_json::to_string_pretty(value)?);
    Ok(())
}

pub(crate) fn show(v: &FieldValue) -> String {
    match &v.value {
        None => "-".to_owned(),
        Some(Value::Time(ms)) => format!("{ms} ms"),
        Some(other) => other.to_string(),
    }
}

pub(crate) fn age(v: &FieldValue) -> String {
    v.timestamp.and_then(|t| t.elapsed().ok()).map_or_else(
        || "-".to_owned(),
        |d| format!("{:.1}s ago", d.as_secs_f64()),
    )
}

pub(crate) fn field_table(values: &[FieldValue]) -> String {
    let mut out = format!(
        "{:<28} {:<7} {:<24} {:<11} {}\n",
        "FIELD", "TYPE", "VALUE", "QUALITY", "UPDATED"
    );
    for v in values {
        out.push_str(&format!(
            "{:<28} {:<7} {:<24} {:<11} {}{}\n",
            format!("{}.{}", v.device, v.field),
            v.ty.map_or("", |t| t.name()),
            show(v),
            v.quality.name(),
            age(v),
            v.error
                .as_ref()
                .map(|e| format!("  ({e})"))
                .unwrap_or_default()
        ));
    }
    out
}
