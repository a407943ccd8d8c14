//! What a newcomer meets on the command line: answers that end their line.

use iogate_tests::TestGateway;

#[tokio::test]
async fn every_json_answer_ends_with_a_newline() {
    let gw = TestGateway::demo().await.expect("demo");
    let client = reqwest::Client::new();
    for (method, path) in [
        (reqwest::Method::GET, "/api/v1/devices"),
        (reqwest::Method::GET, "/api/v1/devices/sim/fields/DO_0"),
        (reqwest::Method::GET, "/api/v1/devices/nope"),
        // An axum refusal (a method the route has not), made JSON on its way out.
        (reqwest::Method::DELETE, "/api/v1/devices"),
    ] {
        let response = client
            .request(method.clone(), gw.url(path))
            .send()
            .await
            .expect("answer");
        let json = response
            .headers()
            .get("content-type")
            .is_some_and(|v| v.as_bytes().starts_with(b"application/json"));
        let body = response.bytes().await.expect("body");
        assert!(json, "{method} {path}: {body:?}");
        assert_eq!(body.last(), Some(&b'\n'), "{method} {path}: {body:?}");
        assert_ne!(
            body.get(body.len().saturating_sub(2)),
            Some(&b'\n'),
            "one newline"
        );
        serde_json::from_slice::<serde_json::Value>(&body).expect("still JSON");
    }
    gw.shutdown().await;
}

/// The demo's field: its link polls an energy meter and an I/O module over a real socket,
/// the module's input follows the output written through the gateway, and the meter feels
/// the load.
#[tokio::test]
async fn the_demo_polls_a_meter_and_an_io_module_on_its_field_line() {
    let gw = TestGateway::demo_as_shipped().await.expect("demo");
    let meter = gw.all_read("meter").await.expect("meter read");
    let volts = meter["fields"]["L1_Voltage"]["value"]
        .as_f64()
        .expect("a REAL");
    assert!((227.0..233.0).contains(&volts), "{volts} V");
    gw.all_read("io").await.expect("io read");
    let (status, links) = gw.get("/api/v1/links").await.expect("links");
    assert_eq!(status, 200);
    let field = links["links"]
        .as_array()
        .and_then(|l| l.iter().find(|l| l["name"] == "field"))
        .cloned()
        .expect("the link field");
    assert_eq!(field["connected"], true, "{field}");
    let plan = reqwest::get(gw.url("/api/v1/links/field/plan"))
        .await
        .expect("the field's plan")
        .text()
        .await
        .expect("its text");
    assert!(
        plan.contains("device meter (profile EastronSDM630, slave 1"),
        "{plan}"
    );
    assert!(
        plan.contains("device io (profile WaveshareIo8, slave 2"),
        "{plan}"
    );

    let current = |b: &serde_json::Value| b["fields"]["L1_Current"]["value"].as_f64();
    let before = current(&meter).expect("a current");
    let (status, body) = gw
        .send(
            reqwest::Method::PUT,
            "/api/v1/devices/io/fields/DO1",
            r#"{"value": true}"#,
        )
        .await
        .expect("write");
    assert_eq!(status, 202, "{body}");
    gw.until("/api/v1/devices/io/fields/DI1", "DI1 follows DO1", |b| {
        b["value"] == true
    })
    .await
    .expect("the input follows the output");
    gw.until("/api/v1/devices/meter", "the meter feels DO1's load", |b| {
        current(b).is_some_and(|a| a > before + 1.5)
    })
    .await
    .expect("the load measured");
    gw.shutdown().await;
}
