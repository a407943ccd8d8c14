//! The BACnet driver against a second, independent stack: the original bacpypes
//! (`tests/bacnet/legacy_device.py`) on 127.0.0.2, with the object types bacpypes3's device
//! does not have (integer, positive integer, large analog and character string values):
//! each read and written as the device holds it, at the field's priority, relinquished, and a
//! change seen through a change-of-value subscription.

use iogate_tests::TestGateway;
use iogate_tests::bacnet::BacnetDevice;
use iogate_tests::devices::temp_dir;
use serde_json::{Value, json};

const PROFILE: &str = r#"name: Zone
protocol: bacnet
fields:
  - { name: Outside, type: REAL, direction: input, object: "analog-input:1" }
  - { name: OutsideFlags, type: BYTE, direction: input, object: "analog-input:1", property: status-flags }
  - { name: Setpoint, type: REAL, direction: inout, object: "analog-value:1", priority: 10 }
  - { name: Occupied, type: BOOL, direction: inout, object: "binary-value:1" }
  - { name: Mode, type: UINT, direction: inout, object: "multi-state-value:1" }
  - { name: Offset, type: DINT, direction: inout, object: "integer-value:1" }
  - { name: Count, type: UDINT, direction: inout, object: "positive-integer-value:1" }
  - { name: Energy, type: LREAL, direction: inout, object: "large-analog-value:1" }
  - { name: Label, type: STRING, direction: inout, object: "characterstring-value:1" }
"#;

fn field<'a>(device: &'a Value, name: &str) -> &'a Value {
    &device["fields"][name]
}

/// A gateway bound to 127.0.0.1 reading the device at 200 ms (`zone`) and once an hour
/// (`watcher`, on a link of its own: its changes come by notification).
async fn gateway(device: &BacnetDevice) -> anyhow::Result<TestGateway> {
    let dir = temp_dir("bacnet-second-stack");
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/zone.yaml"), PROFILE)?;
    let bind = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let bind2 = std::net::UdpSocket::bind("127.0.0.1:0")?.local_addr()?;
    let at = format!("{}:{}", device.host, device.port);
    let config = format!(
        "profiles: {}\nlinks:\n  - name: bms\n    bacnet: {{ bind: \"{bind}\", timeout: 1s, retries: 1 }}\n  - name: slow\n    bacnet: {{ bind: \"{bind2}\" }}\ndevices:\n  - {{ name: zone, profile: Zone, link: bms, device_instance: {i}, address: \"{at}\", refresh_rate: 200ms, cov: false }}\n  - {{ name: watcher, profile: Zone, link: slow, device_instance: {i}, address: \"{at}\", refresh_rate: 1h }}\n",
        dir.join("profiles").display(),
        i = device.instance,
    );
    TestGateway::start(&config).await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_stack_is_read_written_relinquished_and_notifies() -> anyhow::Result<()> {
    let mut device = BacnetDevice::start_legacy(2002).await?;
    let gw = gateway(&device).await?;
    let d = gw.all_read("zone").await?;
    let v = |n: &str| field(&d, n)["value"].clone();
    assert_eq!(v("Outside"), json!(4.5));
    assert_eq!(v("OutsideFlags"), json!(0));
    assert_eq!(v("Setpoint"), json!(20.0));
    assert_eq!(v("Occupied"), json!(false));
    assert_eq!(v("Mode"), json!(1));
    assert_eq!(v("Offset"), json!(-3));
    assert_eq!(v("Count"), json!(7));
    assert_eq!(v("Energy"), json!(1234567.25));
    assert_eq!(v("Label"), json!("north wing"));

    // Every kind written, each checked on the device.
    for (name, value, object, held) in [
        ("Setpoint", json!(22.5), "analogValue,1", "22.5"),
        ("Occupied", json!(true), "binaryValue,1", "active"),
        ("Mode", json!(3), "multiStateValue,1", "3"),
        ("Offset", json!(-7), "integerValue,1", "-7"),
        ("Count", json!(9), "positiveIntegerValue,1", "9"),
        ("Energy", json!(5.5), "largeAnalogValue,1", "5.5"),
        (
            "Label",
            json!("south wing"),
            "characterstringValue,1",
            "south wing",
        ),
    ] {
        let outcome = gw
            .write_outcome("zone", name, value)
            .await?
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        assert_eq!(outcome["status"], "written", "{name}: {outcome}");
        assert_eq!(device.get(object, "presentValue").await?, held, "{name}");
    }
    // At the field's priority (10), and nothing at the default 16.
    assert_eq!(device.cmd("priority analogValue,1 10").await?, "22.5");
    assert_eq!(device.cmd("priority analogValue,1 16").await?, "null");
    assert_eq!(device.cmd("priority integerValue,1 16").await?, "-7");

    // Relinquished: the priority cleared, the relinquish default back, and read so.
    for (name, object, default) in [
        ("Setpoint", "analogValue,1", "18.0"),
        ("Offset", "integerValue,1", "0"),
    ] {
        let outcome = gw
            .write_outcome("zone", name, json!(null))
            .await?
            .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
        assert_eq!(outcome["status"], "written", "{name}: {outcome}");
        assert_eq!(device.get(object, "presentValue").await?, default, "{name}");
    }
    gw.until("/api/v1/devices/zone", "the relinquish defaults", |d| {
        field(d, "Setpoint")["value"] == json!(18.0) && field(d, "Offset")["value"] == json!(0)
    })
    .await?;

    // A value the object's datatype cannot hold is refused before it is sent.
    let refused = gw
        .write_outcome("zone", "Offset", json!(3_000_000_000u64))
        .await?;
    assert!(refused.is_err(), "{refused:?}");
    assert_eq!(device.get("integerValue,1", "presentValue").await?, "0");

    // A change the device's program makes reaches the device read once an hour.
    gw.until("/api/v1/devices/watcher", "first read", |d| {
        field(d, "Outside")["value"] == json!(4.5)
    })
    .await?;
    device.cmd("set analogInput,1 7.25").await?;
    gw.until("/api/v1/devices/watcher", "the notified change", |d| {
        field(d, "Outside")["value"] == json!(7.25) && field(d, "Outside")["quality"] == "good"
    })
    .await?;
    device.kill().await?;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_without_read_property_multiple_is_read_property_by_property() -> anyhow::Result<()>
{
    let mut device = BacnetDevice::start_without_rpm(2003).await?;
    let gw = gateway(&device).await?;
    let d = gw.all_read("zone").await?;
    assert_eq!(field(&d, "Outside")["value"], json!(4.5), "{d}");
    assert_eq!(field(&d, "Label")["value"], json!("north wing"), "{d}");
    assert_eq!(field(&d, "Energy")["value"], json!(1234567.25), "{d}");
    device.cmd("set analogInput,1 6.5").await?;
    gw.until("/api/v1/devices/zone", "the change read", |d| {
        field(d, "Outside")["value"] == json!(6.5)
    })
    .await?;
    let outcome = gw
        .write_outcome("zone", "Count", json!(11))
        .await?
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    assert_eq!(
        device.get("positiveIntegerValue,1", "presentValue").await?,
        "11"
    );
    device.kill().await?;
    Ok(())
}
