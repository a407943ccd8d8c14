//! The Modbus engine over real pseudo-terminals: the gateway opens the pty by path, as it
//! would open /dev/ttyUSB0, and devices answer on the other end.

mod faults;
mod reads_and_writes;

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

const COUNTER_PROFILE: &str = "name: Counter\nfields:\n  - { name: Count, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: Setpoint, type: UINT, direction: output, register: { address: 0, kind: holding_register } }\n";

fn counter_value(body: &Value) -> Option<u64> {
    body["fields"]["Count"]["value"].as_u64()
}
