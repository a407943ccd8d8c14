//! One conformance suite every driver passes: the driver's independent peer (a Modbus TCP
//! device of tokio-modbus (and an RTU line of slaves, misbehaving by themselves), Snap7's S7 server, cpppo's Logix, asyncua's OPC UA server, c104's IEC 104 station) behind
//! a cable that makes it misbehave: silent, garbled headers, answers cut in half with the
//! connection closed, answers with junk after them, answers dripping a byte at a time. The
//! same device also on a second link straight to the peer. For every misbehaviour: the
//! gateway lives, the other link is read on, no value other than the peer's is ever `good`,
//! the field says why it is not, and once the peer behaves it is read again by itself, with
//! no connection left open on the peer but the one in use.
//!
//! A new driver is not done until it has its peer here. A datagram protocol's (BACnet/IP's)
//! cable relays datagrams: silent, garbled, cut in half, with junk after them, or twice.

use std::sync::{Arc, Mutex};

use iogate_tests::cable::{Cable, Mangle};
use iogate_tests::devices::{ModbusDevice, modbus_tcp_server, temp_dir};
use iogate_tests::{SseReader, TestGateway, eventually};
use serde_json::{Value, json};

/// A driver's peer as the suite uses it.
struct Peer {
    /// The port the peer listens on.
    port: u16,
    /// The link's settings (YAML, in a flow mapping) for the peer at a port.
    link: Box<dyn Fn(u16) -> String>,
    /// A device's extra keys (`slave_id: 1`).
    device: &'static str,
    /// The profile: one input field `N` whose value the peer holds and never changes.
    profile: String,
    /// That value.
    value: Value,
    /// What keeps the peer running.
    _running: Box<dyn std::any::Any>,
}

/// The gateway: device `dut` through the cable, `other` straight to the peer.
async fn gateway(name: &str, peer: &Peer, cable: &Cable) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/peer.yaml"), &peer.profile)?;
    let config = format!(
        "profiles: {}\nlinks:\n  - {{ name: hostile, {} }}\n  - {{ name: straight, {} }}\ndevices:\n  - {{ name: dut, profile: Peer, link: hostile, refresh_rate: 100ms{} }}\n  - {{ name: other, profile: Peer, link: straight, refresh_rate: 100ms{} }}\n",
        dir.join("profiles").display(),
        (peer.link)(cable.port),
        (peer.link)(peer.port),
        peer.device,
        peer.device,
    );
    TestGateway::start(&config.replace("PKI", &dir.join("pki").display().to_string())).await
}

fn n(device: &Value) -> &Value {
    &device["fields"]["N"]
}

