use super::*;

#[tokio::test]
async fn standing_transactions_over_grpc_are_declared_switched_and_streamed() {
    use futures_util::StreamExt;
    use iogate_client::proto;
    let bus = RtuBus::default();
    bus.slave(1, |s| s.tables.holding[0] = 215);
    let on = on_bus("tx-grpc-standing", &bus, "").await;
    let mut client = on.gw.client().await.expect("client");
    let status = client
        .raw()
        .ensure_transaction(proto::EnsureTransactionRequest {
            name: "temp".into(),
            parameters: Some(read_request()),
            period_ms: 50,
            enabled: true,
        })
        .await
        .expect("declared")
        .into_inner();
    assert_eq!((status.kind.as_str(), status.enabled), ("read", true));
    let mut updates = client
        .raw()
        .subscribe(proto::SubscribeRequest {
            devices: vec![],
            fields: vec![],
            diagnostics: false,
            transactions: true,
        })
        .await
        .expect("subscribe")
        .into_inner();
    let mut streamed = None;
    while let Some(update) = updates.next().await {
        if let Some(proto::update::Kind::Transaction(t)) = update.expect("update").kind
            && t.last.as_ref().is_some_and(|l| l.value == Some(21.5))
        {
            streamed = Some(t);
            break;
        }
    }
    assert_eq!(streamed.map(|t| t.name), Some("temp".to_owned()));
    let disabled = client
        .raw()
        .set_transaction(proto::SetTransactionRequest {
            name: "temp".into(),
            enabled: Some(false),
            ..Default::default()
        })
        .await
        .expect("disable")
        .into_inner();
    assert!(!disabled.enabled);
    let listed = client
        .raw()
        .list_transactions(proto::ListTransactionsRequest {})
        .await
        .expect("list")
        .into_inner();
    assert_eq!(listed.transactions.len(), 1);
    // Removed: it runs no more and is gone from the list; removing it again is NOT_FOUND.
    client
        .raw()
        .remove_transaction(proto::RemoveTransactionRequest {
            name: "temp".into(),
        })
        .await
        .expect("removed");
    let listed = client
        .raw()
        .list_transactions(proto::ListTransactionsRequest {})
        .await
        .expect("list")
        .into_inner();
    assert!(listed.transactions.is_empty());
    let again = client
        .raw()
        .remove_transaction(proto::RemoveTransactionRequest {
            name: "temp".into(),
        })
        .await;
    assert_eq!(
        again.map(|_| ()).map_err(|s| s.code()),
        Err(tonic::Code::NotFound)
    );
    let missing = client
        .raw()
        .set_transaction(proto::SetTransactionRequest {
            name: "nope".into(),
            trigger: true,
            ..Default::default()
        })
        .await;
    assert_eq!(
        missing.map(|_| ()).map_err(|s| s.code()),
        Err(tonic::Code::NotFound)
    );
    on.gw.shutdown().await;
    on.task.abort();
}

