//! The Modbus engine over real pseudo-terminals: the gateway opens the pty by path, as it
//! would open /dev/ttyUSB0, and devices answer on the other end.

use std::time::Duration;

use reqwest::Method;
use serde_json::{Value, json};

use iogate_tests::devices::{Behaviour, ModbusDevice, RtuBus, pty_at, temp_dir};
use iogate_tests::{TestGateway, bus_gateway, eventually, link_yaml};

/// The documented byte orders, letter by letter (A = most significant byte).
fn order_letters(order: &str, len: usize) -> &'static str {
    match (order, len) {
        ("big-endian", 2) | ("swap-words", 2) => "AB",
        ("little-endian", 2) | ("swap-bytes", 2) => "BA",
        ("big-endian", 4) => "ABCD",
        ("little-endian", 4) => "DCBA",
        ("swap-bytes", 4) => "BADC",
        ("swap-words", 4) => "CDAB",
        ("big-endian", 8) => "ABCDEFGH",
        ("little-endian", 8) => "HGFEDCBA",
        ("swap-bytes", 8) => "BADCFEHG",
        ("swap-words", 8) => "GHEFCDAB",
        _ => panic!("no letters for {order} {len}"),
    }
}

/// Registers holding `value_bytes` (most significant first) in `order`.
fn registers(order: &str, value_bytes: &[u8]) -> Vec<u16> {
    let letters = order_letters(order, value_bytes.len());
    let bytes: Vec<u8> = letters
        .bytes()
        .map(|l| value_bytes[usize::from(l - b'A')])
        .collect();
    bytes
        .chunks_exact(2)
        .map(|p| u16::from_be_bytes([p[0], p[1]]))
        .collect()
}

const ORDERS: [&str; 4] = ["big-endian", "little-endian", "swap-bytes", "swap-words"];

