//! The OPC UA server against an independent client (asyncua, Python): browse, read every
//! IEC type with its status and timestamps, subscribe to a device on a pty, write through
//! the service, refusals in OPC UA's words, tokens as users, and Basic256Sha256
//! SignAndEncrypt with a trusted and an untrusted client certificate.

mod security_and_limits;
mod values_and_writes;

use iogate_tests::devices::{Behaviour, RtuBus, temp_dir};
use iogate_tests::opcua::{Options, UaClient, refused};
use iogate_tests::{TestGateway, bus_gateway_with, eventually};
use reqwest::Method;
use serde_json::json;

fn opcua(dir: &std::path::Path, extra: &str) -> String {
    format!(
        "opcua:\n  listen: 127.0.0.1:0\n  pki_dir: {}\n{extra}",
        dir.join("pki").display()
    )
}

fn url(gw: &TestGateway) -> String {
    format!("opc.tcp://{}/", gw.opcua.expect("an OPC UA server"))
}

const PLANT: &str = "devices:\n  - { name: plant, profile: SimPlant, refresh_rate: 100ms }\n";

/// A REST read with the reader's token.
async fn rest(gw: &TestGateway, path: &str) -> anyhow::Result<serde_json::Value> {
    Ok(gw
        .client
        .get(gw.url(path))
        .bearer_auth("reader-0123456789abcdef")
        .send()
        .await?
        .json()
        .await?)
}

/// The next model change event (value changes on the way are skipped).
async fn next_event(ua: &mut UaClient) -> serde_json::Value {
    for _ in 0..5 {
        let changes = ua
            .cmd(json!({"cmd": "changes", "wait": 5}))
            .await
            .expect("changes");
        if let Some(e) = changes["changes"]
            .as_array()
            .and_then(|c| c.iter().find(|c| c.get("event").is_some()))
        {
            return e.clone();
        }
    }
    panic!("no model change event");
}

/// The status of the first change whose status satisfies `f`.
async fn wait_status(ua: &mut UaClient, f: impl Fn(&str) -> bool) -> String {
    let mut all = Vec::new();
    for _ in 0..10 {
        let changes = ua
            .cmd(json!({"cmd": "changes", "wait": 5}))
            .await
            .expect("changes");
        for c in changes["changes"].as_array().cloned().unwrap_or_default() {
            let status = c["status"].as_str().unwrap_or_default().to_owned();
            all.push(c.clone());
            if f(&status) {
                return status;
            }
        }
    }
    panic!("no such status among {all:?}");
}
