//! The OPC UA client driver against an independent server (asyncua, Python, as a PLC):
//! every IEC type read and written, a server-side change seen once with its source
//! timestamp, status codes as qualities, a value that does not fit its field, a write the
//! server refuses, the server killed and restarted with its namespaces in another order, a
//! server without subscriptions, a subscription the server drops, the other doors (gRPC,
//! the Modbus server) on such a device.

mod doors;
mod limits;
mod peers;
mod recovery;
mod values;

use std::path::Path;

use iogate_tests::TestGateway;
use iogate_tests::plc::UaPlc;
use serde_json::Value;

/// One field per variable of the PLC, as a profile writes them (namespace index 2, which
/// the server's first start has).
pub(crate) const PROFILE: &str = r#"name: TestPlc
protocol: opcua
fields:
  - { name: B, type: BOOL, direction: inout, node: "ns=2;s=Line1.Bool" }
  - { name: SI, type: SINT, direction: inout, node: "ns=2;s=Line1.SInt" }
  - { name: I, type: INT, direction: inout, node: "ns=2;s=Line1.Int" }
  - { name: DI, type: DINT, direction: inout, node: "ns=2;s=Line1.DInt" }
  - { name: LI, type: LINT, direction: inout, node: "ns=2;s=Line1.LInt" }
  - { name: USI, type: USINT, direction: inout, node: "ns=2;s=Line1.USInt" }
  - { name: UI, type: UINT, direction: inout, node: "ns=2;s=Line1.UInt" }
  - { name: UDI, type: UDINT, direction: inout, node: "ns=2;s=Line1.UDInt" }
  - { name: ULI, type: ULINT, direction: inout, node: "ns=2;s=Line1.ULInt" }
  - { name: R, type: REAL, direction: inout, node: "ns=2;s=Line1.Real" }
  - { name: LR, type: LREAL, direction: inout, node: "ns=2;s=Line1.LReal", deadband: 0.5 }
  - { name: S, type: STRING, direction: inout, node: "ns=2;s=Line1.Str", length: 20 }
  - { name: Big, type: INT, direction: input, node: "ns=2;s=Line1.Big" }
  - { name: Locked, type: INT, direction: inout, node: "ns=2;s=Line1.Locked" }
  - { name: Speed, type: LREAL, direction: input, browse_path: "2:Line1/2:Speed", unit: rpm }
  - { name: Missing, type: INT, direction: input, node: "nsu=urn:iogate:test:plc;s=Line1.Nope" }
"#;

/// A gateway with the PLC as device `line1` (refreshed every 100 ms) on link `plc`.
pub(crate) async fn gateway(dir: &Path, plc: &UaPlc, extra: &str) -> anyhow::Result<TestGateway> {
    gateway_with(dir, plc, extra, "").await
}

/// [`gateway`] with more of the config (`more`: top-level sections).
pub(crate) async fn gateway_with(
    dir: &Path,
    plc: &UaPlc,
    extra: &str,
    more: &str,
) -> anyhow::Result<TestGateway> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    std::fs::write(profiles.join("plc.yaml"), PROFILE)?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: plc\n    opcua: {{ url: \"{}\", pki_dir: {}{extra} }}\ndevices:\n  - {{ name: line1, profile: TestPlc, link: plc, refresh_rate: 100ms }}\n{more}",
        profiles.display(),
        plc.url,
        dir.join("pki").display()
    );
    TestGateway::start(&config).await
}

pub(crate) fn field<'a>(device: &'a Value, name: &str) -> &'a Value {
    &device["fields"][name]
}

/// Waits until field `name` of `line1` satisfies `check`.
pub(crate) async fn until_field(
    gw: &TestGateway,
    name: &str,
    what: &str,
    check: impl Fn(&Value) -> bool,
) -> anyhow::Result<Value> {
    let device = gw
        .until("/api/v1/devices/line1", what, |d| check(field(d, name)))
        .await?;
    Ok(field(&device, name).clone())
}
