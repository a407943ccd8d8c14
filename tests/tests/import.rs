//! `iogate profile import` against published device descriptions (wb-mqtt-serial templates,
//! EdgeX device profiles; `tests/fixtures/import/`, with their licences): every result loads
//! as `iogate check` loads it, what cannot be mapped is named with its line, and a device
//! emulated from the source file's own map reads, through the imported profile, the values
//! the source file's map says.

use std::path::Path;

use iogate::profile::import::{Converted, import_file};
use iogate_tests::devices::{ModbusDevice, modbus_tcp_server, temp_dir};
use iogate_tests::{TestGateway, fixtures_dir};
use serde_json::Value;

fn import(dir: &str, file: &str) -> Result<Converted, String> {
    import_file(&fixtures_dir().join("import").join(dir).join(file), None)
}

/// The name a source name becomes (what the import's report and files show).
fn field_name(source: &str) -> String {
    let mut out = String::new();
    for c in source.chars() {
        if c.is_ascii_alphanumeric() {
            out.push(c);
        } else if !out.ends_with('_') {
            out.push('_');
        }
    }
    out.trim_matches('_').to_owned()
}

#[test]
fn every_published_file_imports_into_profiles_that_load_or_says_why_not() {
    let out = temp_dir("import-all");
    let mut imported = 0;
    for dir in ["wb", "edgex"] {
        for entry in std::fs::read_dir(fixtures_dir().join("import").join(dir)).expect("dir") {
            let path = entry.expect("entry").path();
            let name = path
                .file_name()
                .expect("name")
                .to_string_lossy()
                .into_owned();
            if name == "LICENSE" {
                continue;
            }
            match (name.as_str(), import(dir, &name)) {
                ("config-akko.json", Err(e)) => {
                    assert!(e.contains("protocol `dooya` is not Modbus"), "{e}")
                }
                ("config-wb-mai6.json.jinja", Err(e)) => {
                    assert!(
                        e.contains("config-wb-mai6.json.jinja:") && e.contains("a Jinja template"),
                        "{e}"
                    )
                }
                (_, Ok(c)) => {
                    std::fs::write(out.join(&c.file_name), &c.text).expect("write");
                    imported += 1;
                }
                (_, Err(e)) => panic!("{name}: {e}"),
            }
        }
    }
    assert_eq!(imported, 12);
    // What `iogate check` loads: every profile, none with a problem (the two ONOKOM
    // templates, deprecated and current, give one name).
    let profiles = iogate::profile::load_dir(&out).unwrap_or_else(|p| panic!("{p}"));
    assert_eq!(profiles.len(), 11);

    // What was not mapped is named with the source's line.
    let danfoss = import("wb", "config-danfoss-fc51.json").expect("danfoss");
    let source = std::fs::read_to_string(fixtures_dir().join("import/wb/config-danfoss-fc51.json"))
        .expect("source");
    let setup_line = source
        .lines()
        .position(|l| l.contains("\"setup\""))
        .expect("setup")
        + 1;
    assert!(
        danfoss
            .unmapped
            .iter()
            .any(|u| u.contains(&format!("config-danfoss-fc51.json:{setup_line}: `setup`"))),
        "{:#?}",
        danfoss.unmapped
    );
    let pzem = import("wb", "config-pzem-016.json").expect("pzem");
    assert!(
        pzem.unmapped.iter().all(|u| u.contains("round_to")),
        "{:#?}",
        pzem.unmapped
    );
    // A template with comments and tabs (as wb-mqtt-serial reads them) imports.
    assert!(import("wb", "config-drb88.json").is_ok());
    let edgex = import("edgex", "modbus.test.device.profile.yml").expect("edgex");
    assert!(
        edgex
            .unmapped
            .iter()
            .any(|u| u.contains(":98: device command `Switch`")),
        "{:#?}",
        edgex.unmapped
    );
}

/// The registers a wb-mqtt-serial channel of `format` holds for `raw` (an integer, or a
/// float's value), in its word order; read from the template's own keys.
fn wb_words(format: &str, raw: f64, little_words: bool) -> Vec<u16> {
    let mut words = match format {
        "u16" | "s16" => vec![(raw as i64 as i16) as u16],
        "u32" | "s32" => {
            let v = raw as i64 as u32;
            vec![(v >> 16) as u16, v as u16]
        }
        "float" => {
            let v = (raw as f32).to_bits();
            vec![(v >> 16) as u16, v as u16]
        }
        other => panic!("the test encodes no {other}"),
    };
    if little_words {
        words.reverse();
    }
    words
}

