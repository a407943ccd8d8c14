//! Wireshark's IEC 104 dissector (tshark) as the judge of both sides' frames: what passed
//! between the driver and a c104 station, and between the outstation and a c104 master,
//! recorded by a proxy and read back from a capture file. Every APDU is decoded, none is
//! malformed, and tshark warns of nothing.

use iogate_tests::devices::{ModbusDevice, modbus_tcp_server, temp_dir};
use iogate_tests::iec104::{Master, Rtu};
use iogate_tests::wireshark::{Recorder, dissect, pcap};
use iogate_tests::{TestGateway, test_setup};
use serde_json::json;

/// The ASDU type identifications tshark decoded, each once.
fn types(decoded: &[String]) -> std::collections::BTreeSet<u8> {
    decoded
        .iter()
        .flat_map(|l| l.split(','))
        .filter_map(|t| t.trim().parse().ok())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_drivers_frames_with_a_c104_station_are_well_formed_to_wireshark() -> anyhow::Result<()>
{
    let mut rtu = Rtu::start().await?;
    let recorder = Recorder::to(rtu.port).await?;
    let dir = temp_dir("iec104-wireshark-driver");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/station.yaml"),
        iogate_tests::iec104::STATION_PROFILE,
    )?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: rtu\n    iec104: {{ host: 127.0.0.1, port: {}, clock_sync: true, t1: 3s, t2: 1s, t3: 5s }}\ndevices:\n  - {{ name: station, profile: Station, link: rtu, refresh_rate: 200ms }}\n",
        dir.join("profiles").display(),
        recorder.port,
    );
    let gw = TestGateway::start(&config).await?;
    gw.until("/api/v1/devices/station", "interrogated", |d| {
        d["fields"]["energy"]["quality"] == "good" && d["fields"]["flow"]["quality"] == "good"
    })
    .await?;
    rtu.cmd("set 102 20.25").await?;
    for (name, value) in [
        ("enable", json!(true)),
        ("limit", json!(-12)),
        ("setpoint", json!(2.5)),
    ] {
        let outcome = gw.write_outcome("station", name, value).await?;
        assert!(
            outcome.as_ref().is_ok_and(|o| o["status"] == "written"),
            "{name}: {outcome:?}"
        );
    }
    gw.shutdown().await;
    let verdict = dissect(
        &pcap(&recorder.conversations(), 2404),
        2404,
        "iec60870_104",
        "iec60870_asdu.typeid",
    )
    .await?;
    assert!(verdict.problems.is_empty(), "{:#?}", verdict.problems);
    let seen = types(&verdict.decoded);
    // The station's monitored types, and the driver's interrogations, clock and commands.
    for t in [30u8, 3, 13, 35, 9, 37, 5, 7, 36, 100, 101, 103, 45, 49, 50] {
        assert!(seen.contains(&t), "type {t} not decoded; decoded: {seen:?}");
    }
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_outstations_frames_with_a_c104_master_are_well_formed_to_wireshark()
-> anyhow::Result<()> {
    let device = ModbusDevice::default();
    let (port, _server) = modbus_tcp_server(device.clone()).await;
    let dir = temp_dir("iec104-wireshark-outstation");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/pump.yaml"),
        iogate_tests::iec104::PUMP_PROFILE,
    )?;
    let config = format!(
        "profiles: {}\nlinks:\n  - {{ name: line, tcp: {{ host: 127.0.0.1, port: {port} }} }}\ndevices:\n  - {{ name: pump, profile: Pump, link: line, slave_id: 1, refresh_rate: 100ms }}\niec104_server:\n  listen: 127.0.0.1:0\n",
        dir.join("profiles").display()
    );
    let setup = test_setup(&config)?;
    let map = setup
        .iec104_map(&dir)
        .expect("an outstation")
        .map_err(|p| anyhow::anyhow!("{p:?}"))?;
    let ioa = |point: &str| -> u32 {
        map.lines
            .lines()
            .find(|l| l.ends_with(point))
            .and_then(|l| l.split(' ').next()?.parse().ok())
            .unwrap_or_else(|| panic!("{point} in {}", map.lines))
    };
    let (speed, run) = (ioa("C_SE_NB_1 pump.speed"), ioa("C_SC_NA_1 pump.run"));
    let gw = TestGateway::start_setup(setup).await?;
    gw.until("/api/v1/devices/pump", "read", |d| {
        d["fields"]["temp"]["quality"] == "good"
    })
    .await?;
    let outstation = gw.iec104.expect("listening");
    let recorder = Recorder::to(outstation.port()).await?;
    let to = std::net::SocketAddr::from(([127, 0, 0, 1], recorder.port));
    let mut master = Master::connect(to).await?;
    let mut lines = Vec::new();
    for ask in [
        "gi".to_owned(),
        "ci".to_owned(),
        format!("cmd {speed} C_SE_NB_1 1234"),
        format!("cmd {run} C_SC_NA_1 1 select"),
        "mute".to_owned(),
        "unmute".to_owned(),
    ] {
        master.ask(&ask, &mut lines).await?;
    }
    // A change, sent spontaneously with its time tag.
    device.tables.lock().expect("tables").input[2] = 0x5A;
    let status = ioa("M_BO_NA_1 pump.status");
    while !lines
        .iter()
        .any(|l| l.starts_with(&format!("m {status} ")) && l.contains("SPONTANEOUS"))
    {
        lines.push(master.said().await?);
    }
    drop(master);
    gw.shutdown().await;
    let verdict = dissect(
        &pcap(&recorder.conversations(), 2404),
        2404,
        "iec60870_104",
        "iec60870_asdu.typeid",
    )
    .await?;
    assert!(verdict.problems.is_empty(), "{:#?}", verdict.problems);
    let seen = types(&verdict.decoded);
    // Interrogated points of each type, a bitstring with its time tag, the answers to
    // interrogations, the clock, commands.
    for t in [1u8, 11, 13, 7, 33, 100, 101, 103, 45, 49] {
        assert!(seen.contains(&t), "type {t} not decoded; decoded: {seen:?}");
    }
    Ok(())
}
