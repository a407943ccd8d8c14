//! The S7 driver against Snap7's server (python-snap7, `tests/s7/plc.py`): every type and
//! area read at a PDU of 240 and of 960, every type written (a bit without touching
//! its neighbours), item errors per field, the PLC in STOP and a server stopped and started
//! again.

mod doors;
mod failures;
mod guest;
mod interop;
mod values;
mod writes;

use iogate_tests::TestGateway;
use iogate_tests::devices::temp_dir;
use serde_json::{Value, json};

/// One field of every type and area the PLC of `tests/s7/plc.py` holds.
const PROFILE: &str = r#"name: Press
protocol: s7
fields:
  - { name: Flags, type: BYTE, direction: input, address: DB1.DBB0 }
  - { name: B1, type: BOOL, direction: inout, address: DB1.DBX0.1 }
  - { name: B2, type: BOOL, direction: inout, address: DB1.DBX0.2 }
  - { name: Si, type: SINT, direction: inout, address: DB1.DBB1 }
  - { name: In, type: INT, direction: inout, address: DB1.DBW2 }
  - { name: Di, type: DINT, direction: inout, address: DB1.DBD4 }
  - { name: Li, type: LINT, direction: inout, address: DB1.LINT8 }
  - { name: Re, type: REAL, direction: inout, address: DB1.DBD16 }
  - { name: LR, type: LREAL, direction: inout, address: DB1.LREAL20 }
  - { name: Us, type: USINT, direction: inout, address: DB1.DBB28 }
  - { name: Ch, type: STRING, direction: inout, address: DB1.CHAR29 }
  - { name: Ui, type: UINT, direction: inout, address: DB1.DBW30 }
  - { name: Ud, type: UDINT, direction: inout, address: DB1.DBD32 }
  - { name: Ul, type: ULINT, direction: inout, address: DB1.36 }
  - { name: Wd, type: WORD, direction: inout, address: DB1.DBW44 }
  - { name: Dw, type: DWORD, direction: inout, address: DB1.DBD46 }
  - { name: Lw, type: LWORD, direction: inout, address: DB1.LWORD50 }
  - { name: Tdint, type: TIME, direction: inout, address: DB1.DBD58 }
  - { name: Wc, type: STRING, direction: inout, address: DB1.WCHAR62 }
  - { name: Str, type: STRING, direction: inout, address: DB1.STRING64, length: 20 }
  - { name: Stamp, type: STRING, direction: inout, address: DB2.DT0 }
  - { name: StampL, type: STRING, direction: inout, address: DB2.DTL8 }
  - { name: Ws, type: STRING, direction: inout, address: DB2.WSTRING20, length: 10 }
  - { name: DtlMs, type: LINT, direction: inout, address: DB2.DTL44 }
  - { name: M3, type: BOOL, direction: inout, address: M0.3 }
  - { name: Mw, type: INT, direction: inout, address: MW10 }
  - { name: I7, type: BOOL, direction: input, address: I0.7 }
  - { name: Iw, type: WORD, direction: input, address: IW2 }
  - { name: Qb, type: BYTE, direction: inout, address: QB4 }
  - { name: Q6, type: BOOL, direction: inout, address: A4.6 }
  - { name: Tm, type: TIME, direction: inout, address: T4 }
  - { name: Ct, type: INT, direction: inout, address: C6 }
  - { name: Missing, type: INT, direction: inout, address: DB9.DBW0 }
  - { name: Scaled, type: REAL, direction: inout, address: DB1.DBW88, raw_type: INT, scale: 0.1, unit: degC }
  - { name: Long, type: STRING, direction: inout, address: DB3.STRING0, length: 254 }
  - { name: Tail, type: STRING, direction: input, address: DB1.STRING100, length: 100 }
  - { name: Past, type: INT, direction: input, address: DB1.DBW300 }
  - { name: Edge, type: INT, direction: input, address: DB1.DBW254 }
  - { name: Over, type: DINT, direction: input, address: DB1.DBD256 }
"#;

/// A gateway with the PLC at `port` on two links: one asking for a PDU of 240 bytes
/// (`press240`), one of 960 (`press960`).
async fn gateway(name: &str, port: u16) -> anyhow::Result<TestGateway> {
    gateway_with(name, port, "").await
}

/// The same, with more configuration (other front-ends).
async fn gateway_with(name: &str, port: u16, more: &str) -> anyhow::Result<TestGateway> {
    let dir = temp_dir(name);
    std::fs::create_dir_all(dir.join("profiles"))?;
    std::fs::write(dir.join("profiles/press.yaml"), PROFILE)?;
    let mut config = format!("profiles: {}\nlinks:\n", dir.join("profiles").display());
    for pdu in [240, 960] {
        config.push_str(&format!(
            "  - name: plc{pdu}\n    s7: {{ host: 127.0.0.1, port: {port}, rack: 0, slot: 1, pdu_size: {pdu}, timeout: 1s }}\n"
        ));
    }
    config.push_str("devices:\n");
    for pdu in [240, 960] {
        config.push_str(&format!(
            "  - {{ name: press{pdu}, profile: Press, link: plc{pdu}, refresh_rate: 100ms }}\n"
        ));
    }
    config.push_str(more);
    TestGateway::start(&config).await
}

/// A field of a device's answer.
fn field<'a>(device: &'a Value, name: &str) -> &'a Value {
    &device["fields"][name]
}

/// A device once `check` holds.
async fn until_device(
    gw: &TestGateway,
    device: &str,
    what: &str,
    check: impl Fn(&Value) -> bool,
) -> anyhow::Result<Value> {
    gw.until(&format!("/api/v1/devices/{device}"), what, check)
        .await
}

/// Asks for a write through the REST API: the API's refusal (`Err`, its answer), or the
/// write's outcome once it has one.
async fn put(
    gw: &TestGateway,
    device: &str,
    name: &str,
    value: Value,
) -> anyhow::Result<Result<Value, String>> {
    gw.write_outcome(device, name, value).await
}

/// Writes a field through the REST API and waits for its outcome.
async fn write(gw: &TestGateway, device: &str, name: &str, value: Value) -> anyhow::Result<Value> {
    put(gw, device, name, value)
        .await?
        .map_err(|refused| anyhow::anyhow!("{name}: {refused}"))
}

/// Why a write is refused: by the API at once, or by the driver as its outcome.
async fn refused(
    gw: &TestGateway,
    device: &str,
    name: &str,
    value: Value,
) -> anyhow::Result<String> {
    match put(gw, device, name, value).await? {
        Err(refused) => Ok(refused),
        Ok(outcome) => {
            anyhow::ensure!(outcome["status"] == "failed", "{name}: {outcome}");
            Ok(outcome["error"].as_str().unwrap_or_default().to_owned())
        }
    }
}
