//! Run-time declarations as a scan-cycle runtime makes them: its device blocks are called
//! before its `SerialLink` has a port or the device has a slave id, and must see the error
//! codes of source document 000 rather than a refusal, then recover when declared again.

mod removal;
mod states;

use std::time::Duration;

use iogate_client::{Client, DeviceDeclaration, SerialLink, Value};
use reqwest::Method;
use serde_json::json;

use iogate_tests::devices::{ModbusDevice, modbus_tcp_server, pty_at, temp_dir};
use iogate_tests::{TestGateway, eventually};

fn adc(link: &str, slave_id: u32) -> DeviceDeclaration {
    DeviceDeclaration {
        name: "adc".into(),
        profile: "WaveshareAnalogInput".into(),
        link: link.into(),
        slave_id,
        refresh_rate: Duration::from_millis(50),
    }
}

async fn diagnostics(client: &mut Client, device: &str) -> (bool, i32) {
    let info = client.device(device).await.expect("device");
    let d = info.diagnostics.expect("diagnostics");
    (d.connected, d.error_code)
}

async fn reads(client: &Client, device: &str, expected: i64) {
    eventually(&format!("{device} reads {expected}"), || {
        let mut c = client.clone();
        let device = device.to_owned();
        async move {
            c.get(&device, "AI1")
                .await
                .is_ok_and(|v| v.value == Some(Value::Int(expected)))
        }
    })
    .await
    .expect("read");
}

async fn delete(gw: &TestGateway, path: &str) -> (u16, serde_json::Value) {
    let response = gw.client.delete(gw.url(path)).send().await.expect("delete");
    let status = response.status().as_u16();
    let text = response.text().await.expect("body");
    let body = if text.is_empty() {
        serde_json::Value::Null
    } else {
        serde_json::from_str(&text).expect("JSON error body")
    };
    (status, body)
}
