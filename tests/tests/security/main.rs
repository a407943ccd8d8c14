//! Access control: bearer tokens with roles on REST, SSE and gRPC; read-only; the loopback
//! rule without tokens.

mod refusals;
mod roles_and_limits;

use reqwest::Method;
use serde_json::json;

use iogate_tests::TestGateway;
use iogate_tests::devices::temp_dir;

const READ: &str = "read-token-0123456789";
const WRITE: &str = "write-token-0123456789";
const ADMIN: &str = "admin-token-0123456789";

async fn gateway(extra: &str) -> TestGateway {
    let dir = temp_dir("security");
    let tokens = dir.join("tokens");
    std::fs::write(
        &tokens,
        format!("# who may do what\nread {READ}\nwrite {WRITE}\nadmin {ADMIN}\n"),
    )
    .expect("tokens");
    TestGateway::start(&format!(
        "devices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 20ms }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  map:\n    - {{ at: \"%QX0.0\", field: sim.DO_0 }}\nsecurity:\n  tokens_file: {}\n{extra}",
        tokens.display()
    ))
    .await
    .expect("gateway")
}

async fn call(
    gw: &TestGateway,
    method: Method,
    path: &str,
    token: Option<&str>,
    body: &str,
) -> (u16, serde_json::Value) {
    let mut request = gw
        .client
        .request(method, gw.url(path))
        .header("content-type", "application/json")
        .body(body.to_owned());
    if let Some(t) = token {
        request = request.bearer_auth(t);
    }
    let response = request.send().await.expect("request");
    let status = response.status().as_u16();
    (
        status,
        response.json().await.unwrap_or(serde_json::Value::Null),
    )
}

/// The role a REST route needs, as docs/security.md states it.
fn needed_rest(method: &str, path: &str) -> Option<usize> {
    // 0 open, 1 read, 2 write, 3 admin.
    if matches!(path, "/livez" | "/readyz" | "/metrics") {
        return None;
    }
    let declaration = matches!(
        path,
        "/api/v1/links/{link}" | "/api/v1/devices/{device}" | "/api/v1/transactions/{name}"
    );
    Some(match method {
        "get" => 1,
        "delete" => 3,
        "put" if declaration => 3,
        "post" if path == "/api/v1/config/reload" || path == "/api/v1/links/{link}/scan" => 3,
        _ => 2,
    })
}