#[tokio::test]
async fn every_type_and_byte_order_reads_as_the_device_holds_it() {
    // (type, extra register options, value bytes, expected JSON)
    let cases: Vec<(&str, &str, Vec<u8>, Value)> = vec![
        ("SINT", "", (-5i16).to_be_bytes().to_vec(), json!(-5)),
        ("USINT", "", 200u16.to_be_bytes().to_vec(), json!(200)),
        ("BYTE", "", 0xA5u16.to_be_bytes().to_vec(), json!(0xA5)),
        ("INT", "", (-12345i16).to_be_bytes().to_vec(), json!(-12345)),
        ("UINT", "", 54321u16.to_be_bytes().to_vec(), json!(54321)),
        ("WORD", "", 0xBEEFu16.to_be_bytes().to_vec(), json!(0xBEEF)),
        (
            "DINT",
            ", word_count: 2",
            (-123_456_789i32).to_be_bytes().to_vec(),
            json!(-123_456_789),
        ),
        (
            "UDINT",
            ", word_count: 2",
            3_000_000_000u32.to_be_bytes().to_vec(),
            json!(3_000_000_000u32),
        ),
        (
            "DWORD",
            ", word_count: 2",
            0xDEAD_BEEFu32.to_be_bytes().to_vec(),
            json!(0xDEAD_BEEFu32),
        ),
        (
            "LINT",
            ", word_count: 4",
            (-1_234_567_890_123_456_789i64).to_be_bytes().to_vec(),
            json!(-1_234_567_890_123_456_789i64),
        ),
        (
            "ULINT",
            ", word_count: 4",
            12_345_678_901_234_567_890u64.to_be_bytes().to_vec(),
            json!(12_345_678_901_234_567_890u64),
        ),
        (
            "LWORD",
            ", word_count: 4",
            0x0123_4567_89AB_CDEFu64.to_be_bytes().to_vec(),
            json!(0x0123_4567_89AB_CDEFu64),
        ),
        (
            "REAL",
            ", word_count: 2",
            230.5f32.to_be_bytes().to_vec(),
            json!(230.5),
        ),
        (
            "LREAL",
            ", word_count: 4",
            1.0e100f64.to_be_bytes().to_vec(),
            json!(1.0e100),
        ),
        (
            "REAL",
            ", scale: 0.1, offset: -40",
            450i16.to_be_bytes().to_vec(),
            json!(5.0),
        ),
        (
            "LREAL",
            ", raw_type: UDINT, scale: 0.01",
            123_456_789u32.to_be_bytes().to_vec(),
            json!(1_234_567.89),
        ),
        (
            "TIME",
            ", word_count: 4",
            90_500i64.to_be_bytes().to_vec(),
            json!(90_500),
        ),
        // With no word_count every type takes one register (the default is 1): wider
        // types read it widened, sign-extended when signed.
        ("DINT", "", (-1234i16).to_be_bytes().to_vec(), json!(-1234)),
        ("UDINT", "", 0xFFFEu16.to_be_bytes().to_vec(), json!(0xFFFE)),
        ("DWORD", "", 0x8001u16.to_be_bytes().to_vec(), json!(0x8001)),
        ("LINT", "", (-2i16).to_be_bytes().to_vec(), json!(-2)),
        ("ULINT", "", 40_000u16.to_be_bytes().to_vec(), json!(40_000)),
        ("LWORD", "", 0xABCDu16.to_be_bytes().to_vec(), json!(0xABCD)),
        ("TIME", "", (-500i16).to_be_bytes().to_vec(), json!(-500)),
        (
            "TIME",
            ", word_count: 1",
            30_000i16.to_be_bytes().to_vec(),
            json!(30_000),
        ),
        (
            "TIME",
            ", word_count: 2",
            86_400_000i32.to_be_bytes().to_vec(),
            json!(86_400_000),
        ),
        (
            "STRING",
            ", word_count: 4",
            b"HELLO W\0".to_vec(),
            json!("HELLO W"),
        ),
    ];
    let device = ModbusDevice::default();
    let mut profile = String::from("name: AllTypes\nfields:\n");
    let mut expected = Vec::new();
    let mut address = 0u16;
    // Outputs of the same types and orders in holding registers from 100, written later.
    let mut out_address = 100u16;
    let mut outputs = serde_json::Map::new();
    let mut written: Vec<(String, u16, Vec<u16>)> = Vec::new();
    {
        let mut tables = device.tables.lock().expect("tables");
        for (i, (ty, extra, bytes, value)) in cases.iter().enumerate() {
            for order in ORDERS {
                let name = format!("F{i}_{}", order.replace('-', "_"));
                profile.push_str(&format!(
                    "  - {{ name: {name}, type: {ty}, direction: input, register: {{ address: {address}, kind: input_register, byte_order: {order}{extra} }} }}\n"
                ));
                for (k, r) in registers(order, bytes).into_iter().enumerate() {
                    tables.input[usize::from(address) + k] = r;
                }
                address += (bytes.len() / 2) as u16;
                expected.push((name, value.clone()));
                let out = format!("O{i}_{}", order.replace('-', "_"));
                profile.push_str(&format!(
                    "  - {{ name: {out}, type: {ty}, direction: output, register: {{ address: {out_address}, kind: holding_register, byte_order: {order}{extra} }} }}\n"
                ));
                outputs.insert(out.clone(), value.clone());
                written.push((out, out_address, registers(order, bytes)));
                out_address += (bytes.len() / 2) as u16;
            }
        }
        tables.coils[3] = true;
        tables.discrete[5] = true;
        tables.input[900] = 0b1000;
        tables.holding[7] = 2;
    }
    profile.push_str("  - { name: Coil3, type: BOOL, direction: output, register: { address: 3, kind: coil } }\n");
    profile.push_str("  - { name: Di5, type: BOOL, direction: input, register: { address: 5, kind: discrete_input } }\n");
    profile.push_str("  - { name: Bit3, type: BOOL, direction: input, register: { address: 900, kind: input_register, bit: 3 } }\n");
    profile.push_str("  - { name: Bit2, type: BOOL, direction: input, register: { address: 900, kind: input_register, bit: 2 } }\n");
    profile.push_str("  - { name: Flag, type: BOOL, direction: input, register: { address: 7, kind: holding_register } }\n");
    for (name, value) in [
        ("Coil3", true),
        ("Di5", true),
        ("Bit3", true),
        ("Bit2", false),
        ("Flag", true),
    ] {
        expected.push((name.to_owned(), json!(value)));
    }

    let dir = temp_dir("all-types");
    std::fs::create_dir_all(dir.join("profiles")).expect("dir");
    std::fs::write(dir.join("profiles/all_types.yaml"), &profile).expect("profile");
    let port = dir.join("ttyBUS");
    let (device_end, _holder) = pty_at(&port).expect("pty");
    let server = tokio::spawn(
        tokio_modbus::server::rtu::Server::new(device_end).serve_forever(device.clone()),
    );
    let gw = TestGateway::start(&format!(
        "profiles: {}\n{}devices:\n  - {{ name: dev, profile: AllTypes, link: bus, slave_id: 1, refresh_rate: 50ms }}\n",
        dir.join("profiles").display(),
        link_yaml(&port)
    ))
    .await
    .expect("gateway");
    let body = gw.all_read("dev").await.expect("values");
    for (name, value) in &expected {
        let got = &body["fields"][name]["value"];
        let same = match (got.as_f64(), value.as_f64()) {
            (Some(a), Some(b)) if got.is_f64() || value.is_f64() => (a - b).abs() <= b.abs() * 1e-9,
            _ => got == value,
        };
        assert!(same, "{name}: got {got}, expected {value}");
    }
    assert_eq!(body["connected"], true);
    assert_eq!(body["error_code"], 0);

    // Every type and order written in one PATCH lands as the same registers.
    let (status, body) = gw
        .send(
            Method::PATCH,
            "/api/v1/devices/dev/fields",
            Value::Object(outputs).to_string(),
        )
        .await
        .expect("patch");
    assert_eq!(status, 202, "{body}");
    let generations: Vec<u64> = body["writes"]
        .as_array()
        .expect("writes")
        .iter()
        .filter_map(|w| w["generation"].as_u64())
        .collect();
    assert_eq!(generations.len(), written.len());
    for g in generations {
        gw.until(&format!("/api/v1/writes/{g}"), "written", |b| {
            b["status"] == "written"
        })
        .await
        .expect("written");
    }
    let tables = device.tables.lock().expect("tables").clone();
    for (name, address, regs) in &written {
        let start = usize::from(*address);
        assert_eq!(
            &tables.holding[start..start + regs.len()],
            regs.as_slice(),
            "{name}"
        );
    }
    gw.shutdown().await;
    server.abort();
}

