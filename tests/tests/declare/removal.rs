use super::*;

#[tokio::test]
async fn declared_devices_and_links_can_be_removed_and_configured_ones_cannot() {
    let device = ModbusDevice::default();
    device.tables.lock().expect("tables").input[0] = 777;
    let (port, server) = modbus_tcp_server(device).await;
    let gw = TestGateway::demo().await.expect("demo");
    let link = json!({"tcp": {"host": "127.0.0.1", "port": port}});
    let (status, _) = gw
        .send(Method::PUT, "/api/v1/links/plc", link.to_string())
        .await
        .expect("put link");
    assert_eq!(status, 201);
    let bound = json!({"profile": "WaveshareAnalogInput", "link": "plc", "slave_id": 1, "refresh_rate_ms": 50});
    let (status, answer) = gw
        .send(Method::PUT, "/api/v1/devices/adc", bound.to_string())
        .await
        .expect("put device");
    assert_eq!(status, 201);
    // The answer says what the device will do, as every later look at it does.
    assert_eq!(
        answer["device"]["rewrite_outputs"], "on_reconnect",
        "{answer}"
    );
    gw.until("/api/v1/devices/adc", "adc polled", |b| {
        b["fields"]["AI1"]["value"] == 777
    })
    .await
    .expect("polled");

    // The link is in use; configured things stay; unknown names are 404; all as JSON.
    let (status, body) = delete(&gw, "/api/v1/links/plc").await;
    assert_eq!(status, 409, "{body}");
    assert!(
        body["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("device adc")),
        "{body}"
    );
    let (status, body) = delete(&gw, "/api/v1/devices/sim").await;
    assert_eq!(status, 409, "{body}");
    assert!(
        body["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("config file"))
    );
    let (status, body) = delete(&gw, "/api/v1/devices/nope").await;
    assert_eq!(
        (status, &body["error"]["code"]),
        (404, &json!("unknown_device"))
    );

    assert_eq!(delete(&gw, "/api/v1/devices/adc").await.0, 204);
    assert_eq!(gw.get("/api/v1/devices/adc").await.expect("get").0, 404);
    let (_, list) = gw.get("/api/v1/devices").await.expect("list");
    assert!(
        list["devices"]
            .as_array()
            .is_some_and(|d| d.iter().all(|d| d["name"] != "adc")),
        "{list}"
    );
    assert_eq!(delete(&gw, "/api/v1/links/plc").await.0, 204);
    assert_eq!(gw.get("/api/v1/links/plc").await.expect("get").0, 404);

    // The names can be declared again, over gRPC, and removed the same way there.
    let mut client = gw.client().await.expect("client");
    let (status, _) = gw
        .send(Method::PUT, "/api/v1/links/plc", link.to_string())
        .await
        .expect("put link");
    assert_eq!(status, 201);
    let (_, created) = client
        .ensure_device(&adc("plc", 1))
        .await
        .expect("declared again");
    assert!(created);
    reads(&client, "adc", 777).await;
    let refused = client.remove_link("plc").await.expect_err("in use");
    assert!(refused.to_string().contains("device adc"), "{refused}");
    client.remove_device("adc").await.expect("removed");
    client.remove_link("plc").await.expect("removed");
    assert!(client.device("adc").await.is_err());
    server.abort();
    gw.shutdown().await;
}

#[tokio::test]
async fn a_removed_link_closes_its_socket() {
    use tokio::io::AsyncReadExt;
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let gw = TestGateway::demo().await.expect("demo");
    let link = json!({"tcp": {"host": "127.0.0.1", "port": port}});
    let (status, _) = gw
        .send(Method::PUT, "/api/v1/links/raw", link.to_string())
        .await
        .expect("put link");
    assert_eq!(status, 201);
    let (mut socket, _) = tokio::time::timeout(iogate_tests::PATIENCE, listener.accept())
        .await
        .expect("the link connects")
        .expect("accept");
    assert_eq!(delete(&gw, "/api/v1/links/raw").await.0, 204);
    let mut buf = [0u8; 16];
    let read = tokio::time::timeout(iogate_tests::PATIENCE, socket.read(&mut buf))
        .await
        .expect("closed by the gateway");
    assert!(matches!(read, Ok(0) | Err(_)), "{read:?}");
    gw.shutdown().await;
}
