//! Entry points for coverage-guided fuzzing (`fuzz/`, cargo-fuzz): each feeds bytes a
//! stranger controls to one parser the way the gateway meets them, and must end in a value
//! or an error, never a panic. Built for fuzzing and for the unit tests, which run every
//! target over its seed corpus and every finding kept in `fuzz/regressions/`.

use crate::codec::IecType;
use crate::link::frame::Request;

/// A Modbus PDU as the Modbus server reads it.
pub fn modbus_request(data: &[u8]) {
    if let Ok(request) = Request::parse(data) {
        let mut out = Vec::new();
        request.encode(&mut out);
    }
}

/// Bytes on a serial line as the Modbus RTU server splits them into frames.
pub fn modbus_rtu_request(data: &[u8]) {
    let (frames, _) = crate::link::rtu_frame::split_frames(data);
    for frame in frames {
        if let Ok((_, pdu)) = crate::link::rtu_frame::open(frame) {
            modbus_request(pdu);
        }
    }
}

/// Characters on a serial line as the Modbus ASCII server assembles them.
pub fn modbus_ascii_request(data: &[u8]) {
    let mut assembler = crate::link::ascii::Assembler::default();
    for &c in data {
        if let Some(Ok(frame)) = assembler.push(c) {
            modbus_request(frame.get(1..).unwrap_or_default());
        }
    }
}

/// An MBAP header and PDU as the Modbus TCP server reads them.
pub fn modbus_tcp_request(data: &[u8]) {
    let Some(head) = data.first_chunk::<{ crate::link::mbap::HEADER_LEN }>() else {
        return;
    };
    if crate::link::mbap::Header::parse(head).is_ok() {
        modbus_request(&data[crate::link::mbap::HEADER_LEN..]);
    }
}

/// A device's answer as the master reads it: the first byte says how long the request
/// (a PDU, parsed as the server would) is; the rest is the answer to it.
pub fn modbus_answer(data: &[u8]) {
    let Some((&n, rest)) = data.split_first() else {
        return;
    };
    let n = usize::from(n % 16).min(rest.len());
    let (request, answer) = rest.split_at(n);
    if let Ok(request) = Request::parse(request) {
        let _ = request.parse_response(answer);
        if let Ok((_, pdu)) = crate::link::rtu_frame::open(answer) {
            let _ = request.parse_response(pdu);
        }
    }
}

/// Packets from an MQTT broker, both versions.
pub fn mqtt_packets(data: &[u8]) {
    crate::api::mqtt::fuzz_packets(data);
}

/// A Sparkplug NCMD/DCMD payload.
pub fn sparkplug_command(data: &[u8]) {
    crate::api::mqtt::fuzz_command(data);
}

/// A JSON body of a write (REST, MQTT's JSON commands), converted for every type.
pub fn json_write(data: &[u8]) {
    let Ok(body) = serde_json::from_slice::<serde_json::Value>(data) else {
        return;
    };
    let value = crate::api::http::rest::value_of(body);
    for ty in IecType::ALL {
        let _ = crate::api::convert::json_to_value(ty, &value);
    }
}

/// A configuration file.
pub fn config_yaml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data)
        && let Ok(config) = crate::config::parse("fuzz.yaml", text)
    {
        let _ = crate::drivers::check_links(&config);
    }
}

/// A profile.
pub fn profile_yaml(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = crate::profile::load_str("fuzz.yaml", text);
    }
}

/// A tokens file.
pub fn tokens(data: &[u8]) {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = crate::auth::Tokens::parse(text);
    }
}

/// An imported wb-mqtt-serial template (the first byte 0) or EdgeX profile (else).
pub fn import(data: &[u8]) {
    use crate::profile::import::{Format, import_text};
    let Some((&kind, rest)) = data.split_first() else {
        return;
    };
    let format = if kind == 0 { Format::Wb } else { Format::Edgex };
    if let Ok(text) = std::str::from_utf8(rest) {
        let _ = import_text("fuzz", text, format);
    }
}