#[tokio::test]
async fn every_function_type_and_order_over_a_modbus_tcp_link() {
    use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
    let device = ModbusDevice::default();
    {
        let mut t = device.tables.lock().expect("tables");
        t.discrete[3] = true;
        t.discrete[12] = true;
        // -100000 as SIGNED_NUMBER32 in SwapWords (CDAB) order.
        let v = (-100_000i32) as u32;
        t.input[0] = v as u16;
        t.input[1] = (v >> 16) as u16;
        // 0x01020304 as UNSIGNED_NUMBER32 in LittleEndian (DCBA) order.
        t.holding[20] = 0x0403;
        t.holding[21] = 0x0201;
    }
    let (port, server) = modbus_tcp_server(device.clone()).await;
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: plc, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n"
    ))
    .await
    .expect("gateway");
    let post = |body: Value| {
        let gw = &gw;
        async move {
            let (status, answer) = gw
                .send(
                    Method::POST,
                    "/api/v1/links/plc/transactions",
                    body.to_string(),
                )
                .await
                .expect("post");
            assert_eq!(status, 200, "{answer}");
            answer
        }
    };
    // FC02, 13 bits from 0 with LittleEndian: bits 3 and 12 set.
    let a = post(json!({"function": 2, "slave": 1, "address": 0, "bit_count": 13, "byte_order": "LittleEndian", "timeout_ms": 500})).await;
    assert_eq!(a["value"], json!(f64::from((1u32 << 3) | (1 << 12))), "{a}");
    assert_eq!(
        a["request"], "01 02 00 00 00 0D",
        "unit id and PDU on a Modbus TCP link"
    );
    let a = post(json!({"function": 4, "slave": 1, "address": 0, "value_type": "SIGNED_NUMBER32", "byte_order": "SwapWords", "divisor": 1000, "precision": 2, "timeout_ms": 500})).await;
    assert_eq!(a["value"], json!(-100.0), "{a}");
    let a = post(json!({"function": 3, "slave": 1, "address": 20, "value_type": "UNSIGNED_NUMBER32", "byte_order": "LittleEndian", "timeout_ms": 500})).await;
    assert_eq!(a["value"], json!(f64::from(0x0102_0304u32)), "{a}");
    // FC05, and int8/int16 with FC16.
    let a =
        post(json!({"function": 5, "slave": 1, "address": 7, "values": [true], "timeout_ms": 500}))
            .await;
    assert_eq!(a["state"], 4, "{a}");
    let a = post(json!({"function": 16, "slave": 1, "address": 30, "type": "int8", "values": [-2, 5], "timeout_ms": 500})).await;
    assert_eq!(a["state"], 4, "{a}");
    let a = post(json!({"function": 16, "slave": 1, "address": 32, "type": "int16", "byte_order": "Little-endian", "values": [-2], "timeout_ms": 500})).await;
    assert_eq!(a["state"], 4, "{a}");
    {
        let t = device.tables.lock().expect("tables");
        assert!(t.coils[7]);
        assert_eq!(&t.holding[30..33], &[0xFFFE, 5, 0xFEFF]);
    }
    // A value out of its type is refused before sending.
    let (status, answer) = gw
        .send(
            Method::POST,
            "/api/v1/links/plc/transactions",
            json!({"function": 6, "slave": 1, "address": 1, "type": "uint8", "values": [256]})
                .to_string(),
        )
        .await
        .expect("post");
    assert_eq!(status, 400, "{answer}");
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn every_bit_count_under_every_byte_order_reads_every_coil_an_independent_master_set() {
    use tokio_modbus::client::Writer;
    let (gw, mut master, server) = with_tcp_device().await;
    // A pattern with no symmetry: bit i of 0x9E3779B97 on coil i.
    let pattern: Vec<bool> = (0..32).map(|i| 0x9E37_79B9u64 >> i & 1 == 1).collect();
    master
        .write_multiple_coils(0, &pattern)
        .await
        .expect("io")
        .expect("written");
    for n in 1..=32usize {
        for order in ["LittleEndian", "BigEndian", "SwapBytes", "SwapWords"] {
            let (status, answer) = gw
                .send(
                    Method::POST,
                    "/api/v1/links/rs485/transactions",
                    json!({"function": 1, "slave": 1, "address": 0, "bit_count": n,
                           "byte_order": order, "precision": 0, "timeout_ms": 500})
                    .to_string(),
                )
                .await
                .expect("transaction");
            assert_eq!(status, 200, "{answer}");
            let expected = expected_bits(&pattern[..n], order);
            assert_eq!(
                answer["value"].as_f64(),
                Some(expected as f64),
                "{n} bits, {order}: {answer}"
            );
        }
    }
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn floats_keep_the_digits_the_device_meant_and_int32_is_always_an_integer() {
    use tokio_modbus::client::{Reader, Writer};
    let (gw, mut master, server) = with_tcp_device().await;
    let read = |address: u16, precision: u8| {
        json!({"function": 3, "slave": 1, "address": address, "value_type": "FLOAT",
               "byte_order": "BigEndian", "precision": precision, "timeout_ms": 500})
    };
    // Values packed by hand by the master, the documented losses before.
    for (k, (x, precision, shown)) in [
        (0.29f32, 2u8, 0.29f64),
        (100.1, 1, 100.1),
        (21.57, 3, 21.57),
        (23.987, 3, 23.987),
        (23.987, 2, 23.98),
        (-0.29, 2, -0.29),
    ]
    .into_iter()
    .enumerate()
    {
        let address = 2 * k as u16;
        let bits = x.to_bits();
        master
            .write_multiple_registers(address, &[(bits >> 16) as u16, bits as u16])
            .await
            .expect("io")
            .expect("written");
        let (status, answer) = transact(&gw, read(address, precision)).await;
        assert_eq!(status, 200, "{answer}");
        assert_eq!(
            answer["value"],
            json!(shown),
            "{x} with {precision}: {answer}"
        );
    }
    // The type decides the encoding, never the value.
    let write = |ty: &str, value: Value| {
        json!({"function": 16, "slave": 1, "address": 100, "type": ty,
               "byte_order": "BigEndian", "values": [value], "timeout_ms": 500})
    };
    let cases = [
        ("int32", json!(12), Some([0x0000, 0x000C])),
        ("int32", json!(12.0), Some([0x0000, 0x000C])),
        ("int32", json!(12.6), None),
        ("float", json!(12), Some([0x4140, 0x0000])),
        ("float", json!(12.6), Some([0x4149, 0x999A])),
        ("int32/float", json!(12), Some([0x0000, 0x000C])),
        (
            "int32/float",
            serde_json::from_str("12.0").expect("json"),
            Some([0x4140, 0x0000]),
        ),
    ];
    for (ty, value, registers) in cases {
        master
            .write_multiple_registers(100, &[0xDEAD, 0xBEEF])
            .await
            .expect("io")
            .expect("written");
        let (status, answer) = transact(&gw, write(ty, value.clone())).await;
        let held = master
            .read_holding_registers(100, 2)
            .await
            .expect("io")
            .expect("read");
        match registers {
            Some(r) => {
                assert_eq!((status, &answer["actual"]), (200, &json!(true)), "{answer}");
                assert_eq!(held, r.to_vec(), "{ty} {value}");
            }
            None => {
                assert_eq!(status, 400, "{ty} {value}: {answer}");
                assert_eq!(held, vec![0xDEAD, 0xBEEF], "nothing was written");
            }
        }
    }
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn a_declared_transaction_is_removed_and_then_its_link_can_be() {
    use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
    let (port, server) = modbus_tcp_server(ModbusDevice::default()).await;
    let (other, other_server) = modbus_tcp_server(ModbusDevice::default()).await;
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {port} }} }}\n\
         transactions:\n  - {{ name: configured, link: plant, function: 3, slave: 1, address: 0, \
         value_type: UNSIGNED_NUMBER16, byte_order: BigEndian, refresh_interval: 0s }}\n"
    ))
    .await
    .expect("gateway");
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/links/rt",
            json!({"tcp": {"host": "127.0.0.1", "port": other}}).to_string(),
        )
        .await
        .expect("link");
    assert!(status == 200 || status == 201, "{body}");
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/transactions/poll",
            json!({"link": "rt", "function": 3, "slave": 1, "address": 0, "value_type": "UNSIGNED_NUMBER16",
                   "byte_order": "BigEndian", "timeout_ms": 200, "refresh_interval_ms": 20}).to_string(),
        )
        .await
        .expect("declare");
    assert_eq!(status, 200, "{body}");
    let (status, refused) = gw
        .send(Method::DELETE, "/api/v1/links/rt", String::new())
        .await
        .expect("delete");
    assert_eq!(status, 409, "{refused}");
    assert!(
        refused["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("transaction poll")),
        "{refused}"
    );
    let (status, body) = gw
        .send(Method::DELETE, "/api/v1/transactions/poll", String::new())
        .await
        .expect("delete");
    assert_eq!(status, 204, "{body}");
    let (status, _) = gw.get("/api/v1/transactions/poll").await.expect("get");
    assert_eq!(status, 404);
    let (status, body) = gw
        .send(Method::DELETE, "/api/v1/links/rt", String::new())
        .await
        .expect("delete");
    assert_eq!(status, 204, "{body}");
    // One from the config file stays, as configured devices do.
    let (status, body) = gw
        .send(
            Method::DELETE,
            "/api/v1/transactions/configured",
            String::new(),
        )
        .await
        .expect("delete");
    assert_eq!(status, 409, "{body}");
    assert!(
        body["error"]["message"]
            .as_str()
            .is_some_and(|m| m.contains("comes from the config file")),
        "{body}"
    );
    gw.shutdown().await;
    server.abort();
    other_server.abort();
}
