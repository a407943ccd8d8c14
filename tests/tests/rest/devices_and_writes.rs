use super::*;

#[tokio::test]
async fn devices_are_listed_with_diagnostics() {
    let gw = demo().await;
    until_json(&gw, "/api/v1/devices", "both devices polled", |b| {
        b["devices"].as_array().is_some_and(|d| {
            d.len() == 2
                && d.iter()
                    .all(|d| d["connected"] == true && d["io_cycles"].as_u64() > Some(0))
        })
    })
    .await;
    let (status, body) = gw.get("/api/v1/devices").await.expect("get");
    assert_eq!(status, 200);
    let sim = &body["devices"][0];
    assert_eq!(sim["name"], "sim");
    assert_eq!(sim["profile"], "SimIo");
    assert_eq!(sim["error_code"], 0);
    assert!(sim["last_response_ms"].is_number());
    gw.shutdown().await;
}

#[tokio::test]
async fn a_field_carries_type_quality_and_timestamp() {
    let gw = demo().await;
    until_json(&gw, "/api/v1/devices/sim/fields/DI_0", "DI_0 read", |b| {
        b["quality"] == "good"
    })
    .await;
    let (status, body) = gw
        .get("/api/v1/devices/sim/fields/di_0")
        .await
        .expect("get");
    assert_eq!(status, 200, "field names ignore case");
    assert_eq!(body["field"], "DI_0");
    assert_eq!(body["type"], "BOOL");
    assert_eq!(body["direction"], "input");
    assert_eq!(body["value"], false);
    let ts = body["timestamp"].as_str().expect("timestamp");
    assert!(ts.ends_with('Z') && ts.contains('T'), "RFC 3339: {ts}");

    let (status, body) = gw.get("/api/v1/devices/plant").await.expect("get");
    assert_eq!(status, 200);
    let names: Vec<&String> = body["fields"].as_object().expect("fields").keys().collect();
    assert_eq!(
        names.first().map(|s| s.as_str()),
        Some("PumpRunning"),
        "profile order"
    );
    assert_eq!(names.len(), 19);
    gw.shutdown().await;
}

#[tokio::test]
async fn a_write_to_an_output_lands_and_reports_written() {
    let gw = demo().await;
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/sim/fields/DO_0",
            r#"{"value": true}"#,
        )
        .await
        .expect("put");
    assert_eq!(status, 202, "{body}");
    assert_eq!(body["status"], "pending");
    let generation = body["generation"].as_u64().expect("generation");
    let write = format!("/api/v1/writes/{generation}");
    until_json(&gw, &write, "write done", |b| b["status"] == "written").await;
    let (_, body) = gw
        .get("/api/v1/devices/sim/fields/DO_0")
        .await
        .expect("get");
    assert_eq!(body["value"], true);
    assert_eq!(body["last_write"]["generation"], generation);
    assert_eq!(body["last_write"]["status"], "written");
    gw.shutdown().await;
}

#[tokio::test]
async fn every_type_round_trips_through_the_api() {
    let gw = demo().await;
    // Outputs and inouts are written; inputs are set on the simulated device.
    let cases = [
        ("PumpRunning", json!(true), "simulate"),
        ("PumpStart", json!(true), "write"),
        ("Level", json!(42.25), "simulate"),
        ("TemperatureSetpoint", json!(0.1), "write"),
        ("FlowTotal", json!(12345.678901234), "simulate"),
        ("TrimOffset", json!(-128), "write"),
        ("Pressure", json!(-32768), "simulate"),
        ("BatchCount", json!(-2147483648i64), "simulate"),
        ("TotalCycles", json!(i64::MIN), "simulate"),
        ("Recipe", json!(255), "write"),
        ("SpeedRpm", json!(65535), "simulate"),
        ("RunSeconds", json!(4294967295u64), "simulate"),
        ("SerialNumber", json!(u64::MAX), "simulate"),
        ("AlarmBits", json!(170), "simulate"),
        ("StatusWord", json!(43690), "simulate"),
        ("ErrorMask", json!(4294967295u64), "write"),
        ("Signature", json!(u64::MAX), "simulate"),
        ("BatchName", json!("Batch 17 ÄÖ"), "write"),
        ("MixTime", json!(90500), "write"),
    ];
    for (field, value, how) in &cases {
        let path = match *how {
            "write" => format!("/api/v1/devices/plant/fields/{field}"),
            _ => format!("/api/v1/devices/plant/fields/{field}/simulate"),
        };
        let (status, body) = gw
            .send(Method::PUT, &path, json!({ "value": value }).to_string())
            .await
            .expect("put");
        assert_eq!(status, 202, "{field}: {body}");
    }
    for (field, value, _) in &cases {
        let path = format!("/api/v1/devices/plant/fields/{field}");
        until_json(&gw, &path, field, |b| &b["value"] == value).await;
    }
    // TIME also takes IEC literals.
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/plant/fields/MixTime",
            r#"{"value": "T#1m30s"}"#,
        )
        .await
        .expect("put");
    assert_eq!(status, 202);
    until_json(
        &gw,
        "/api/v1/devices/plant/fields/MixTime",
        "MixTime 90000",
        |b| b["value"] == 90000,
    )
    .await;
    gw.shutdown().await;
}

