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
