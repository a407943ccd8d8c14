//! The gateway's resident memory by the number of fields it holds.

use std::time::Duration;

use super::common::{self, Row};
use super::profiles_dir;

/// Resident memory with `fields` fields: simulated devices of 100 fields each.
fn footprint(fields: usize) -> anyhow::Result<u64> {
    let dir = common::temp_dir(&format!("suite-fields-{fields}"))?;
    let mut profile = String::from("name: Hundred\nprotocol: simulated\nfields:\n");
    for i in 0..100 {
        let ty = ["REAL", "INT", "BOOL", "DINT"][i % 4];
        let direction = if i % 5 == 0 { "output" } else { "input" };
        profile.push_str(&format!(
            "  - {{ name: F{i}, type: {ty}, direction: {direction}, register: {{ address: {i}, kind: virtual }} }}\n"
        ));
    }
    let profiles = profiles_dir(&dir)?;
    std::fs::write(profiles.join("hundred.yaml"), profile)?;
    let mut config = format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {}\ndevices:\n",
        profiles.display()
    );
    for d in 0..fields / 100 {
        config.push_str(&format!(
            "  - {{ name: d{d}, profile: Hundred, refresh_rate: 1s }}\n"
        ));
    }
    let gateway = common::start(&dir, &config)?;
    std::thread::sleep(Duration::from_secs(3));
    Ok(common::rss_kib(gateway.child.id()))
}

pub(crate) fn footprints(rows: &mut Vec<Row>) -> anyhow::Result<()> {
    let base = footprint(100)?;
    for fields in [10_000, 50_000] {
        let rss = footprint(fields)?;
        let per_field = (rss.saturating_sub(base) * 1024) as f64 / (fields - 100) as f64;
        println!(
            "{fields} fields: {} KiB resident (one device of 100: {base} KiB)",
            rss
        );
        rows.push(Row {
            measure: format!("footprint, {fields} fields (MiB resident)"),
            iogate: format!("{:.1}", rss as f64 / 1024.0),
            peer: format!("100 fields {:.1} MiB", base as f64 / 1024.0),
            ratio: rss as f64 / base as f64,
            goal: format!("{per_field:.0} bytes per field"),
        });
    }
    Ok(())
}
