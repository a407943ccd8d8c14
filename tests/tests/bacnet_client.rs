//! The BACnet driver against an independent BACnet/IP device (bacpypes3,
//! `tests/bacnet/device.py`): analog, binary and multi-state inputs, outputs and values read
//! with their status flags, writes at a field's priority checked on the device, a fault
//! flagged by the device never shown as a good value, a device that is not there silent,
//! and configuration problems named at their lines.

use iogate_tests::TestGateway;
use iogate_tests::bacnet::BacnetDevice;
use iogate_tests::devices::temp_dir;
use serde_json::{Value, json};

const PROFILE: &str = r#"name: Ahu
protocol: bacnet
fields:
  - { name: Temp, type: REAL, direction: input, object: "analog-input:1", unit: degC }
  - { name: TempUnits, type: UINT, direction: input, object: "analog-input:1", property: units }
  - { name: TempFlags, type: BYTE, direction: input, object: "analog-input:1", property: status-flags }
  - { name: TempReliability, type: UINT, direction: input, object: "analog-input:1", property: reliability }
  - { name: Valve, type: REAL, direction: inout, object: "analog-output:1", priority: 8 }
  - { name: Setpoint, type: REAL, direction: inout, object: "analog-value:1" }
  - { name: Alarm, type: BOOL, direction: input, object: "binary-input:1" }
  - { name: Fan, type: BOOL, direction: inout, object: "binary-output:1" }
  - { name: Enable, type: BOOL, direction: inout, object: "binary-value:1" }
  - { name: Mode, type: UINT, direction: input, object: "multi-state-input:1" }
  - { name: Speed, type: UINT, direction: inout, object: "multi-state-output:1" }
  - { name: Season, type: UINT, direction: input, object: "multi-state-value:1" }
  - { name: Nothing, type: REAL, direction: input, object: "analog-input:99" }
"#;

/// A gateway with the device on a BACnet link bound to a free port of 127.0.0.1, and a
/// second device (instance 77) that does not exist.
async fn gateway(name: &str, device: &BacnetDevice) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/ahu.yaml"), PROFILE)?;
    let bind = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let bind2 = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: bms\n    bacnet: {{ bind: \"{bind}\", timeout: 500ms, retries: 1 }}\n  - name: slow\n    bacnet: {{ bind: \"{bind2}\" }}\ndevices:\n  - {{ name: ahu, profile: Ahu, link: bms, device_instance: {}, address: \"127.0.0.1:{}\", refresh_rate: 200ms }}\n  - {{ name: ghost, profile: Ahu, link: bms, device_instance: 77, address: \"127.0.0.1:9\", refresh_rate: 200ms, cov: false }}\n  - {{ name: watcher, profile: Ahu, link: slow, device_instance: {1}, address: \"127.0.0.1:{2}\", refresh_rate: 1h }}\n",
        dir.join("profiles").display(),
        device.instance,
        device.port,
    );
    TestGateway::start(&config).await
}