const COUNTER_PROFILE: &str = "name: Counter\nfields:\n  - { name: Count, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: Setpoint, type: UINT, direction: output, register: { address: 0, kind: holding_register } }\n";

/// A gateway on a fresh bus; `devices` is the YAML list of devices.
/// What `bus_gateway` starts: the gateway, the holder of the pty's gateway end, the bus task
/// and the port path.
#[tokio::test]
async fn a_cycle_is_the_minimal_number_of_batched_transactions() {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "minimal",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 20ms }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "three cycles", |b| {
        b["io_cycles"].as_u64() >= Some(3)
    })
    .await
    .expect("cycles");
    bus.clear_seen();
    gw.until("/api/v1/devices/io", "more cycles", |b| {
        b["io_cycles"].as_u64() >= Some(8)
    })
    .await
    .expect("cycles");
    let seen = bus.seen();
    let mut distinct: Vec<(u8, u16, u16)> = seen
        .iter()
        .map(|s| (s.function, s.address, s.count))
        .collect();
    distinct.sort();
    distinct.dedup();
    // 8 discrete inputs, 8 coils, 4 input registers, 2 holding registers: one read each.
    assert_eq!(distinct, vec![(1, 0, 8), (2, 0, 8), (3, 0, 2), (4, 0, 4)]);
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_burst_of_writes_becomes_a_few_bus_writes_and_the_last_value_lands() {
    // The bus answers at 9600-baud speed, as a real line would.
    let bus = RtuBus::at_baud(9600);
    bus.slave(1, |_| {});
    let (gw, _pty, task, _) = bus_gateway(
        "burst",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 200ms }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    // 100 writes at once, as a burst from several clients; the newest is the one with the
    // highest generation.
    let puts = (0..100u32).map(|i| {
        let gw = &gw;
        async move {
            let value = f64::from(i) * 0.01;
            let (status, body) = gw
                .send(
                    Method::PUT,
                    "/api/v1/devices/io/fields/AO_0",
                    json!({ "value": value }).to_string(),
                )
                .await
                .expect("put");
            assert_eq!(status, 202, "{body}");
            (body["generation"].as_u64().expect("generation"), i)
        }
    });
    let mut accepted = futures_util::future::join_all(puts).await;
    accepted.sort();
    let (last, newest) = *accepted.last().expect("100 writes");
    gw.until(&format!("/api/v1/writes/{last}"), "last write", |b| {
        b["status"] == "written"
    })
    .await
    .expect("written");
    let value = bus.read_slave(1, |s| s.tables.holding[0]).expect("slave");
    assert_eq!(
        u32::from(value),
        newest * 10,
        "the newest value, at 0.001 V per count"
    );
    for (generation, _) in &accepted {
        let (_, body) = gw
            .get(&format!("/api/v1/writes/{generation}"))
            .await
            .expect("get");
        assert!(
            body["status"] == "written" || body["status"] == "superseded",
            "write {generation}: {body}"
        );
    }
    let writes = bus
        .seen()
        .iter()
        .filter(|s| s.function == 6 || s.function == 16)
        .count();
    println!("100 writes to one field became {writes} bus writes");
    assert!(writes <= 5, "{writes} bus writes for 100 requests");
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_device_without_fc15_and_fc16_gets_single_writes() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.single_writes_only = true);
    let (gw, _pty, task, _) = bus_gateway(
        "single-writes",
        &bus,
        &[],
        "  - { name: io, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms }\n",
    )
    .await;
    gw.until("/api/v1/devices/io", "connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("connected");
    let patch = |body: &'static str| {
        let gw = &gw;
        async move {
            let (status, answer) = gw
                .send(Method::PATCH, "/api/v1/devices/io/fields", body)
                .await
                .expect("patch");
            assert_eq!(status, 202, "{answer}");
            let last = answer["writes"]
                .as_array()
                .and_then(|w| w.iter().filter_map(|x| x["generation"].as_u64()).max())
                .expect("generations");
            for w in answer["writes"].as_array().expect("writes") {
                let g = w["generation"].as_u64().expect("generation");
                gw.until(&format!("/api/v1/writes/{g}"), "written", |b| {
                    b["status"] == "written"
                })
                .await
                .expect("every write lands");
            }
            last
        }
    };
    patch(r#"{"DO_0": true, "DO_1": true, "DO_2": true, "AO_0": 1.5, "AO_1": 2.5}"#).await;
    let tables = bus.read_slave(1, |s| s.tables.clone()).expect("slave");
    assert_eq!(&tables.coils[..3], &[true, true, true]);
    assert_eq!(&tables.holding[..2], &[1500, 2500]);
    let seen = bus.seen();
    let count = |f: u8| seen.iter().filter(|s| s.function == f).count();
    assert_eq!((count(15), count(16)), (1, 1), "each refused once");
    assert_eq!((count(5), count(6)), (3, 2), "then written one by one");

    // The device's limits are remembered: no more FC15/FC16.
    bus.clear_seen();
    patch(r#"{"DO_3": true, "DO_4": true}"#).await;
    let seen = bus.seen();
    assert!(
        seen.iter().all(|s| s.function != 15 && s.function != 16),
        "{seen:?}"
    );
    assert_eq!(seen.iter().filter(|s| s.function == 5).count(), 2);
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn writing_one_bit_keeps_the_other_bits_of_the_register() {
    let bus = RtuBus::default();
    bus.slave(2, |s| s.tables.holding[0] = 0x0080);
    let (gw, _pty, task, _) = bus_gateway(
        "bits",
        &bus,
        &[],
        "  - { name: vfd, profile: GenericVfd, link: bus, slave_id: 2, refresh_rate: 50ms }\n",
    )
    .await;
    let (status, _) = gw
        .send(Method::PUT, "/api/v1/devices/vfd/fields/Run", "true")
        .await
        .expect("put");
    assert_eq!(status, 202);
    eventually("Run bit set", || async {
        bus.read_slave(2, |s| s.tables.holding[0]) == Some(0x0081)
    })
    .await
    .expect("bit 0 set, bit 7 kept");
    gw.send(
        Method::PATCH,
        "/api/v1/devices/vfd/fields",
        r#"{"Reverse": true, "FrequencySetpoint": 49.99, "AccelTime": "T#2s500ms"}"#,
    )
    .await
    .expect("patch");
    eventually("control word and setpoint", || async {
        bus.read_slave(2, |s| {
            (
                s.tables.holding[0],
                s.tables.holding[1],
                s.tables.holding[2],
                s.tables.holding[3],
            )
        }) == Some((0x0083, 4999, 0, 2500))
    })
    .await
    .expect("written");
    gw.until("/api/v1/devices/vfd/fields/Reverse", "read back", |b| {
        b["value"] == true
    })
    .await
    .expect("read back");
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_refused_batch_is_split_and_the_other_fields_keep_working() {
    let bus = RtuBus::default();
    bus.slave(1, |s| {
        s.refused = vec![2];
        for i in 0..5 {
            s.tables.input[i] = 100 + i as u16;
        }
    });
    let profile = "name: Five\nfields:\n  - { name: A, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: B, type: UINT, direction: input, register: { address: 1, kind: input_register } }\n  - { name: C, type: UINT, direction: input, register: { address: 2, kind: input_register } }\n  - { name: D, type: UINT, direction: input, register: { address: 3, kind: input_register } }\n  - { name: E, type: UINT, direction: input, register: { address: 4, kind: input_register } }\n";
    let (gw, _pty, task, _) = bus_gateway(
        "split",
        &bus,
        &[("five.yaml", profile)],
        "  - { name: five, profile: Five, link: bus, slave_id: 1, refresh_rate: 20ms }\n",
    )
    .await;
    let body = gw
        .until("/api/v1/devices/five", "split", |b| {
            ["A", "B", "D", "E"]
                .iter()
                .all(|f| b["fields"][f]["quality"] == "good")
                && b["fields"]["C"]["quality"] == "bad"
        })
        .await
        .expect("fields");
    assert_eq!(body["fields"]["A"]["value"], 100);
    assert_eq!(body["fields"]["E"]["value"], 104);
    assert!(
        body["fields"]["C"]["error"]
            .as_str()
            .is_some_and(|e| e.contains("exception 02")),
        "{body}"
    );
    assert_eq!(body["connected"], true, "an exception is an answer");
    // The split is remembered: later cycles never ask for the whole range again.
    bus.clear_seen();
    gw.until("/api/v1/devices/five", "more cycles", |b| {
        b["io_cycles"].as_u64() >= Some(10)
    })
    .await
    .expect("cycles");
    assert!(bus.seen().iter().all(|s| s.count < 5), "{:?}", bus.seen());
    gw.shutdown().await;
    task.abort();
}

fn counter_value(body: &Value) -> Option<u64> {
    body["fields"]["Count"]["value"].as_u64()
}

#[tokio::test]
async fn misbehaving_devices_are_contained_while_another_keeps_updating() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.counter = Some(0));
    bus.slave(2, |s| s.counter = Some(0));
    let (gw, _pty, task, _) = bus_gateway(
        "misbehave",
        &bus,
        &[("counter.yaml", COUNTER_PROFILE)],
        "  - { name: good, profile: Counter, link: bus, slave_id: 1, refresh_rate: 20ms, timeout: 100ms }\n  - { name: flaky, profile: Counter, link: bus, slave_id: 2, refresh_rate: 20ms, timeout: 100ms, retries: 1 }\n",
    )
    .await;
    gw.until("/api/v1/devices/flaky", "flaky connected", |b| {
        b["connected"] == true
    })
    .await
    .expect("up");

    let phases = [
        (Behaviour::Silent, "timeout"),
        (Behaviour::Late(Duration::from_millis(120)), "timeout"),
        (Behaviour::BadCrc, "CRC mismatch"),
        (Behaviour::WrongLength, "invalid response"),
        (Behaviour::Exception(4), "exception 04"),
    ];
    for (behaviour, error) in phases {
        bus.slave(2, |s| s.behaviour = behaviour.clone());
        let flaky = gw
            .until(
                "/api/v1/devices/flaky",
                &format!("{behaviour:?} noticed"),
                |b| {
                    b["fields"]["Count"]["error"]
                        .as_str()
                        .is_some_and(|e| e.contains(error))
                },
            )
            .await
            .expect("noticed");
        if matches!(behaviour, Behaviour::Exception(_)) {
            assert_eq!(flaky["connected"], true, "an exception is an answer");
        } else {
            assert_eq!(
                (flaky["connected"].clone(), flaky["error_code"].clone()),
                (json!(false), json!(10))
            );
        }
        // The good device keeps updating while the other misbehaves.
        let (_, good) = gw.get("/api/v1/devices/good").await.expect("get");
        let before = counter_value(&good).expect("count");
        for _ in 0..3 {
            let good = gw
                .until("/api/v1/devices/good", "good updates", |b| {
                    counter_value(b) > Some(before)
                })
                .await
                .expect("good keeps updating");
            assert_eq!(good["connected"], true);
            assert_ne!(counter_value(&good), Some(0xBAD0));
            let (_, flaky) = gw.get("/api/v1/devices/flaky").await.expect("get");
            assert_ne!(
                counter_value(&flaky),
                Some(0xBAD0),
                "a late reply was taken: {flaky}"
            );
        }
        bus.slave(2, |s| s.behaviour = Behaviour::Normal);
        gw.until("/api/v1/devices/flaky", "flaky recovers", |b| {
            b["connected"] == true && b["fields"]["Count"]["quality"] == "good"
        })
        .await
        .expect("recovers");
    }
    let metrics = gw.metrics().await.expect("metrics");
    for needle in [
        "iogate_device_timeouts_total{device=\"flaky\"}",
        "iogate_device_crc_errors_total{device=\"flaky\"}",
        "outcome=\"invalid_response\"",
        "iogate_device_exceptions_total{device=\"flaky\",code=\"04\"}",
        "iogate_link_discarded_bytes_total{link=\"bus\"}",
        "iogate_link_planned_utilisation_ratio{link=\"bus\"}",
        "iogate_link_utilisation_ratio{link=\"bus\"}",
    ] {
        let line = metrics
            .lines()
            .find(|l| l.contains(needle))
            .unwrap_or_else(|| panic!("{needle} missing:\n{metrics}"));
        let n: f64 = line
            .rsplit(' ')
            .next()
            .and_then(|v| v.parse().ok())
            .unwrap_or(0.0);
        assert!(n > 0.0, "{line}");
    }
    assert!(
        !metrics.contains("device=\"good\",function=\"fc04\",outcome=\"timeout\""),
        "the good device never timed out"
    );
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn a_lost_port_is_reopened_and_the_latest_outputs_are_written_again() {
    let bus = RtuBus::default();
    bus.slave(1, |s| s.counter = Some(0));
    let (gw, pty, task, port) = bus_gateway(
        "reopen",
        &bus,
        &[("counter.yaml", COUNTER_PROFILE)],
        "  - { name: dev, profile: Counter, link: bus, slave_id: 1, refresh_rate: 20ms, timeout: 100ms }\n",
    )
    .await;
    gw.send(Method::PUT, "/api/v1/devices/dev/fields/Setpoint", "1234")
        .await
        .expect("put");
    eventually("setpoint written", || async {
        bus.read_slave(1, |s| s.tables.holding[0]) == Some(1234)
    })
    .await
    .expect("written");

    // Unplug: the device end goes away.
    task.abort();
    let _ = task.await;
    drop(pty);
    let link = gw
        .until("/api/v1/links/bus", "port lost", |b| {
            b["connected"] == false && b["error_code"] == 3
        })
        .await
        .expect("lost");
    assert_eq!(link["devices"], json!(["dev"]));
    gw.until("/api/v1/devices/dev", "device unreachable", |b| {
        b["connected"] == false && b["error_code"] == 10
    })
    .await
    .expect("unreachable");

    // Plug a new adapter in at the same path: a fresh device whose registers are all zero.
    let fresh = RtuBus::default();
    fresh.slave(1, |s| s.counter = Some(0));
    let (device_end, _holder) = pty_at(&port).expect("new pty");
    let task = fresh.serve(device_end);
    gw.until("/api/v1/links/bus", "link back", |b| {
        b["connected"] == true && b["error_code"] == 0
    })
    .await
    .expect("back");
    gw.until("/api/v1/devices/dev", "device back", |b| {
        b["connected"] == true && counter_value(b) > Some(0)
    })
    .await
    .expect("device back");
    eventually("setpoint written again", || async {
        fresh.read_slave(1, |s| s.tables.holding[0]) == Some(1234)
    })
    .await
    .expect("rewritten");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_link_reconnects_total{link=\"bus\"} 1"),
        "{metrics}"
    );
    gw.shutdown().await;
    task.abort();
}
