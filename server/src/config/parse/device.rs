//! Reading a device of `devices:`: its keys, its rules, its client-loss policy.

use std::time::Duration;

use super::*;

const CLIENT_LOSS_KEYS: &[&str] = &["after", "safe"];

/// `on_client_loss`: `hold`, or `{ after: DURATION, safe: { FIELD: VALUE, ... } }`.
fn read_client_loss(
    node: &Node,
    report: &mut Report,
    ctx: &str,
) -> Option<Option<crate::config::ClientLoss>> {
    if let yaml::Kind::Str(text) = &node.kind {
        if text == "hold" {
            return Some(None);
        }
        report.push(
            node.line,
            ctx,
            format!(
                "`{}` is not a client-loss policy: `hold`, or `{{ after: 2s, safe: {{ FIELD: value }} }}`",
                crate::text::quote(text)
            ),
        );
        return None;
    }
    let mut map = node.map(report, ctx)?;
    let after = match map.require("after", report, ctx) {
        Some(n) => duration_value(
            n,
            report,
            &format!("{ctx}.after"),
            Duration::from_millis(10),
        ),
        None => None,
    };
    let safe_ctx = format!("{ctx}.safe");
    let safe = map
        .require("safe", report, ctx)
        .and_then(|n| match &n.kind {
            yaml::Kind::Map(entries) if !entries.is_empty() => Some(
                entries
                    .iter()
                    .filter_map(|(key, value)| {
                        let text = match &value.kind {
                            yaml::Kind::Bool(b) => Some(b.to_string()),
                            _ => value.scalar_text(report, &format!("{safe_ctx}.{}", key.name)),
                        };
                        text.map(|v| (key.name.clone(), v))
                    })
                    .collect::<Vec<_>>(),
            ),
            _ => {
                report.push(
                    n.line,
                    &safe_ctx,
                    "expected a mapping of output fields to their safe values",
                );
                None
            }
        });
    map.finish(report, ctx, CLIENT_LOSS_KEYS);
    Some(Some(crate::config::ClientLoss {
        after: after?,
        safe: safe?,
    }))
}

/// A device as far as it can be read (with whether a written `slave_id` was refused):
/// values that were refused (their problems reported) take their defaults, so that the
/// device is still checked against its profile and links.
pub(super) fn read_device(
    node: &Node,
    index: usize,
    report: &mut Report,
) -> Option<(DeviceConfig, bool)> {
    let mut map = node.map(report, &format!("devices[{index}]"))?;
    let (name, ctx) = name_of(&mut map, report, "device", index);
    let at = |k: &str| format!("{ctx}: {k}");
    let profile = map
        .require("profile", report, &ctx)
        .and_then(|n| n.scalar_text(report, &at("profile")));
    let link = map
        .get("link")
        .and_then(|n| n.scalar_text(report, &at("link")));
    let slave_node = map.get("slave_id");
    let slave_id = slave_node.and_then(|n| {
        let id = n.int_in(report, &at("slave_id"), 0, i128::from(u32::MAX))?;
        ruled(rules::slave_id(id as u64), n.line, &at("slave_id"), report)
    });
    let slave_refused = slave_node.is_some() && slave_id.is_none();
    // `0ms`: back to back (a device read again as soon as its answers came).
    let back_to_back = matches!(
        map.get("refresh_rate"),
        Some(Node { kind: yaml::Kind::Str(t), .. })
            if crate::duration::parse(t).is_ok_and(|d| d.is_zero())
    );
    let mut duration_of = |key: &str, default: Duration, min: Duration| -> Option<Duration> {
        map.get(key).map_or(Some(default), |node| {
            duration_value(node, report, &at(key), min)
        })
    };
    let refresh_rate = if back_to_back {
        Some(Duration::ZERO)
    } else {
        duration_of("refresh_rate", rules::DEFAULT_REFRESH, rules::MIN_PERIOD)
    };
    let timeout = duration_of("timeout", rules::DEFAULT_TIMEOUT, rules::MIN_PERIOD);
    let retries = match map.get("retries") {
        None => Some(rules::DEFAULT_RETRIES),
        Some(n) => n
            .int_in(report, &at("retries"), 0, i128::from(rules::MAX_RETRIES))
            .map(|r| r as u32),
    };
    let mut registers = |key: &str, min: i128, report: &mut Report| {
        map.get(key).map(|n| {
            n.int_in(report, &at(key), min, i128::from(rules::MAX_READ_REGISTERS))
                .map(|m| m as u16)
        })
    };
    let max_batch = registers("max_batch", 1, report).unwrap_or(Some(rules::MAX_READ_REGISTERS));
    let max_gap = registers("max_gap", 0, report).unwrap_or(Some(0));
    let write_mode = match map.get("write_mode") {
        None => Some(crate::config::WriteMode::default()),
        Some(n) => write_mode(n, report, &at("write_mode")),
    };
    let rewrite_outputs = match map.get("rewrite_outputs") {
        None => Some(None),
        Some(n) => rewrite_outputs(n, report, &at("rewrite_outputs")).map(Some),
    };
    let on_client_loss = match map.get("on_client_loss") {
        None => Some(None),
        Some(n) => read_client_loss(n, report, &at("on_client_loss")),
    };
    let (at_keys, keys) = own_keys(&mut map, report, &ctx);
    map.finish(report, &ctx, &keys);
    Some((
        DeviceConfig {
            name: name?,
            profile: profile?,
            link,
            slave_id,
            refresh_rate: refresh_rate.unwrap_or(rules::DEFAULT_REFRESH),
            timeout: timeout.unwrap_or(rules::DEFAULT_TIMEOUT),
            retries: retries.unwrap_or(rules::DEFAULT_RETRIES),
            max_batch: max_batch.unwrap_or(rules::MAX_READ_REGISTERS),
            max_gap: max_gap.unwrap_or(0),
            write_mode: write_mode.unwrap_or_default(),
            rewrite_outputs: rewrite_outputs.flatten(),
            on_client_loss: on_client_loss.flatten(),
            at: at_keys,
            line: node.line,
        },
        slave_refused,
    ))
}