fn field<'a>(device: &'a Value, name: &str) -> &'a Value {
    &device["fields"][name]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_object_kind_is_read_and_written_as_the_device_holds_it() -> anyhow::Result<()> {
    let mut device = BacnetDevice::start(1001).await?;
    let gw = gateway("bacnet-values", &device).await?;
    let d = gw
        .until("/api/v1/devices/ahu", "read", |d| {
            [
                "Temp",
                "TempUnits",
                "TempFlags",
                "TempReliability",
                "Valve",
                "Mode",
                "Season",
            ]
            .iter()
            .all(|f| field(d, f)["quality"] == "good")
        })
        .await?;
    let v = |n: &str| field(&d, n)["value"].clone();
    assert_eq!(v("Temp"), json!(21.5));
    assert_eq!(v("TempUnits"), json!(62), "degrees-Celsius is 62");
    assert_eq!(v("TempFlags"), json!(0), "no status flag set");
    assert_eq!(v("TempReliability"), json!(0), "no-fault-detected is 0");
    assert_eq!(v("Valve"), json!(0.0));
    assert_eq!(v("Setpoint"), json!(20.0));
    assert_eq!(v("Alarm"), json!(false));
    assert_eq!(v("Fan"), json!(false));
    assert_eq!(v("Enable"), json!(true));
    assert_eq!(v("Mode"), json!(2));
    assert_eq!(v("Speed"), json!(1));
    assert_eq!(v("Season"), json!(1));
    // An object the device does not have is that field's error; the others stay good.
    let nothing = field(&d, "Nothing");
    assert_eq!(nothing["quality"], "bad", "{nothing}");
    assert!(
        nothing["error"]
            .as_str()
            .unwrap_or_default()
            .contains("unknown-object")
            || nothing["error"]
                .as_str()
                .unwrap_or_default()
                .contains("UNKNOWN_OBJECT"),
        "{nothing}"
    );

    // A change on the device is seen: by a device read every 200 ms, and by one read once
    // an hour, through its change-of-value subscription.
    gw.until("/api/v1/devices/watcher", "first read", |d| {
        field(d, "Temp")["value"] == json!(21.5)
    })
    .await?;
    device.cmd("set analog-input,1 23.25").await?;
    for name in ["ahu", "watcher"] {
        gw.until(&format!("/api/v1/devices/{name}"), "the change", |d| {
            field(d, "Temp")["value"] == json!(23.25) && field(d, "Temp")["quality"] == "good"
        })
        .await?;
    }

    // Writes reach the device, at the field's priority (8) or the lowest (16).
    for (name, value) in [
        ("Valve", json!(42.5)),
        ("Setpoint", json!(21.0)),
        ("Fan", json!(true)),
        ("Enable", json!(false)),
        ("Speed", json!(3)),
    ] {
        let outcome = gw
            .write_outcome("ahu", name, value.clone())
            .await?
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        assert_eq!(outcome["status"], "written", "{name}: {outcome}");
    }
    assert_eq!(device.get("analog-output,1", "presentValue").await?, "42.5");
    // The valve at its field's priority 8, nothing at 16; the setpoint at 16.
    assert_eq!(device.cmd("priority analog-output,1 8").await?, "42.5");
    assert_eq!(device.cmd("priority analog-output,1 16").await?, "null");
    assert_eq!(device.cmd("priority analog-value,1 16").await?, "21.0");
    assert_eq!(device.get("analog-value,1", "presentValue").await?, "21.0");
    assert_eq!(
        device.get("binary-output,1", "presentValue").await?,
        "active"
    );
    assert_eq!(
        device.get("binary-value,1", "presentValue").await?,
        "inactive"
    );
    assert_eq!(
        device.get("multi-state-output,1", "presentValue").await?,
        "3"
    );

    // A relinquish (null) clears the gateway's priority only: the valve goes back to its
    // relinquish default, and what the gateway reads of it follows.
    let outcome = gw
        .write_outcome("ahu", "Valve", json!(null))
        .await?
        .map_err(|e| anyhow::anyhow!("relinquish: {e}"))?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    assert_eq!(outcome["value"], json!(null), "{outcome}");
    assert_eq!(device.cmd("priority analog-output,1 8").await?, "null");
    assert_eq!(device.get("analog-output,1", "presentValue").await?, "0.0");
    gw.until("/api/v1/devices/ahu", "the relinquish default", |d| {
        field(d, "Valve")["value"] == json!(0.0)
    })
    .await?;
    // An input has nothing to relinquish: refused, and nothing is sent.
    let input = gw.write_outcome("ahu", "Temp", json!(null)).await?;
    assert!(
        input.as_ref().is_err_and(|e| e.starts_with("409")),
        "{input:?}"
    );

    // A value the object cannot take is refused before it is sent.
    let refused = gw.write_outcome("ahu", "Speed", json!(0)).await?;
    let why = match refused {
        Err(e) => e,
        Ok(o) => o["error"].as_str().unwrap_or_default().to_owned(),
    };
    assert!(why.contains("multi-state"), "{why}");
    assert_eq!(
        device.get("multi-state-output,1", "presentValue").await?,
        "3"
    );

    // A fault the device flags is never a good value.
    device.cmd("flags analog-input,1 FAULT").await?;
    let d = gw
        .until("/api/v1/devices/ahu", "the fault", |d| {
            field(d, "Temp")["quality"] != "good"
        })
        .await?;
    let temp = field(&d, "Temp");
    assert!(
        temp["error"].as_str().unwrap_or_default().contains("fault"),
        "{temp}"
    );
    // The flags and the reliability themselves are values, read as the device holds them:
    // the fault flag (bit 1), unreliable-other (7).
    let d = gw
        .until("/api/v1/devices/ahu", "the flags read", |d| {
            field(d, "TempFlags")["value"] == json!(2)
        })
        .await?;
    assert_eq!(field(&d, "TempFlags")["quality"], "good");
    assert_eq!(field(&d, "TempReliability")["value"], json!(7));
    device.cmd("flags analog-input,1 OK").await?;
    gw.until("/api/v1/devices/ahu", "good again", |d| {
        field(d, "Temp")["quality"] == "good"
    })
    .await?;

    // The device that is not there is disconnected, and the link still reads the other.
    let ghost = gw
        .until("/api/v1/devices/ghost", "silent", |d| {
            d["connected"] == false
        })
        .await?;
    assert_eq!(ghost["error_code"], 10, "{ghost}");
    let (_, plan) = (
        200,
        reqwest::get(gw.url("/api/v1/links/bms/plan"))
            .await?
            .text()
            .await?,
    );
    assert!(plan.contains("link bms: bacnet"), "{plan}");
    device.kill().await?;
    Ok(())
}

