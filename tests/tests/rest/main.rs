//! The REST API, driven over HTTP against a gateway running the built-in demo.

mod devices_and_writes;
mod events_profiles_errors;

use reqwest::Method;
use serde_json::{Value, json};

use iogate_tests::{SseReader, TestGateway, eventually};

async fn demo() -> TestGateway {
    TestGateway::demo().await.expect("demo starts")
}

/// Waits until `path`'s JSON satisfies `check`.
async fn until_json(gw: &TestGateway, path: &str, what: &str, check: impl Fn(&Value) -> bool) {
    eventually(what, || async {
        matches!(gw.get(path).await, Ok((200, body)) if check(&body))
    })
    .await
    .expect(what);
}

fn error_code(body: &Value) -> &str {
    body["error"]["code"].as_str().unwrap_or("<no error code>")
}
