//! The two text formats a scraper may ask for. The registry writes OpenMetrics 1.0; a
//! scraper that does not ask for it by `Accept` (curl, promtool, older Prometheus, most
//! tools) gets the Prometheus text format 0.0.4, as the official client libraries answer.
//! The two differ in a few lines, so 0.0.4 is written from the OpenMetrics text: counter
//! families are named with their `_total` suffix, `# UNIT` and `# EOF` go, `unknown` is
//! `untyped`, `info` a gauge, `_created` samples and exemplars are dropped.

use std::collections::HashMap;

/// A text exposition format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    /// `application/openmetrics-text; version=1.0.0`.
    OpenMetrics,
    /// `text/plain; version=0.0.4`.
    Prometheus,
}

impl Format {
    /// The format an `Accept` header asks for: OpenMetrics when it names
    /// `application/openmetrics-text` with a quality at least that of any other type it
    /// names; else (no header, `*/*`, `text/plain`, anything else) the Prometheus format.
    pub(crate) fn negotiate(accept: Option<&str>) -> Format {
        let Some(accept) = accept else {
            return Format::Prometheus;
        };
        let mut openmetrics: Option<f32> = None;
        let mut other: f32 = 0.0;
        for range in accept.split(',') {
            let mut parts = range.split(';').map(str::trim);
            let media = parts.next().unwrap_or("").to_ascii_lowercase();
            let q = parts
                .filter_map(|p| p.split_once('='))
                .find(|(k, _)| k.trim().eq_ignore_ascii_case("q"))
                .and_then(|(_, v)| v.trim().parse::<f32>().ok())
                .unwrap_or(1.0);
            if media == "application/openmetrics-text" {
                openmetrics = Some(openmetrics.map_or(q, |best| best.max(q)));
            } else if !media.is_empty() {
                other = other.max(q);
            }
        }
        match openmetrics {
            Some(q) if q > 0.0 && q >= other => Format::OpenMetrics,
            _ => Format::Prometheus,
        }
    }

    pub(crate) fn content_type(self) -> &'static str {
        match self {
            Format::OpenMetrics => "application/openmetrics-text; version=1.0.0; charset=utf-8",
            Format::Prometheus => "text/plain; version=0.0.4; charset=utf-8",
        }
    }
}

/// The families' types as the OpenMetrics text declares them.
fn family_types(openmetrics: &str) -> HashMap<&str, &str> {
    openmetrics
        .lines()
        .filter_map(|l| l.strip_prefix("# TYPE "))
        .filter_map(|l| l.split_once(' '))
        .collect()
}

/// The Prometheus 0.0.4 text of an OpenMetrics 1.0 exposition.
pub(crate) fn to_prometheus(openmetrics: &str) -> String {
    let types = family_types(openmetrics);
    // The name a family's HELP and TYPE lines carry in 0.0.4.
    let renamed = |name: &str| -> String {
        match types.get(name).copied() {
            Some("counter") => format!("{name}_total"),
            Some("info") => format!("{name}_info"),
            _ => name.to_owned(),
        }
    };
    let mut out = String::with_capacity(openmetrics.len());
    for line in openmetrics.lines() {
        if line == "# EOF" || line.starts_with("# UNIT ") {
            continue;
        }
        if let Some(rest) = line.strip_prefix("# HELP ") {
            let (name, help) = rest.split_once(' ').unwrap_or((rest, ""));
            // 0.0.4 escapes only `\` and newlines in HELP.
            let help = help.replace("\\\"", "\"");
            out.push_str(&format!("# HELP {} {help}\n", renamed(name)));
            continue;
        }
        if let Some(rest) = line.strip_prefix("# TYPE ") {
            let (name, ty) = rest.split_once(' ').unwrap_or((rest, "untyped"));
            let ty = match ty {
                "counter" | "gauge" | "histogram" | "summary" => ty,
                "info" | "stateset" => "gauge",
                "gaugehistogram" => "histogram",
                _ => "untyped",
            };
            out.push_str(&format!("# TYPE {} {ty}\n", renamed(name)));
            continue;
        }
        if line.starts_with('#') {
            continue;
        }
        let metric = line.split(['{', ' ']).next().unwrap_or("");
        let created = metric
            .strip_suffix("_created")
            .is_some_and(|family| types.get(family) == Some(&"counter"));
        if created {
            continue;
        }
        // An exemplar follows ` # ` after the value; 0.0.4 has none.
        let labels_end = label_end(line);
        let sample = match line[labels_end..].find(" # ") {
            Some(at) => &line[..labels_end + at],
            None => line,
        };
        out.push_str(sample);
        out.push('\n');
    }
    out
}

/// Where a sample's label set ends (after its closing brace), or 0 without one.
fn label_end(line: &str) -> usize {
    // A label set follows the name directly; a brace after a space is an exemplar's.
    let Some(open) = line
        .find(['{', ' '])
        .filter(|&at| line[at..].starts_with('{'))
    else {
        return 0;
    };
    let mut quoted = false;
    let mut escaped = false;
    for (i, c) in line[open..].char_indices() {
        match c {
            _ if escaped => escaped = false,
            '\\' if quoted => escaped = true,
            '"' => quoted = !quoted,
            '}' if !quoted => return open + i + 1,
            _ => {}
        }
    }
    line.len()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_format_is_what_the_scraper_asks_for() {
        assert_eq!(Format::negotiate(None), Format::Prometheus);
        assert_eq!(Format::negotiate(Some("*/*")), Format::Prometheus);
        assert_eq!(Format::negotiate(Some("text/plain")), Format::Prometheus);
        assert_eq!(
            Format::negotiate(Some("application/openmetrics-text; version=1.0.0")),
            Format::OpenMetrics
        );
        // What Prometheus sends.
        assert_eq!(
            Format::negotiate(Some(
                "application/openmetrics-text;version=1.0.0,application/openmetrics-text;version=0.0.1;q=0.75,text/plain;version=0.0.4;q=0.5,*/*;q=0.1"
            )),
            Format::OpenMetrics
        );
        assert_eq!(
            Format::negotiate(Some(
                "text/plain;version=0.0.4,application/openmetrics-text;q=0.5"
            )),
            Format::Prometheus
        );
        assert_eq!(
            Format::negotiate(Some("application/openmetrics-text;q=0")),
            Format::Prometheus
        );
    }

    #[test]
    fn counters_are_named_with_total_and_openmetrics_lines_go() {
        let om = "\
# HELP iogate_requests Requests \\\"sent\\\".
# TYPE iogate_requests counter
iogate_requests_total{link=\"a # b\"} 3
iogate_requests_created{link=\"a # b\"} 1700000000.0
# HELP iogate_response_seconds Response time.
# TYPE iogate_response_seconds histogram
# UNIT iogate_response_seconds seconds
iogate_response_seconds_bucket{le=\"+Inf\"} 1
iogate_response_seconds_sum 0.5
iogate_response_seconds_count 1
# HELP iogate_up Up.
# TYPE iogate_up gauge
iogate_up 1 # {trace=\"x\"} 1
# EOF
";
        assert_eq!(
            to_prometheus(om),
            "\
# HELP iogate_requests_total Requests \"sent\".
# TYPE iogate_requests_total counter
iogate_requests_total{link=\"a # b\"} 3
# HELP iogate_response_seconds Response time.
# TYPE iogate_response_seconds histogram
iogate_response_seconds_bucket{le=\"+Inf\"} 1
iogate_response_seconds_sum 0.5
iogate_response_seconds_count 1
# HELP iogate_up Up.
# TYPE iogate_up gauge
iogate_up 1
"
        );
    }
}