/// Runs the suite against `peer`.
async fn conformance(name: &str, peer: Peer) -> anyhow::Result<()> {
    let cable = Cable::to(peer.port).await?;
    let gw = gateway(name, &peer, &cable).await?;
    let want = peer.value.clone();
    for device in ["dut", "other"] {
        gw.until(&format!("/api/v1/devices/{device}"), "read", |d| {
            n(d)["value"] == want && n(d)["quality"] == "good"
        })
        .await?;
    }
    // Every value event of the device behind the cable, from now on.
    let mut sse = SseReader::open(&gw, "/api/v1/events?device=dut").await?;
    let wrong: Arc<Mutex<Vec<Value>>> = Arc::default();
    let (seen, expected) = (wrong.clone(), want.clone());
    let watcher = tokio::spawn(async move {
        while let Ok(Some((event, v))) = sse.next().await {
            if event == "value" && v["quality"] == "good" && v["value"] != expected {
                seen.lock().expect("lock").push(v);
            }
        }
    });
    for m in [
        Mangle::Silent,
        Mangle::Garble,
        Mangle::Truncate,
        Mangle::Oversize,
        Mangle::Drip,
    ] {
        let (_, before) = gw.get("/api/v1/devices/other").await?;
        let cycles = before["io_cycles"].as_u64().unwrap_or(0);
        let from = cable.mangled();
        cable.mangle(m);
        eventually(&format!("{m:?}: answers mangled"), || async {
            cable.mangled() >= from + 3
        })
        .await?;
        // The device behind the cable is not good unless its value is the peer's; when it
        // is not good, its error says why.
        let (_, dut) = gw.get("/api/v1/devices/dut").await?;
        if n(&dut)["quality"] != "good" {
            assert!(n(&dut)["error"].is_string(), "{m:?}: {dut}");
        }
        // The other link was read on meanwhile.
        let (_, other) = gw.get("/api/v1/devices/other").await?;
        assert!(
            other["io_cycles"].as_u64().unwrap_or(0) > cycles && n(&other)["value"] == want,
            "{m:?}: {other}"
        );
        cable.mangle(Mangle::Pass);
        gw.until("/api/v1/devices/dut", "read again", |d| {
            n(d)["value"] == want && n(d)["quality"] == "good"
        })
        .await
        .map_err(|e| anyhow::anyhow!("{m:?}: {e}"))?;
    }
    eventually("one connection left on the peer", || async {
        cable.open() <= 1
    })
    .await?;
    watcher.abort();
    let wrong = wrong.lock().expect("lock").clone();
    assert!(
        wrong.is_empty(),
        "a value not the peer's served good: {wrong:?}"
    );
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn modbus_tcp_keeps_the_rules_of_a_guest() -> anyhow::Result<()> {
    let device = ModbusDevice::default();
    device
        .tables
        .lock()
        .map_err(|_| anyhow::anyhow!("poisoned"))?
        .input[0] = 1234;
    let (port, server) = modbus_tcp_server(device).await;
    conformance(
        "conformance-modbus",
        Peer {
            port,
            link: Box::new(|p| format!("tcp: {{ host: 127.0.0.1, port: {p} }}")),
            device: ", slave_id: 1, timeout: 500ms",
            profile: "name: Peer\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n".into(),
            value: json!(1234),
            _running: Box::new(AbortOnDrop(server)),
        },
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn s7_keeps_the_rules_of_a_guest() -> anyhow::Result<()> {
    let plc = iogate_tests::s7::S7Plc::start(None).await?;
    conformance(
        "conformance-s7",
        Peer {
            port: plc.port,
            link: Box::new(|p| format!("s7: {{ host: 127.0.0.1, port: {p}, timeout: 1s }}")),
            device: "",
            profile: "name: Peer\nprotocol: s7\nfields:\n  - { name: N, type: INT, direction: input, address: MW10 }\n".into(),
            value: json!(1234),
            _running: Box::new(plc),
        },
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn iec104_keeps_the_rules_of_a_guest() -> anyhow::Result<()> {
    // c104's station answers the interrogation every second and test frames after t3.
    let rtu = iogate_tests::iec104::Rtu::start().await?;
    conformance(
        "conformance-iec104",
        Peer {
            port: rtu.port,
            link: Box::new(|p| {
                format!("iec104: {{ host: 127.0.0.1, port: {p}, t0: 2s, t1: 1s, t2: 500ms, t3: 1s, interrogation: 1s }}")
            }),
            device: "",
            profile: "name: Peer\nprotocol: iec104\nfields:\n  - { name: N, type: REAL, direction: input, ioa: 102 }\n".into(),
            value: json!(12.5),
            _running: Box::new(rtu),
        },
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ethernet_ip_keeps_the_rules_of_a_guest() -> anyhow::Result<()> {
    let plc = iogate_tests::eip::LogixPlc::start(None, &["Count=DINT"]).await?;
    let wrote = plc.write(&["Count=1234"]).await?;
    anyhow::ensure!(wrote["Count"] == "Success", "{wrote}");
    conformance(
        "conformance-eip",
        Peer {
            port: plc.port,
            link: Box::new(|p| {
                format!("eip: {{ host: 127.0.0.1, port: {p}, path: \"1,0\", timeout: 1s }}")
            }),
            device: "",
            profile: "name: Peer\nprotocol: ab-eip\nfields:\n  - { name: N, type: DINT, direction: input, tag: Count }\n".into(),
            value: json!(1234),
            _running: Box::new(plc),
        },
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn opc_ua_keeps_the_rules_of_a_guest() -> anyhow::Result<()> {
    let plc = iogate_tests::plc::UaPlc::start(&[]).await?;
    let port: u16 = plc.port().parse()?;
    let ns = plc.ns;
    conformance(
        "conformance-opcua",
        Peer {
            port,
            link: Box::new(|p| {
                format!("opcua: {{ url: \"opc.tcp://127.0.0.1:{p}/plc\", pki_dir: PKI }}")
            }),
            device: "",
            profile: format!(
                "name: Peer\nprotocol: opcua\nfields:\n  - {{ name: N, type: INT, direction: input, node: \"ns={ns};s=Line1.Int\" }}\n"
            ),
            value: json!(-300),
            _running: Box::new(plc),
        },
    )
    .await
}

/// Modbus RTU: the line is the cable. Slave 1 misbehaves (silent, a bad CRC, one register
/// too few, an answer of other values after the timeout); slave 2 on the same line is read
/// on, and slave 1 is never `good` with another value than its own.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn modbus_rtu_keeps_the_rules_of_a_guest() -> anyhow::Result<()> {
    use iogate_tests::devices::{Behaviour, RtuBus};
    let bus = RtuBus::default();
    for id in [1, 2] {
        bus.slave(id, |s| s.tables.input[0] = 1234);
    }
    let profile = "name: Peer\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n";
    let (gw, _pty, task, _) = iogate_tests::bus_gateway(
        "conformance-rtu",
        &bus,
        &[("peer.yaml", profile)],
        "  - { name: dut, profile: Peer, link: bus, slave_id: 1, refresh_rate: 50ms, timeout: 100ms }\n  - { name: other, profile: Peer, link: bus, slave_id: 2, refresh_rate: 50ms, timeout: 100ms }\n",
    )
    .await;
    for device in ["dut", "other"] {
        gw.until(&format!("/api/v1/devices/{device}"), "read", |d| {
            n(d)["value"] == 1234 && n(d)["quality"] == "good"
        })
        .await?;
    }
    let mut sse = SseReader::open(&gw, "/api/v1/events?device=dut").await?;
    let wrong: Arc<Mutex<Vec<Value>>> = Arc::default();
    let seen = wrong.clone();
    let watcher = tokio::spawn(async move {
        while let Ok(Some((event, v))) = sse.next().await {
            if event == "value" && v["quality"] == "good" && v["value"] != 1234 {
                seen.lock().expect("lock").push(v);
            }
        }
    });
    for behaviour in [
        Behaviour::Silent,
        Behaviour::BadCrc,
        Behaviour::WrongLength,
        // Past the timeout, within twice it: after a timeout the next request to the slave
        // waits for the late answer that long (RTU has no transaction ids: an answer later
        // still is indistinguishable from the next one's, docs/devices.md).
        Behaviour::Late(std::time::Duration::from_millis(150)),
    ] {
        bus.slave(1, |s| s.behaviour = behaviour.clone());
        let dut = gw
            .until("/api/v1/devices/dut", "not good", |d| {
                n(d)["quality"] != "good"
            })
            .await?;
        assert!(n(&dut)["error"].is_string(), "{behaviour:?}: {dut}");
        let (_, before) = gw.get("/api/v1/devices/other").await?;
        let cycles = before["io_cycles"].as_u64().unwrap_or(0);
        gw.until("/api/v1/devices/other", "read on", |d| {
            d["io_cycles"].as_u64().unwrap_or(0) > cycles + 3 && n(d)["value"] == 1234
        })
        .await?;
        bus.slave(1, |s| s.behaviour = Behaviour::Normal);
        gw.until("/api/v1/devices/dut", "read again", |d| {
            n(d)["value"] == 1234 && n(d)["quality"] == "good"
        })
        .await
        .map_err(|e| anyhow::anyhow!("{behaviour:?}: {e}"))?;
    }
    watcher.abort();
    let wrong = wrong.lock().expect("lock").clone();
    assert!(
        wrong.is_empty(),
        "a value not the slave's served good: {wrong:?}"
    );
    gw.shutdown().await;
    task.abort();
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bacnet_keeps_the_rules_of_a_guest() -> anyhow::Result<()> {
    use iogate_tests::udp_cable::{Mangle, UdpCable};
    let device = iogate_tests::bacnet::BacnetDevice::start(2001).await?;
    let cable = UdpCable::to(device.port).await?;
    let dir = temp_dir("conformance-bacnet");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/peer.yaml"),
        "name: Peer\nprotocol: bacnet\nfields:\n  - { name: N, type: REAL, direction: input, object: \"analog-input:1\" }\n",
    )?;
    let free = || std::net::UdpSocket::bind("127.0.0.1:0").and_then(|s| s.local_addr());
    let (a, b) = (free()?, free()?);
    let config = format!(
        "profiles: {}\nlinks:\n  - {{ name: hostile, bacnet: {{ bind: \"{a}\", timeout: 300ms, retries: 1 }} }}\n  - {{ name: straight, bacnet: {{ bind: \"{b}\", timeout: 300ms, retries: 1 }} }}\ndevices:\n  - {{ name: dut, profile: Peer, link: hostile, device_instance: 2001, address: \"127.0.0.1:{}\", refresh_rate: 100ms }}\n  - {{ name: other, profile: Peer, link: straight, device_instance: 2001, address: \"127.0.0.1:{}\", refresh_rate: 100ms }}\n",
        dir.join("profiles").display(),
        cable.port,
        device.port,
    );
    let gw = TestGateway::start(&config).await?;
    let want = json!(21.5);
    for d in ["dut", "other"] {
        gw.until(&format!("/api/v1/devices/{d}"), "read", |v| {
            n(v)["value"] == want && n(v)["quality"] == "good"
        })
        .await?;
    }
    let mut sse = SseReader::open(&gw, "/api/v1/events?device=dut").await?;
    let wrong: Arc<Mutex<Vec<Value>>> = Arc::default();
    let (seen, expected) = (wrong.clone(), want.clone());
    let watcher = tokio::spawn(async move {
        while let Ok(Some((event, v))) = sse.next().await {
            if event == "value" && v["quality"] == "good" && v["value"] != expected {
                seen.lock().expect("lock").push(v);
            }
        }
    });
    for m in [
        Mangle::Silent,
        Mangle::Garble,
        Mangle::Truncate,
        Mangle::Oversize,
        Mangle::Twice,
    ] {
        let (_, before) = gw.get("/api/v1/devices/other").await?;
        let cycles = before["io_cycles"].as_u64().unwrap_or(0);
        let from = cable.mangled();
        cable.mangle(m);
        eventually(&format!("{m:?}: answers mangled"), || async {
            cable.mangled() >= from + 3
        })
        .await?;
        let (_, dut) = gw.get("/api/v1/devices/dut").await?;
        if n(&dut)["quality"] != "good" {
            assert!(n(&dut)["error"].is_string(), "{m:?}: {dut}");
        }
        gw.until("/api/v1/devices/other", "read on", |d| {
            d["io_cycles"].as_u64().unwrap_or(0) > cycles && n(d)["value"] == want
        })
        .await
        .map_err(|e| anyhow::anyhow!("{m:?}: {e}"))?;
        cable.mangle(Mangle::Pass);
        gw.until("/api/v1/devices/dut", "read again", |d| {
            n(d)["value"] == want && n(d)["quality"] == "good"
        })
        .await
        .map_err(|e| anyhow::anyhow!("{m:?}: {e}"))?;
    }
    watcher.abort();
    let wrong = wrong.lock().expect("lock").clone();
    assert!(
        wrong.is_empty(),
        "a value not the device's served good: {wrong:?}"
    );
    gw.shutdown().await;
    device.kill().await?;
    Ok(())
}

/// Stops a task when dropped.
struct AbortOnDrop(tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}
