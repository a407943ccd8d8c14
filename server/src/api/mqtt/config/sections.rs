//! The `mqtt:` section's sub-sections (`tls`, `sparkplug`, `json`, `report`, `buffer`), each
//! read with its problems at their lines.

use super::*;

pub(super) fn read_tls(node: &Node, report: &mut Report) -> Option<MqttTls> {
    let ctx = "mqtt.tls";
    let mut map = node.map(report, ctx)?;
    let mut file = |key: &str, report: &mut Report| {
        map.get(key)
            .and_then(|n| path_at(n, report, &format!("{ctx}.{key}")))
    };
    let ca = file("ca", report);
    let cert = file("cert", report);
    let key = file("key", report);
    map.finish(report, ctx, TLS_KEYS);
    Some(MqttTls { ca, cert, key })
}

pub(super) fn read_sparkplug(node: &Node, report: &mut Report) -> Option<SparkplugConfig> {
    let ctx = "mqtt.sparkplug";
    let mut map = node.map(report, ctx)?;
    let group_id = map
        .require("group_id", report, ctx)
        .and_then(|n| level_at(n, report, &format!("{ctx}.group_id")));
    let edge_node_id = map
        .require("edge_node_id", report, ctx)
        .and_then(|n| level_at(n, report, &format!("{ctx}.edge_node_id")));
    let primary_host = map
        .get("primary_host")
        .and_then(|n| level_at(n, report, &format!("{ctx}.primary_host")));
    map.finish(report, ctx, SPARKPLUG_KEYS);
    Some(SparkplugConfig {
        group_id: group_id?,
        edge_node_id: edge_node_id?,
        primary_host,
    })
}

pub(super) fn read_json(node: &Node, report: &mut Report) -> Option<JsonConfig> {
    let ctx = "mqtt.json";
    let mut map = node.map(report, ctx)?;
    let prefix = map.require("prefix", report, ctx).and_then(|n| {
        let text = n.scalar_text(report, &format!("{ctx}.prefix"))?;
        check_prefix(&text)
            .map_err(|e| report.push(n.line, format!("{ctx}.prefix"), e))
            .ok()?;
        Some(text)
    });
    let qos = match map.get("qos") {
        None => Some(1),
        Some(n) => n
            .int_in(report, &format!("{ctx}.qos"), 0, 1)
            .map(|q| q as u8),
    };
    let retain = match map.get("retain") {
        None => Some(true),
        Some(n) => boolean(n, report, &format!("{ctx}.retain")),
    };
    map.finish(report, ctx, JSON_KEYS);
    Some(JsonConfig {
        prefix: prefix?,
        qos: qos.unwrap_or(1),
        retain: retain.unwrap_or(true),
    })
}

pub(super) fn read_report(node: &Node, report: &mut Report) -> Option<ReportConfig> {
    let ctx = "mqtt.report";
    let mut map = node.map(report, ctx)?;
    let deadband = map
        .get("deadband")
        .and_then(|n| read_deadband(n, report, &format!("{ctx}.deadband")));
    let min_interval = map
        .get("min_interval")
        .and_then(|n| duration_at(n, report, &format!("{ctx}.min_interval")));
    let max_interval = map
        .get("max_interval")
        .and_then(|n| duration_at(n, report, &format!("{ctx}.max_interval")));
    map.finish(report, ctx, REPORT_KEYS);
    let config = ReportConfig {
        deadband: deadband.unwrap_or_default(),
        min_interval: min_interval.unwrap_or(DEFAULT_MIN_INTERVAL),
        max_interval: max_interval.unwrap_or(DEFAULT_MAX_INTERVAL),
    };
    if config.max_interval > Duration::ZERO && config.max_interval < config.min_interval {
        report.push(
            node.line,
            format!("{ctx}.max_interval"),
            "must not be shorter than min_interval",
        );
    }
    Some(config)
}

pub(super) fn read_buffer(node: &Node, report: &mut Report) -> Option<BufferConfig> {
    let ctx = "mqtt.buffer";
    let mut map = node.map(report, ctx)?;
    let dir = map
        .get("dir")
        .and_then(|n| path_at(n, report, &format!("{ctx}.dir")));
    let max_bytes = map.get("max_bytes").and_then(|n| {
        let c = format!("{ctx}.max_bytes");
        let text = n.scalar_text(report, &c)?;
        match parse_size(&text) {
            Some(b) if b >= 1 << 20 => Some(b),
            Some(_) => {
                report.push(n.line, c, "must be at least 1MiB");
                None
            }
            None => {
                report.push(
                    n.line,
                    c,
                    format!("`{text}` is not a size (write e.g. 256MiB, 1GiB or 500MB)"),
                );
                None
            }
        }
    });
    let max_age = map
        .get("max_age")
        .and_then(|n| duration_at(n, report, &format!("{ctx}.max_age")));
    let replay_rate = map.get("replay_rate").and_then(|n| {
        let c = format!("{ctx}.replay_rate");
        let rate = match &n.kind {
            Kind::Int(i) => u32::try_from(*i).ok(),
            _ => n
                .scalar_text(report, &c)?
                .strip_suffix("/s")
                .and_then(|r| r.trim().parse::<u32>().ok()),
        };
        match rate {
            Some(r) if (1..=1_000_000).contains(&r) => Some(r),
            _ => {
                report.push(
                    n.line,
                    c,
                    "is not a rate (write messages per second, e.g. 500/s; 1/s to 1000000/s)",
                );
                None
            }
        }
    });
    let fsync = map.get("fsync").and_then(|n| {
        let c = format!("{ctx}.fsync");
        let text = n.scalar_text(report, &c)?;
        match text.as_str() {
            "always" => Some(Fsync::Always),
            "second" => Some(Fsync::Second),
            "never" => Some(Fsync::Never),
            other => {
                report.push(
                    n.line,
                    c,
                    format!("unknown choice `{other}` (expected always, second or never)"),
                );
                None
            }
        }
    });
    map.finish(report, ctx, BUFFER_KEYS);
    Some(BufferConfig {
        dir,
        max_bytes: max_bytes.unwrap_or(DEFAULT_MAX_BYTES),
        max_age: max_age.unwrap_or(DEFAULT_MAX_AGE),
        replay_rate: replay_rate.unwrap_or(DEFAULT_REPLAY_RATE),
        fsync: fsync.unwrap_or_default(),
    })
}