#[test]
fn bacnet_settings_and_devices_are_checked_with_their_lines() -> anyhow::Result<()> {
    let dir = temp_dir("bacnet-check");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/ahu.yaml"), PROFILE)?;
    std::fs::write(
        dir.join("profiles/bad.yaml"),
        "name: Bad\nprotocol: bacnet\nfields:\n  - { name: A, type: REAL, direction: input, object: \"analog-inptu:1\" }\n  - { name: B, type: REAL, direction: input, object: \"analog-input:1\", property: present-valu }\n  - { name: C, type: REAL, direction: inout, object: \"analog-output:1\", priority: 17 }\n",
    )?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: bms\n    bacnet: {{ bind: \"plant:47808\", timeout: 0s }}\n  - name: b1\n    bacnet: {{ bind: 127.0.0.1:47808 }}\n  - name: b2\n    bacnet: {{ bind: 127.0.0.2 }}\ndevices:\n  - {{ name: a, profile: Ahu, link: bms }}\n  - {{ name: b, profile: Ahu, link: bms, device_instance: 4194303 }}\n  - {{ name: c, profile: Ahu, link: bms, device_instance: 5, cov: maybe }}\n  - {{ name: d, profile: Ahu, link: b1, device_instance: 9 }}\n  - {{ name: e, profile: Ahu, link: b1, device_instance: 9, address: \"127.0.0.1:0\" }}\n  - {{ name: f, profile: Ahu, link: b1, device_instance: 10, address: \"255.255.255.255:47808\" }}\n",
        dir.join("profiles").display()
    );
    let path = dir.join("iogate.yaml");
    std::fs::write(&path, config)?;
    let text = match iogate::app::Setup::from_file(&path) {
        Ok(_) => String::from("no problem found"),
        Err(problems) => problems.to_string(),
    };
    for expected in [
        "bad.yaml:4",
        "`analog-inptu` is not a BACnet object type",
        "bad.yaml:5",
        "`present-valu` is not a BACnet property",
        "bad.yaml:6",
        "`17` is not a write priority",
        "bacnet.bind",
        "not an IPv4 address",
        "bacnet.timeout",
        "device a",
        "needs its `device_instance`",
        "`4194303` is not a device instance",
        "`cov: maybe`: true or false",
        "link b2: link b1 takes UDP port 47808 already",
        "device e: device d on link b1 has device_instance 9 already",
        "needs its port (not 0)",
        "255.255.255.255 is not: a device is asked by unicast",
    ] {
        assert!(text.contains(expected), "{expected}: {text}");
    }
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_devices_object_list_becomes_its_profile_and_the_profile_reads() -> anyhow::Result<()> {
    let device = BacnetDevice::start(1003).await?;
    let dir = temp_dir("bacnet-import");
    let out = dir.join("profiles");
    let target = format!("127.0.0.1:{}", device.port);
    let (t, o) = (target.clone(), out.clone());
    let code = tokio::task::spawn_blocking(move || {
        iogate::drivers::bacnet::import::run(&t, &[], Some(&o))
    })
    .await?;
    assert_eq!(code, 0);
    let name = "BACnet_TestDevice_1003";
    let text = std::fs::read_to_string(out.join(format!("{name}.yaml")))?;
    for line in [
        "protocol: bacnet",
        "{ name: Temperature, type: REAL, direction: input, object: \"analog-input:1\", unit: \"degrees-celsius\" }",
        "{ name: Valve, type: REAL, direction: inout, object: \"analog-output:1\", unit: \"percent\" }",
        "{ name: Fan, type: BOOL, direction: inout, object: \"binary-output:1\" }",
        "{ name: Mode, type: UINT, direction: input, object: \"multi-state-input:1\" }",
    ] {
        assert!(text.contains(line), "{line}:\n{text}");
    }
    // The profile made reads the device.
    let bind = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: bms\n    bacnet: {{ bind: \"{bind}\" }}\ndevices:\n  - {{ name: d, profile: {name}, link: bms, device_instance: 1003, address: \"{target}\", refresh_rate: 200ms }}\n",
        out.display()
    );
    let gw = TestGateway::start(&config).await?;
    let d = gw
        .until("/api/v1/devices/d", "read", |d| {
            field(d, "Temperature")["quality"] == "good" && field(d, "Season")["quality"] == "good"
        })
        .await?;
    assert_eq!(field(&d, "Temperature")["value"], json!(21.5));
    device.kill().await?;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn devices_behind_a_router_are_found_by_who_is_and_are_separate_devices() -> anyhow::Result<()>
{
    use iogate_tests::bacnet::BacnetRouter;
    let count = 100;
    let port = std::net::UdpSocket::bind("127.0.0.2:0")?
        .local_addr()?
        .port();
    let mut router = BacnetRouter::start("127.0.0.2", port, 3000, count).await?;
    let dir = temp_dir("bacnet-router");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(
        dir.join("profiles/vav.yaml"),
        "name: Vav\nprotocol: bacnet\nfields:\n  - { name: Flow, type: REAL, direction: input, object: \"analog-input:1\" }\n  - { name: Setpoint, type: REAL, direction: inout, object: \"analog-value:1\" }\n",
    )?;
    // The gateway on another address, a foreign device of the router's BBMD: its Who-Is
    // goes out through the BBMD, the I-Ams come back routed.
    let bind = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let mut config = format!(
        "profiles: {}\nlinks:\n  - name: bms\n    bacnet: {{ bind: \"{bind}\", bbmd: \"127.0.0.2:{port}\", foreign_ttl: 30s, timeout: 1s, retries: 1 }}\ndevices:\n",
        dir.join("profiles").display()
    );
    for k in 1..=count {
        config.push_str(&format!(
            "  - {{ name: vav{k}, profile: Vav, link: bms, device_instance: {}, refresh_rate: 1s }}\n",
            3000 + k
        ));
    }
    let gw = TestGateway::start(&config).await?;
    // Every device is its own: its own value, through the router.
    for k in 1..=count {
        gw.until(&format!("/api/v1/devices/vav{k}"), "read", |d| {
            field(d, "Flow")["value"] == json!(k as f64) && field(d, "Flow")["quality"] == "good"
        })
        .await?;
    }
    // A write reaches the one device it is for.
    let outcome = gw
        .write_outcome("vav7", "Setpoint", json!(23.5))
        .await?
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    assert_eq!(
        router.cmd("get 3007 analog-value,1 presentValue").await?,
        "23.5"
    );
    assert_eq!(
        router.cmd("get 3008 analog-value,1 presentValue").await?,
        "20.0"
    );
    // A change behind the router comes through.
    router.cmd("set 3042 analog-input,1 4.25").await?;
    gw.until("/api/v1/devices/vav42", "the change", |d| {
        field(d, "Flow")["value"] == json!(4.25)
    })
    .await?;
    let (_, v41) = gw.get("/api/v1/devices/vav41").await?;
    assert_eq!(field(&v41, "Flow")["value"], json!(41.0), "{v41}");

    // A scan finds the router and every device behind it, each by its network and MAC.
    let on = std::net::UdpSocket::bind("127.0.0.1:0")?
        .local_addr()?
        .to_string();
    let bbmd = format!("127.0.0.2:{port}");
    let found = tokio::task::spawn_blocking(move || {
        iogate::drivers::bacnet::scan::find(&[("--on", &on), ("--bbmd", &bbmd), ("--wait", "3s")])
    })
    .await?
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    let found: Value = serde_json::from_str(&found)?;
    let devices = found["devices"].as_array().cloned().unwrap_or_default();
    assert_eq!(devices.len(), count + 1, "{found}");
    let vav7 = devices
        .iter()
        .find(|d| d["device_instance"] == 3007)
        .ok_or_else(|| anyhow::anyhow!("3007 not found: {found}"))?;
    assert_eq!(vav7["network"], 2, "{vav7}");
    assert_eq!(vav7["mac"], "08", "{vav7}");
    assert!(vav7["address"].is_null(), "{vav7}");

    // A device behind the router imported by its instance alone.
    let out = dir.join("imported");
    let (on, bbmd) = (
        std::net::UdpSocket::bind("127.0.0.1:0")?
            .local_addr()?
            .to_string(),
        format!("127.0.0.2:{port}"),
    );
    let o = out.clone();
    let code = tokio::task::spawn_blocking(move || {
        iogate::drivers::bacnet::import::run("3007", &[("--on", &on), ("--bbmd", &bbmd)], Some(&o))
    })
    .await?;
    assert_eq!(code, 0);
    let text = std::fs::read_to_string(out.join("BACnet_Vav7_3007.yaml"))?;
    assert!(
        text.contains("{ name: Flow, type: REAL, direction: input, object: \"analog-input:1\", unit: \"liters-per-second\" }"),
        "{text}"
    );
    Ok(())
}

/// An UnconfirmedCOVNotification as the standard encodes it (BVLC, NPDU, APDU): subscriber
/// process `pid`, from device `instance`, analog-input:1's present value `value` and its
/// status flags all clear.
fn notification(pid: u8, instance: u32, value: f32) -> Vec<u8> {
    let object = |kind: u32, n: u32| ((kind << 22) | n).to_be_bytes();
    let mut apdu = vec![0x10, 0x02, 0x09, pid, 0x1C];
    apdu.extend(object(8, instance));
    apdu.push(0x2C);
    apdu.extend(object(0, 1));
    apdu.extend([0x39, 0x78, 0x4E, 0x09, 0x55, 0x2E, 0x44]);
    apdu.extend(value.to_be_bytes());
    apdu.extend([0x2F, 0x09, 0x6F, 0x2E, 0x82, 0x04, 0x00, 0x2F, 0x4F]);
    let mut out = vec![0x81, 0x0A, 0, 0, 0x01, 0x00];
    out.extend(apdu);
    let len = (out.len() as u16).to_be_bytes();
    out[2..4].copy_from_slice(&len);
    out
}

/// The same notification in a Forwarded-NPDU (BVLC 0x04) that names `origin` as the host
/// it comes from, as a BBMD forwards a broadcast.
fn forwarded(pid: u8, instance: u32, value: f32, origin: std::net::SocketAddrV4) -> Vec<u8> {
    let original = notification(pid, instance, value);
    let mut out = vec![0x81, 0x04, 0, 0];
    out.extend(origin.ip().octets());
    out.extend(origin.port().to_be_bytes());
    out.extend(&original[4..]);
    let len = (out.len() as u16).to_be_bytes();
    out[2..4].copy_from_slice(&len);
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_notification_from_another_address_is_never_a_value() -> anyhow::Result<()> {
    let device = BacnetDevice::start(1005).await?;
    let dir = temp_dir("bacnet-spoof");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/ahu.yaml"), PROFILE)?;
    let bind = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: bms\n    bacnet: {{ bind: \"{bind}\" }}\ndevices:\n  - {{ name: ahu, profile: Ahu, link: bms, device_instance: 1005, address: \"127.0.0.1:{}\", refresh_rate: 1h }}\n",
        dir.join("profiles").display(),
        device.port
    );
    let gw = TestGateway::start(&config).await?;
    gw.until("/api/v1/devices/ahu", "read", |d| {
        field(d, "Temp")["value"] == json!(21.5) && field(d, "Temp")["quality"] == "good"
    })
    .await?;
    let mut sse = iogate_tests::SseReader::open(&gw, "/api/v1/events?device=ahu").await?;
    // Notifications for every subscriber process a gateway could have given, from an
    // address that is not the device's: none is taken.
    // Nor as a Forwarded-NPDU sent to the gateway alone that names the device's own address
    // as its origin (only a foreign device's BBMD sends those).
    let spoofer = std::net::UdpSocket::bind("127.0.0.2:0")?;
    let origin = std::net::SocketAddrV4::new(std::net::Ipv4Addr::LOCALHOST, device.port);
    for pid in 1..=200u8 {
        spoofer.send_to(&notification(pid, 1005, 99.5), bind)?;
        spoofer.send_to(&forwarded(pid, 1005, 99.5, origin), bind)?;
    }
    let seen = tokio::time::timeout(std::time::Duration::from_secs(2), async {
        while let Ok(Some((event, v))) = sse.next().await {
            if event == "value" && v["value"] == json!(99.5) {
                return Some(v);
            }
        }
        None
    })
    .await
    .ok()
    .flatten();
    assert!(seen.is_none(), "a spoofed notification was taken: {seen:?}");
    let (_, d) = gw.get("/api/v1/devices/ahu").await?;
    assert_eq!(field(&d, "Temp")["value"], json!(21.5), "{d}");
    device.kill().await?;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reload_replaces_the_devices_subscriptions_and_never_adds_to_them() -> anyhow::Result<()>
{
    let mut device = BacnetDevice::start(1006).await?;
    let bind = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let port = device.port;
    let config = |refresh: &str| {
        format!(
            "profiles: profiles\nlinks:\n  - name: bms\n    bacnet: {{ bind: \"{bind}\" }}\ndevices:\n  - {{ name: ahu, profile: Ahu, link: bms, device_instance: 1006, address: \"127.0.0.1:{}\", refresh_rate: {refresh} }}\n",
            port
        )
    };
    let (_, path) =
        iogate_tests::config_files("bacnet-reload", &[("ahu.yaml", PROFILE)], &config("200ms"));
    let gw = iogate_tests::start_file(&path).await;
    // Each object whose present value is read is subscribed once the device answers its
    // first read: by its third, all are.
    let read = |ms: u64| {
        move |d: &Value| {
            d["refresh_rate_ms"] == json!(ms) && d["io_cycles"].as_u64().is_some_and(|n| n >= 3)
        }
    };
    gw.until("/api/v1/devices/ahu", "read", read(200)).await?;
    let held = device.cmd("subscriptions").await?;
    assert_ne!(held, "0");
    for refresh in ["300ms", "400ms", "250ms"] {
        std::fs::write(&path, config(refresh))?;
        let (status, answer) = gw
            .send(reqwest::Method::POST, "/api/v1/config/reload", "")
            .await?;
        assert_eq!(status, 200, "{answer}");
        let ms = refresh.trim_end_matches("ms").parse()?;
        gw.until("/api/v1/devices/ahu", "read again", read(ms))
            .await?;
    }
    // Each plan subscribed under the same subscriber process: the device holds what it held.
    assert_eq!(device.cmd("subscriptions").await?, held);
    device.kill().await?;
    Ok(())
}
