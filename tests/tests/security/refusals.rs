use super::*;

#[tokio::test]
async fn a_body_over_the_limit_is_refused_at_once_and_a_refusal_reaches_http2_clients() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let gw = gateway("").await;
    // Content-Length over 1 MiB: 413 before the body, the connection closed (the body
    // timeout is 30 s: an answer now is not that).
    let addr = gw.base.trim_start_matches("http://").to_owned();
    let mut big = tokio::net::TcpStream::connect(&addr)
        .await
        .expect("connect");
    big.write_all(
        format!("PUT /api/v1/devices/sim/fields/DO_0 HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {ADMIN}\r\nContent-Type: application/json\r\nContent-Length: 2000000\r\n\r\n").as_bytes(),
    )
    .await
    .expect("headers");
    let mut answer = Vec::new();
    tokio::time::timeout(
        std::time::Duration::from_secs(10),
        big.read_to_end(&mut answer),
    )
    .await
    .expect("answered before the body timeout")
    .expect("read");
    let text = String::from_utf8_lossy(&answer);
    assert!(text.starts_with("HTTP/1.1 413"), "{text}");
    assert!(text.contains("\"payload_too_large\""), "{text}");
    // A refusal of a PUT with a body: read first, then answered, over HTTP/1.1 and HTTP/2.
    let body = format!("{{\"value\": \"{}\"}}", "a".repeat(500_000));
    for client in [
        reqwest::Client::builder().http1_only().build(),
        reqwest::Client::builder().http2_prior_knowledge().build(),
    ] {
        let client = client.expect("client");
        for (token, status, code) in [
            (None, 401, "unauthenticated"),
            (Some(READ), 403, "forbidden"),
        ] {
            let mut request = client
                .put(gw.url("/api/v1/devices/sim/fields/DO_0"))
                .header("content-type", "application/json")
                .body(body.clone());
            if let Some(t) = token {
                request = request.bearer_auth(t);
            }
            let response = request.send().await.expect("an answer, not a reset stream");
            assert_eq!(response.status().as_u16(), status);
            let json: serde_json::Value = response.json().await.expect("the refusal's body");
            assert_eq!(json["error"]["code"], code, "{json}");
        }
    }
    gw.shutdown().await;
}

#[tokio::test]
async fn every_documented_route_refuses_each_role_below_its_own() {
    let gw = gateway("").await;
    let (_, doc) = call(&gw, Method::GET, "/api/v1/openapi.json", Some(READ), "").await;
    let tokens = [None, Some(READ), Some(WRITE), Some(ADMIN)];
    let mut checked = 0;
    let paths = doc["paths"].as_object().expect("paths").clone();
    for (template, item) in &paths {
        let path = template
            .replace("{device}", "sim")
            .replace("{field}", "DO_0")
            .replace("{link}", "nolink")
            .replace("{profile}", "SimIo")
            .replace("{generation}", "1")
            .replace("{id}", "1")
            .replace("{name}", "nothing")
            .replace("{at}", "%25QX0.0");
        for method in item.as_object().expect("methods").keys() {
            let Some(needed) = needed_rest(method, template) else {
                continue;
            };
            let m = Method::from_bytes(method.to_uppercase().as_bytes()).expect("method");
            for (rank, token) in tokens.iter().enumerate() {
                if path.ends_with("/events") && rank >= needed {
                    continue; // a stream that would not end
                }
                let (status, body) = call(&gw, m.clone(), &path, *token, "{}").await;
                let want = match (rank, token) {
                    (_, None) => Some(401),
                    (r, _) if r < needed => Some(403),
                    _ => None,
                };
                match want {
                    Some(want) => assert_eq!(status, want, "{m} {path} with {token:?}: {body}"),
                    None => assert!(
                        status != 401 && status != 403,
                        "{m} {path} with {token:?} was refused: {status} {body}"
                    ),
                }
                checked += 1;
            }
        }
    }
    assert!(checked > 80, "only {checked} calls checked");
    gw.shutdown().await;
}

#[tokio::test]
async fn every_rpc_of_the_service_refuses_each_role_below_its_own() {
    use prost::Message;
    let gw = gateway("").await;
    let set = prost_types::FileDescriptorSet::decode(iogate_proto::FILE_DESCRIPTOR_SET)
        .expect("descriptors");
    let methods: Vec<String> = set
        .file
        .iter()
        .flat_map(|f| f.service.iter())
        .filter(|s| s.name() == "Gateway")
        .flat_map(|s| s.method.iter().map(|m| m.name().to_owned()))
        .collect();
    assert!(methods.len() >= 19, "{methods:?}");
    let channel = tonic::transport::Endpoint::from_shared(gw.grpc.clone())
        .expect("endpoint")
        .connect()
        .await
        .expect("channel");
    for method in &methods {
        let needed = match method.as_str() {
            m if m.starts_with("Ensure") || m.starts_with("Remove") || m == "ReloadConfig" => 3,
            "Write" | "Exchange" | "Transact" | "SetTransaction" => 2,
            _ => 1,
        };
        for (rank, token) in [None, Some(READ), Some(WRITE), Some(ADMIN)]
            .into_iter()
            .enumerate()
        {
            let mut request = tonic::Request::new(());
            if let Some(t) = token {
                request.metadata_mut().insert(
                    "authorization",
                    format!("Bearer {t}").parse().expect("ascii"),
                );
            }
            let mut grpc = tonic::client::Grpc::new(channel.clone());
            grpc.ready().await.expect("ready");
            let path: tonic::codegen::http::uri::PathAndQuery =
                format!("/iogate.v1.Gateway/{method}")
                    .parse()
                    .expect("path");
            // Every request message with its defaults is empty on the wire.
            let codec = tonic_prost::ProstCodec::<(), ()>::default();
            let answer = tokio::time::timeout(
                std::time::Duration::from_secs(5),
                grpc.server_streaming(request, path, codec),
            )
            .await;
            let code = match answer {
                Ok(Err(status)) => Some(status.code()),
                Ok(Ok(_)) | Err(_) => None,
            };
            let want = match (rank, token) {
                (_, None) => Some(tonic::Code::Unauthenticated),
                (r, _) if r < needed => Some(tonic::Code::PermissionDenied),
                _ => None,
            };
            match want {
                Some(want) => assert_eq!(code, Some(want), "{method} with {token:?}"),
                None => assert!(
                    !matches!(
                        code,
                        Some(tonic::Code::Unauthenticated | tonic::Code::PermissionDenied)
                    ),
                    "{method} with {token:?} was refused: {code:?}"
                ),
            }
        }
    }
    gw.shutdown().await;
}