/// An S7 PLC's answers and item bytes.
pub fn s7_answer(data: &[u8]) {
    crate::drivers::s7::fuzz_answer(data);
}

/// A fuzz target: bytes in, nothing out but a panic if it has one.
pub type Target = fn(&[u8]);

/// gRPC request messages as the service decodes them (the first byte says which), a
/// write's values converted for every type.
pub fn grpc_request(data: &[u8]) {
    use iogate_proto::pb;
    use prost::Message;
    let Some((&kind, body)) = data.split_first() else {
        return;
    };
    match kind % 6 {
        0 => {
            if let Ok(w) = pb::WriteRequest::decode(body) {
                for write in &w.writes {
                    for ty in IecType::ALL {
                        if let Some(v) = &write.value {
                            let _ = crate::codec::Value::from_pb_as(ty, v);
                        }
                    }
                }
            }
        }
        1 => drop(pb::ReadRequest::decode(body)),
        2 => drop(pb::SubscribeRequest::decode(body)),
        3 => drop(pb::ExchangeRequest::decode(body)),
        4 => drop(pb::EnsureLinkRequest::decode(body)),
        _ => drop(pb::EnsureDeviceRequest::decode(body)),
    }
}

/// OPC UA binary as the server's socket and the client driver meet it (the first byte says
/// which message): requests a client sends, and a server's DataValue converted for every
/// type as the client driver reads it.
pub fn opcua_binary(data: &[u8]) {
    use opcua::types::{
        ActivateSessionRequest, BinaryDecodable, BrowseRequest, ContextOwned,
        CreateMonitoredItemsRequest, CreateSessionRequest, DataValue, ReadRequest, WriteRequest,
    };
    let Some((&kind, body)) = data.split_first() else {
        return;
    };
    let owned = ContextOwned::default();
    let ctx = owned.context();
    let mut s = std::io::Cursor::new(body);
    match kind % 7 {
        0 => {
            if let Ok(dv) = DataValue::decode(&mut s, &ctx) {
                for ty in IecType::ALL {
                    let _ = crate::drivers::opcua::variant::reading(ty, 64, &dv);
                }
            }
        }
        1 => drop(ReadRequest::decode(&mut s, &ctx)),
        2 => drop(WriteRequest::decode(&mut s, &ctx)),
        3 => drop(CreateMonitoredItemsRequest::decode(&mut s, &ctx)),
        4 => drop(CreateSessionRequest::decode(&mut s, &ctx)),
        5 => drop(ActivateSessionRequest::decode(&mut s, &ctx)),
        _ => drop(BrowseRequest::decode(&mut s, &ctx)),
    }
}

/// Every target by name, for the corpus tests.
pub const TARGETS: &[(&str, Target)] = &[
    ("modbus_request", modbus_request),
    ("modbus_rtu_request", modbus_rtu_request),
    ("modbus_ascii_request", modbus_ascii_request),
    ("modbus_tcp_request", modbus_tcp_request),
    ("modbus_answer", modbus_answer),
    ("mqtt_packets", mqtt_packets),
    ("sparkplug_command", sparkplug_command),
    ("json_write", json_write),
    ("config_yaml", config_yaml),
    ("profile_yaml", profile_yaml),
    ("tokens", tokens),
    ("import", import),
    ("s7_answer", s7_answer),
    ("grpc_request", grpc_request),
    ("opcua_binary", opcua_binary),
];

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    /// Every seed and every finding kept runs through its target without a panic.
    #[test]
    fn every_corpus_and_regression_input_runs_through_its_target() {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../fuzz");
        let mut ran = 0;
        for (name, target) in super::TARGETS {
            for dir in ["corpus", "regressions"] {
                let Ok(entries) = std::fs::read_dir(root.join(dir).join(name)) else {
                    continue;
                };
                for entry in entries.flatten() {
                    let data = std::fs::read(entry.path()).expect("readable");
                    target(&data);
                    ran += 1;
                }
            }
        }
        assert!(
            ran >= super::TARGETS.len(),
            "only {ran} inputs: the seed corpora are missing"
        );
    }
}