/// A device emulated from a wb-mqtt-serial template's channels: each readable register
/// channel holds a value of its own; returns the device and each field's expected value.
fn wb_device(file: &str) -> (ModbusDevice, Vec<(String, f64)>) {
    let text =
        std::fs::read_to_string(fixtures_dir().join("import/wb").join(file)).expect("source");
    let source: Value = serde_json::from_str(&text).expect("json");
    let device = ModbusDevice::default();
    let mut expected = Vec::new();
    let mut tables = device.tables.lock().expect("tables");
    for (i, ch) in source["device"]["channels"]
        .as_array()
        .expect("channels")
        .iter()
        .enumerate()
    {
        let address = match &ch["address"] {
            Value::String(s) => u16::from_str_radix(
                s.trim_start_matches("0x"),
                if s.starts_with("0x") { 16 } else { 10 },
            )
            .expect("address"),
            v => v.as_u64().expect("address") as u16,
        };
        let format = ch["format"].as_str().unwrap_or("u16");
        let scale = ch["scale"].as_f64().unwrap_or(1.0);
        let offset = ch["offset"].as_f64().unwrap_or(0.0);
        let little = ch["word_order"].as_str() == Some("little_endian");
        let (raw, value) = if format == "float" {
            let v = 200.25 + i as f64;
            (v, v * scale + offset)
        } else {
            let raw = 100.0 + 7.0 * i as f64;
            (raw, raw * scale + offset)
        };
        let table = match ch["reg_type"].as_str() {
            Some("input") => &mut tables.input,
            _ => &mut tables.holding,
        };
        for (k, w) in wb_words(format, raw, little).into_iter().enumerate() {
            table[usize::from(address) + k] = w;
        }
        expected.push((field_name(ch["name"].as_str().expect("name")), value));
    }
    drop(tables);
    (device, expected)
}

async fn poll(
    profiles: &Path,
    profile: &str,
    device: ModbusDevice,
) -> (TestGateway, Value, tokio::task::JoinHandle<()>) {
    let (port, server) = modbus_tcp_server(device).await;
    let gw = TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n\
         devices:\n  - {{ name: dev, profile: {profile}, link: plant, slave_id: 1, refresh_rate: 50ms, max_gap: 20 }}\n",
        profiles.display()
    ))
    .await
    .expect("gateway");
    let body = gw.all_read("dev").await.expect("every field read");
    (gw, body, server)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_emulated_from_the_source_map_reads_the_same_through_the_imported_profile() {
    let profiles = temp_dir("import-poll");
    for (dir, file) in [
        ("wb", "config-pzem-016.json"),
        ("wb", "config-sdm220.json"),
        ("edgex", "modbus.test.device.profile.yml"),
    ] {
        let c = import(dir, file).expect("import");
        std::fs::write(profiles.join(&c.file_name), &c.text).expect("write");
    }
    for (file, profile) in [
        ("config-pzem-016.json", "PZEM_016"),
        ("config-sdm220.json", "SDM220"),
    ] {
        let (device, expected) = wb_device(file);
        let (gw, body, server) = poll(&profiles, profile, device).await;
        for (name, want) in &expected {
            let got = body["fields"][name]["value"]
                .as_f64()
                .unwrap_or_else(|| panic!("{file} {name}: {body:#}"));
            assert!(
                (got - want).abs() <= want.abs() * 1e-6 + 1e-9,
                "{file} {name}: read {got}, the map says {want}"
            );
        }
        gw.shutdown().await;
        server.abort();
    }

    // The EdgeX profile's map, as its resources state it.
    let device = ModbusDevice::default();
    {
        let mut t = device.tables.lock().expect("tables");
        t.coils[0] = true; // SwitchA: COILS 0
        t.coils[14] = false; // SwitchB: COILS 14
        t.holding[1] = 7; // OperationMode: HOLDING 1, Int16
        t.holding[2] = 0; // FanSpeed: HOLDING 2-3, Int32
        t.holding[3] = 3;
        t.input[3] = 215; // RoomTemperature: INPUT 3, rawType Int16, scale 0.1
        t.holding[5] = (-50i16) as u16; // Temperature: HOLDING 5, rawType Int16, scale 0.1
        t.holding[10] = 1 << 10; // CommunicationFailure: HOLDING 10.10 (bit 10)
    }
    let (gw, body, server) = poll(&profiles, "Test_Device_Modbus_Profile", device).await;
    let f = &body["fields"];
    assert_eq!(f["SwitchA"]["value"], true, "{body:#}");
    assert_eq!(f["SwitchB"]["value"], false);
    assert_eq!(f["OperationMode"]["value"], 7);
    assert_eq!(f["FanSpeed"]["value"], 3);
    assert!(
        (f["RoomTemperature"]["value"].as_f64().expect("t") - 21.5).abs() < 1e-6,
        "{body:#}"
    );
    assert!(
        (f["Temperature"]["value"].as_f64().expect("t") + 5.0).abs() < 1e-6,
        "{body:#}"
    );
    assert_eq!(f["CommunicationFailure"]["value"], true);
    gw.shutdown().await;
    server.abort();
}

