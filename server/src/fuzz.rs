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
    crate::drivers::register();
    if let Ok(text) = std::str::from_utf8(data)
        && let Ok(config) = crate::config::parse("fuzz.yaml", text)
    {
        let _ = crate::drivers::check_links(&config);
    }
}

/// A profile.
pub fn profile_yaml(data: &[u8]) {
    crate::drivers::register();
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

/// A BACnet device's answers, notifications and a profile's BACnet notation.
pub fn bacnet_answer(data: &[u8]) {
    crate::drivers::bacnet::fuzz_answer(data);
}

/// An IEC 104 station's APDUs and ASDUs, and a profile's IEC 104 notation.
pub fn iec104_frames(data: &[u8]) {
    crate::drivers::iec104::fuzz_frames(data);
}

/// A SCADA master's APDUs and ASDUs as the IEC 104 outstation takes them, commands read
/// as writes of every type, and a map file's text.
pub fn iec104_master(data: &[u8]) {
    crate::api::iec104_server::fuzz::master(data);
}

/// A Logix controller's EtherNet/IP answers and Read Tag replies by every type.
pub fn eip_answer(data: &[u8]) {
    crate::drivers::eip::fuzz_answer(data);
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
                    let _ = crate::opcua_variant::reading(ty, 64, &dv);
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

/// An HTTP request to the REST API's router (paths, query strings, bodies): the first byte
/// picks the method, the text to the first newline is the request's target, the rest its
/// body. The router answers every request without a panic and without a 500; a stream's
/// body is not waited for.
pub fn http_request(data: &[u8]) {
    use tower::ServiceExt;
    let Some((&kind, rest)) = data.split_first() else {
        return;
    };
    let methods = ["GET", "PUT", "POST", "DELETE", "PATCH", "HEAD"];
    let method = methods[usize::from(kind) % methods.len()];
    let split = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
    let (target, body) = (&rest[..split], rest.get(split + 1..).unwrap_or_default());
    let Ok(request) = axum::http::Request::builder()
        .method(method)
        .uri(target)
        .header("content-type", "application/json")
        .body(axum::body::Body::from(body.to_vec()))
    else {
        return;
    };
    let (runtime, router) = http_router();
    runtime.block_on(async {
        let answered = router.clone().oneshot(request);
        let Ok(Ok(response)) = tokio::time::timeout(HTTP_PATIENCE, answered).await else {
            return;
        };
        let status = response.status();
        assert_ne!(status, axum::http::StatusCode::INTERNAL_SERVER_ERROR);
        let streamed = response
            .headers()
            .get("content-type")
            .is_some_and(|t| t.as_bytes().starts_with(b"text/event-stream"));
        if !streamed {
            let body = http_body_util::BodyExt::collect(response.into_body());
            let _ = tokio::time::timeout(HTTP_PATIENCE, body).await;
        }
    });
}

/// How long a request of [`http_request`] may take.
const HTTP_PATIENCE: std::time::Duration = std::time::Duration::from_millis(500);

/// The router of a gateway with the demo's simulated devices, and the runtime it runs on,
/// made once; declarations may reach no port and no host.
fn http_router() -> &'static (tokio::runtime::Runtime, axum::Router) {
    use std::sync::{Arc, OnceLock};
    static ROUTER: OnceLock<(tokio::runtime::Runtime, axum::Router)> = OnceLock::new();
    ROUTER.get_or_init(|| {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("a runtime");
        let router = runtime.block_on(async {
            let setup = crate::app::Setup::demo_simulated().expect("the demo");
            let cache = Arc::new(crate::cache::Cache::new(&setup.config, setup.catalog));
            let tasks = crate::runtime::Tasks::new(
                tokio_util::task::TaskTracker::new(),
                tokio_util::sync::CancellationToken::new(),
                Arc::new(crate::metrics::Metrics::new()),
            );
            let service = crate::service::Service::new(cache, tasks);
            service.set_policy(crate::config::security::DeclarePolicy {
                serial_ports: Vec::new(),
                tcp_hosts: Vec::new(),
            });
            service.set_ready(true);
            crate::api::http::router(Arc::new(service), HTTP_PATIENCE)
        });
        (runtime, router)
    })
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
    ("eip_answer", eip_answer),
    ("bacnet_answer", bacnet_answer),
    ("iec104_frames", iec104_frames),
    ("grpc_request", grpc_request),
    ("opcua_binary", opcua_binary),
    ("http_request", http_request),
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

    /// A request header whose additional header is an Argument claiming a value rank of
    /// 2^31 - 1: refused as malformed, not 8 GiB allocated to pad its dimensions (found by
    /// the `opcua_binary` target; the input is kept in `fuzz/regressions/`).
    #[test]
    fn an_opcua_argument_claiming_a_huge_rank_is_refused() {
        use opcua::types::{BinaryDecodable, BrowseRequest, ContextOwned};
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../fuzz/regressions/opcua_binary/argument-rank-2g");
        let data = std::fs::read(path).expect("the finding");
        let ctx = ContextOwned::default();
        let mut s = std::io::Cursor::new(data.get(1..).unwrap_or_default());
        let decoded = BrowseRequest::decode(&mut s, &ctx.context());
        let err = decoded.err().map(|e| e.to_string()).unwrap_or_default();
        assert!(err.contains("value rank"), "{err}");
    }

    /// The HTTP target's requests reach the API: the demo's devices are there to read and
    /// write.
    #[test]
    fn the_http_targets_router_serves_the_api() {
        use tower::ServiceExt;
        let (runtime, router) = super::http_router();
        let status = |method: &str, uri: &str, body: &str| {
            let request = axum::http::Request::builder()
                .method(method)
                .uri(uri)
                .header("content-type", "application/json")
                .body(axum::body::Body::from(body.to_owned()))
                .expect("request");
            runtime
                .block_on(router.clone().oneshot(request))
                .expect("answered")
                .status()
                .as_u16()
        };
        assert_eq!(status("GET", "/api/v1/devices/sim", ""), 200);
        assert_eq!(
            status(
                "PUT",
                "/api/v1/devices/plant/fields/Recipe",
                r#"{"value": 300}"#
            ),
            400
        );
        let declared = r#"{"tcp": {"host": "127.0.0.1", "port": 502}}"#;
        assert_eq!(
            status("PUT", "/api/v1/links/l1", declared),
            403,
            "no host is allowed"
        );
    }
}