/// The keys of the drivers' own a device carries (`Words::device_keys`), as written, and
/// every key a device may have.
fn own_keys(
    map: &mut crate::yaml::MapReader<'_>,
    report: &mut Report,
    ctx: &str,
) -> (Vec<(&'static str, String)>, Vec<&'static str>) {
    let own: Vec<&'static str> = crate::profile::drivers()
        .iter()
        .flat_map(|w| w.device_keys.iter().copied())
        .collect();
    let mut at = Vec::new();
    for key in &own {
        if at.iter().any(|(k, _)| k == key) {
            continue;
        }
        // A driver's key may be a word, a number or a truth value (`cov: false`).
        let text = map.get(key).and_then(|n| match &n.kind {
            crate::yaml::Kind::Bool(b) => Some(b.to_string()),
            _ => n.scalar_text(report, &format!("{ctx}: {key}")),
        });
        if let Some(text) = text {
            at.push((*key, text));
        }
    }
    let keys = DEVICE_KEYS.iter().copied().chain(own).collect();
    (at, keys)
}

/// `rewrite_outputs`: `on_reconnect` or `never`.
fn rewrite_outputs(
    n: &Node,
    report: &mut Report,
    ctx: &str,
) -> Option<crate::config::RewriteOutputs> {
    let t = n.scalar_text(report, ctx)?;
    let rule = crate::config::RewriteOutputs::parse(&t);
    if rule.is_none() {
        report.push(
            n.line,
            ctx,
            format!(
                "`{}` is not a rule for outputs after a reconnect (on_reconnect or never)",
                crate::text::quote(&t)
            ),
        );
    }
    rule
}

/// `write_mode`: `on_change` or `reconcile`.
fn write_mode(n: &Node, report: &mut Report, ctx: &str) -> Option<crate::config::WriteMode> {
    let t = n.scalar_text(report, ctx)?;
    let mode = crate::config::WriteMode::parse(&t);
    if mode.is_none() {
        report.push(
            n.line,
            ctx,
            format!(
                "`{}` is not a write mode (on_change or reconcile)",
                crate::text::quote(&t)
            ),
        );
    }
    mode
}