/// Writes `value` to `field` of `dev` and waits for the write's outcome.
async fn write(gw: &TestGateway, field: &str, value: bool) {
    let (status, body) = gw
        .send(
            reqwest::Method::PUT,
            &format!("/api/v1/devices/dev/fields/{field}"),
            format!("{{\"value\": {value}}}"),
        )
        .await
        .expect("put");
    assert_eq!(status, 202, "{body}");
    let generation = body["generation"].as_u64().expect("generation");
    gw.until(&format!("/api/v1/writes/{generation}"), "written", |w| {
        w["status"] == "written"
    })
    .await
    .expect("written");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_switch_with_its_own_on_and_off_values_is_written_as_the_device_means_it() {
    let profiles = temp_dir("import-switch");
    for file in ["config-carel-ir33.json", "config-bac-6000aln.json"] {
        let c = import("wb", file).expect("import");
        std::fs::write(profiles.join(&c.file_name), &c.text).expect("write");
    }

    // Carel IR33 "Unit On-Off": coil 54, on_value 0 / off_value 1; the unit is off.
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").coils[54] = true;
    let (gw, body, server) = poll(&profiles, "carel_ir33", device.clone()).await;
    assert_eq!(body["fields"]["Unit_On_Off"]["value"], false, "{body:#}");
    write(&gw, "Unit_On_Off", true).await;
    assert!(
        !device.tables.lock().expect("tables").coils[54],
        "TRUE (switch the unit on) is coil 54 = 0"
    );
    gw.until("/api/v1/devices/dev/fields/Unit_On_Off", "on", |f| {
        f["value"] == true
    })
    .await
    .expect("read back on");
    write(&gw, "Unit_On_Off", false).await;
    assert!(
        device.tables.lock().expect("tables").coils[54],
        "FALSE is 1"
    );
    gw.shutdown().await;
    server.abort();

    // BAC-6000ALN "Status": holding 0, on 0x00a5 / off 0x005a; anything else is no value.
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").holding[0] = 0x5a;
    let (gw, body, server) = poll(&profiles, "BAC_6000ALN", device.clone()).await;
    assert_eq!(body["fields"]["Status"]["value"], false, "{body:#}");
    write(&gw, "Status", true).await;
    assert_eq!(device.tables.lock().expect("tables").holding[0], 0xa5);
    device.tables.lock().expect("tables").holding[0] = 7;
    let bad = gw
        .until("/api/v1/devices/dev/fields/Status", "bad", |f| {
            f["quality"] == "bad"
        })
        .await
        .expect("a value that is neither is bad");
    assert!(
        bad.to_string()
            .contains("neither on_value 165 nor off_value 90"),
        "{bad:#}"
    );
    gw.shutdown().await;
    server.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scaled_thirty_two_bit_counter_keeps_every_digit() {
    let profiles = temp_dir("import-lreal");
    let c = import("wb", "config-pzem-016.json").expect("import");
    assert!(c.text.contains("name: Energy, type: LREAL"), "{}", c.text);
    std::fs::write(profiles.join(&c.file_name), &c.text).expect("write");
    // Energy: input 5-6, u32 low word first, scale 0.0001: 123456789 is 12345.6789 kWh.
    let device = ModbusDevice::default();
    {
        let mut t = device.tables.lock().expect("tables");
        t.input[5] = (123_456_789u32 & 0xFFFF) as u16;
        t.input[6] = (123_456_789u32 >> 16) as u16;
    }
    let (gw, body, server) = poll(&profiles, "PZEM_016", device).await;
    assert_eq!(body["fields"]["Energy"]["value"], 12345.6789, "{body:#}");
    gw.shutdown().await;
    server.abort();
}

#[test]
fn a_current_template_is_imported_over_its_deprecated_twin_with_its_title_resolved() {
    let current = import("wb", "config-onokom-air-aux-1-mb-b.json").expect("current");
    assert!(!current.deprecated);
    assert!(
        current
            .text
            .contains("description: \"ONOKOM AIR AUX-1-MB-B (Adapter"),
        "the title is the translation of `template_title`"
    );
    let old = import("wb", "config-onokom-air-aux-1-mb-b-depricated.json").expect("old");
    assert!(old.deprecated);
    assert_eq!(old.profile, current.profile);
    assert!(current.fields > old.fields);
}
