//! The profile library: each profile that cites a public register map reads, from a device
//! emulated from that map (`tests/fixtures/library/`), what the map says; and every cited
//! profile has such a check.

use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
use iogate_tests::{TestGateway, fixtures_dir, profiles_dir};
use serde_json::Value;

/// The profile names of `profiles/` whose description cites a register map.
fn cited() -> Vec<String> {
    iogate::drivers::register();
    let mut names: Vec<String> = iogate::profile::load_dir(&profiles_dir())
        .expect("profiles load")
        .into_iter()
        .filter(|p| {
            let yaml =
                std::fs::read_to_string(profiles_dir().join(format!("{}.yaml", snake(&p.name))));
            yaml.is_ok_and(|t| t.contains("Register map:"))
        })
        .map(|p| p.name)
        .collect();
    names.sort();
    names
}

/// A profile's file is its name's snake case, but not always: find it by its `name:` line.
fn snake(name: &str) -> String {
    std::fs::read_dir(profiles_dir())
        .expect("profiles")
        .filter_map(Result::ok)
        .find(|e| {
            std::fs::read_to_string(e.path())
                .is_ok_and(|t| t.lines().any(|l| l.trim() == format!("name: {name}")))
        })
        .and_then(|e| {
            e.path()
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
        })
        .unwrap_or_default()
}

fn fill(table: &mut [u16], spec: &Value) {
    for (start, values) in spec.as_object().into_iter().flatten() {
        let start: usize = start.parse().expect("address");
        for (i, v) in values.as_array().expect("values").iter().enumerate() {
            table[start + i] = v.as_u64().expect("register") as u16;
        }
    }
}

fn fill_bits(table: &mut [bool], spec: &Value) {
    for (start, values) in spec.as_object().into_iter().flatten() {
        let start: usize = start.parse().expect("address");
        for (i, v) in values.as_array().expect("values").iter().enumerate() {
            table[start + i] = v.as_u64() == Some(1);
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_cited_profile_reads_what_its_published_map_says() {
    let cited = cited();
    assert!(cited.len() >= 4, "{cited:?}");
    for name in &cited {
        let path = fixtures_dir().join(format!("library/{name}.json"));
        let text = std::fs::read_to_string(&path).unwrap_or_else(|_| {
            panic!(
                "profile {name} cites a map but has no emulated device at {}",
                path.display()
            )
        });
        let spec: Value = serde_json::from_str(&text).expect("json");
        let device = ModbusDevice::default();
        {
            let mut t = device.tables.lock().expect("tables");
            fill(&mut t.holding, &spec["tables"]["holding"]);
            fill(&mut t.input, &spec["tables"]["input"]);
            fill_bits(&mut t.coils, &spec["tables"]["coils"]);
            fill_bits(&mut t.discrete, &spec["tables"]["discrete"]);
        }
        let (port, server) = modbus_tcp_server(device).await;
        let gw = TestGateway::start(&format!(
            "profiles: {}\nlinks:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n\
             devices:\n  - {{ name: dev, profile: {name}, link: plant, slave_id: 1, refresh_rate: 50ms }}\n",
            profiles_dir().display()
        ))
        .await
        .expect("gateway");
        let body = gw
            .all_read("dev")
            .await
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        for (field, want) in spec["expect"].as_object().expect("expect") {
            let got = &body["fields"][field]["value"];
            let same = match (got.as_f64(), want.as_f64()) {
                (Some(g), Some(w)) => (g - w).abs() <= w.abs() * 1e-6,
                _ => got == want,
            };
            assert!(same, "{name}.{field}: read {got}, the map says {want}");
        }
        gw.shutdown().await;
        server.abort();
    }
}