#[tokio::test]
async fn caller_mistakes_get_json_errors_with_the_right_status() {
    let gw = demo().await;
    let put = |path: &'static str, body: &'static str| {
        let gw = &gw;
        async move { gw.send(Method::PUT, path, body).await.expect("request") }
    };
    let cases: Vec<(u16, &str, (u16, Value))> = vec![
        (
            404,
            "unknown_device",
            gw.get("/api/v1/devices/nope").await.expect("get"),
        ),
        (
            404,
            "unknown_field",
            gw.get("/api/v1/devices/sim/fields/NOPE")
                .await
                .expect("get"),
        ),
        (
            404,
            "unknown_link",
            gw.get("/api/v1/links/nope").await.expect("get"),
        ),
        (
            404,
            "unknown_profile",
            gw.get("/api/v1/profiles/nope").await.expect("get"),
        ),
        (
            404,
            "no_route",
            gw.get("/api/v2/devices").await.expect("get"),
        ),
        (
            409,
            "not_writable",
            put("/api/v1/devices/sim/fields/DI_0", r#"{"value": true}"#).await,
        ),
        (
            400,
            "invalid_value",
            put("/api/v1/devices/plant/fields/Recipe", r#"{"value": 256}"#).await,
        ),
        (
            400,
            "invalid_value",
            put("/api/v1/devices/plant/fields/Recipe", r#"{"value": 2.5}"#).await,
        ),
        (
            400,
            "invalid_value",
            put("/api/v1/devices/sim/fields/DO_0", r#"{"value": "on"}"#).await,
        ),
        (
            400,
            "invalid_value",
            put(
                "/api/v1/devices/plant/fields/TemperatureSetpoint",
                r#"{"value": 1e39}"#,
            )
            .await,
        ),
        (
            400,
            "invalid_value",
            put(
                "/api/v1/devices/plant/fields/MixTime",
                r#"{"value": "soon"}"#,
            )
            .await,
        ),
        (
            400,
            "invalid_value",
            put("/api/v1/devices/sim/fields/DO_0", r#"{"value": null}"#).await,
        ),
        (
            400,
            "invalid_json",
            put("/api/v1/devices/sim/fields/DO_0", r#"{"value": tru"#).await,
        ),
        (
            400,
            "missing_body",
            put("/api/v1/devices/sim/fields/DO_0", "").await,
        ),
        (
            404,
            "unknown_device",
            put("/api/v1/devices/nope/fields/DO_0", r#"{"value": true}"#).await,
        ),
        (
            409,
            "not_an_input",
            put(
                "/api/v1/devices/sim/fields/DO_0/simulate",
                r#"{"value": true}"#,
            )
            .await,
        ),
        (
            400,
            "invalid_generation",
            gw.get("/api/v1/writes/abc").await.expect("get"),
        ),
        (
            404,
            "unknown_write",
            gw.get("/api/v1/writes/999999").await.expect("get"),
        ),
        (
            404,
            "unknown_device",
            gw.get("/api/v1/events?device=nope").await.expect("get"),
        ),
        (
            400,
            "invalid_query",
            gw.get("/api/v1/events?devices=sim").await.expect("get"),
        ),
    ];
    for (want_status, want_code, (status, body)) in cases {
        assert_eq!(
            (status, error_code(&body)),
            (want_status, want_code),
            "{body}"
        );
        let message = body["error"]["message"].as_str().expect("message");
        assert!(!message.is_empty());
    }
    let (_, body) = put("/api/v1/devices/plant/fields/Recipe", r#"{"value": 256}"#).await;
    assert_eq!(
        body["error"]["message"],
        "field plant.Recipe (USINT): 256 is out of range for USINT (0 to 255)"
    );
    gw.shutdown().await;
}

#[tokio::test]
async fn patch_writes_all_fields_or_none() {
    let gw = demo().await;
    let (status, body) = gw
        .send(
            Method::PATCH,
            "/api/v1/devices/plant/fields",
            r#"{"PumpStart": true, "Recipe": 999, "PumpRunning": true}"#,
        )
        .await
        .expect("patch");
    assert_eq!(status, 400, "{body}");
    let message = body["error"]["message"].as_str().expect("message");
    assert!(message.starts_with("nothing was written"), "{message}");
    assert!(
        message.contains("Recipe") && message.contains("PumpRunning"),
        "every problem: {message}"
    );
    let (_, field) = gw
        .get("/api/v1/devices/plant/fields/PumpStart")
        .await
        .expect("get");
    assert!(
        field.get("last_write").is_none(),
        "nothing written: {field}"
    );

    let (status, body) = gw
        .send(
            Method::PATCH,
            "/api/v1/devices/plant/fields",
            r#"{"PumpStart": true, "Recipe": 7}"#,
        )
        .await
        .expect("patch");
    assert_eq!(status, 202, "{body}");
    assert_eq!(body["writes"].as_array().map(Vec::len), Some(2));
    until_json(
        &gw,
        "/api/v1/devices/plant/fields/Recipe",
        "Recipe 7",
        |b| b["value"] == 7,
    )
    .await;
    until_json(
        &gw,
        "/api/v1/devices/plant/fields/PumpStart",
        "PumpStart",
        |b| b["value"] == true,
    )
    .await;

    for bad in ["[1, 2]", "{}", "\"DO_0\""] {
        let (status, body) = gw
            .send(Method::PATCH, "/api/v1/devices/plant/fields", bad)
            .await
            .expect("patch");
        assert_eq!((status, error_code(&body)), (400, "invalid_body"), "{bad}");
    }
    gw.shutdown().await;
}

#[tokio::test]
async fn a_burst_of_writes_ends_with_the_last_value_and_every_write_resolved() {
    let gw = demo().await;
    let mut generations = Vec::new();
    for i in 0..100 {
        let (status, body) = gw
            .send(
                Method::PUT,
                "/api/v1/devices/plant/fields/TemperatureSetpoint",
                json!({ "value": i }).to_string(),
            )
            .await
            .expect("put");
        assert_eq!(status, 202);
        generations.push(body["generation"].as_u64().expect("generation"));
    }
    until_json(
        &gw,
        "/api/v1/devices/plant/fields/TemperatureSetpoint",
        "last value",
        |b| b["value"].as_f64() == Some(99.0),
    )
    .await;
    let last = *generations.last().expect("100 writes");
    until_json(
        &gw,
        &format!("/api/v1/writes/{last}"),
        "last written",
        |b| b["status"] == "written",
    )
    .await;
    let mut written = 0;
    for g in &generations {
        let (_, body) = gw.get(&format!("/api/v1/writes/{g}")).await.expect("get");
        match body["status"].as_str() {
            Some("written") => written += 1,
            Some("superseded") => {}
            other => panic!("write {g} ended as {other:?}"),
        }
    }
    // The demo's plant device refreshes every 250 ms: a burst lands in a few cycles.
    assert!(written < 10, "{written} of 100 writes reached the device");
    gw.shutdown().await;
}
