use super::*;

#[tokio::test]
async fn health_and_reflection_are_served() {
    let (gw, _client) = demo().await;
    let channel = tonic::transport::Endpoint::from_shared(gw.grpc.clone())
        .expect("endpoint")
        .connect()
        .await
        .expect("channel");
    let mut health = tonic_health::pb::health_client::HealthClient::new(channel.clone());
    let status = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: iogate_proto::SERVICE_NAME.into(),
        })
        .await
        .expect("check")
        .into_inner();
    assert_eq!(
        status.status(),
        tonic_health::pb::health_check_response::ServingStatus::Serving
    );

    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    let mut reflection = ServerReflectionClient::new(channel);
    let request = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut answers = reflection
        .server_reflection_info(futures_util::stream::iter([request]))
        .await
        .expect("reflection")
        .into_inner();
    let answer = answers.next().await.expect("an answer").expect("ok");
    let Some(MessageResponse::ListServicesResponse(list)) = answer.message_response else {
        panic!("unexpected answer {answer:?}")
    };
    let names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
    assert!(
        names.contains(&iogate_proto::SERVICE_NAME.to_owned()),
        "{names:?}"
    );
    assert!(
        names.contains(&"grpc.health.v1.Health".to_owned()),
        "{names:?}"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn profiles_describe_their_layout_and_st_declaration() {
    let (gw, mut client) = demo().await;
    let profiles = client.profiles().await.expect("profiles");
    assert_eq!(profiles.len(), 8);
    let p = client
        .profile("WaveshareAnalogInput")
        .await
        .expect("profile");
    let layout: Vec<&str> = p.layout.iter().map(|m| m.name.as_str()).collect();
    assert_eq!(
        &layout[..7],
        [
            "link",
            "slave_id",
            "refresh_rate",
            "connected",
            "error_code",
            "io_cycles",
            "last_response_ms"
        ]
    );
    assert!(
        p.st_declaration
            .contains("FUNCTION_BLOCK WaveshareAnalogInput")
    );
    assert!(p.st_declaration.contains("    AI8 : INT;"));
    let devices = client.devices().await.expect("devices");
    assert_eq!(
        devices.iter().map(|d| d.name.as_str()).collect::<Vec<_>>(),
        ["sim", "plant"]
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn malformed_messages_are_invalid_arguments() {
    let (gw, _client) = demo().await;
    let channel = tonic::transport::Channel::from_shared(gw.grpc.clone())
        .expect("uri")
        .connect()
        .await
        .expect("connect");
    let mut grpc = tonic::client::Grpc::new(channel);
    // GetWriteRequest.generation is a varint: a string in its place, a truncated varint, a
    // length running past the end.
    for garbage in [
        vec![0x0A, 0x03, b'a', b'b', b'c'],
        vec![0x08, 0xFF, 0xFF],
        vec![0x12, 0x7F, 0x00],
    ] {
        grpc.ready().await.expect("ready");
        let path =
            tonic::codegen::http::uri::PathAndQuery::from_static("/iogate.v1.Gateway/GetWrite");
        let status = grpc
            .unary(tonic::Request::new(garbage.clone()), path, RawCodec)
            .await
            .expect_err("garbage refused");
        assert_eq!(
            status.code(),
            Code::InvalidArgument,
            "{garbage:02X?}: {status:?}"
        );
        assert!(status.message().contains("malformed"), "{status:?}");
    }
    // A well-formed message still gets its answer: generation 999999 is unknown.
    grpc.ready().await.expect("ready");
    let path = tonic::codegen::http::uri::PathAndQuery::from_static("/iogate.v1.Gateway/GetWrite");
    let status = grpc
        .unary(
            tonic::Request::new(vec![0x08, 0xBF, 0x84, 0x3D]),
            path,
            RawCodec,
        )
        .await
        .expect_err("unknown generation");
    assert_eq!(status.code(), Code::NotFound, "{status:?}");
    gw.shutdown().await;
}

#[tokio::test]
async fn rest_sse_the_map_and_grpc_give_one_view_of_a_field() {
    let (gw, mut client) = demo().await;
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/plant/fields/TemperatureSetpoint",
            r#"{"value": 65.5}"#.to_owned(),
        )
        .await
        .expect("write");
    assert_eq!(status, 202, "{body}");
    let generation = body["generation"].as_u64().expect("generation");
    let rest = gw
        .until(
            "/api/v1/devices/plant/fields/TemperatureSetpoint",
            "written and read back",
            |b| b["last_write"]["status"] == "written" && b["value"] == 65.5,
        )
        .await
        .expect("written");
    // The map over REST (%MD1 in the demo) and the event stream carry the same JSON.
    let (_, map) = gw.get("/api/v1/map/%25MD1").await.expect("map");
    let mut events = iogate_tests::SseReader::open(&gw, "/api/v1/events?device=plant")
        .await
        .expect("events");
    let sse = events
        .until(|name, data| name == "value" && data["field"] == "TemperatureSetpoint")
        .await
        .expect("an event");
    for key in [
        "device",
        "field",
        "type",
        "direction",
        "value",
        "quality",
        "timestamp",
        "unit",
        "mismatch",
        "last_write",
    ] {
        assert_eq!(map[key], rest[key], "/map: {key}");
        assert_eq!(sse[key], rest[key], "SSE: {key}");
    }
    assert_eq!(rest["unit"], "°C");
    assert_eq!(rest["last_write"]["generation"], generation);
    // gRPC: the same value, quality, unit and last write.
    let grpc = client
        .get("plant", "TemperatureSetpoint")
        .await
        .expect("get");
    assert_eq!(grpc.value, Some(Value::Real(65.5)));
    assert_eq!(grpc.quality, Quality::Good);
    assert_eq!(grpc.unit.as_deref(), Some("°C"));
    assert!(!grpc.mismatch);
    let last = grpc.last_write.expect("last write");
    assert_eq!(
        (last.generation, last.outcome),
        (generation, WriteOutcome::Written)
    );
    gw.shutdown().await;
}
