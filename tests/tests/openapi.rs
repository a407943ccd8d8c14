//! `/api/v1/openapi.json` is a valid OpenAPI 3.1 document describing every route, so that
//! client generators and Swagger tools accept it.

use serde_json::Value;

use iogate_tests::devices::temp_dir;
use iogate_tests::{TestGateway, fixtures_dir, repo_file, run_installer};

fn oas_schema() -> jsonschema::Validator {
    let text = std::fs::read_to_string(fixtures_dir().join("openapi/oas-3.1-schema.json"))
        .expect("the vendored OpenAPI 3.1 schema");
    let schema: Value = serde_json::from_str(&text).expect("schema JSON");
    jsonschema::draft202012::new(&schema).expect("a valid JSON Schema")
}

fn problems(validator: &jsonschema::Validator, doc: &Value) -> Vec<String> {
    validator
        .iter_errors(doc)
        .map(|e| format!("{} at {}", e, e.instance_path()))
        .collect()
}

/// Every `$ref` in `value`, as `#/components/...` paths.
fn refs<'a>(value: &'a Value, out: &mut Vec<&'a str>) {
    match value {
        Value::Object(map) => {
            for (k, v) in map {
                match (k.as_str(), v) {
                    ("$ref", Value::String(r)) => out.push(r),
                    _ => refs(v, out),
                }
            }
        }
        Value::Array(items) => items.iter().for_each(|v| refs(v, out)),
        _ => {}
    }
}

#[tokio::test]
async fn the_document_is_valid_openapi_3_1_and_describes_every_route() {
    let gw = TestGateway::demo().await.expect("demo");
    let (status, doc) = gw.get("/api/v1/openapi.json").await.expect("openapi");
    assert_eq!(status, 200);
    assert!(
        doc["openapi"]
            .as_str()
            .is_some_and(|v| v.starts_with("3.1.")),
        "{}",
        doc["openapi"]
    );

    let validator = oas_schema();
    let found = problems(&validator, &doc);
    assert!(
        found.is_empty(),
        "{} problems:\n{}",
        found.len(),
        found.join("\n")
    );

    // The check can fail: a response without its required description is caught.
    let mut broken = doc.clone();
    if let Some(ok) = broken["paths"]["/livez"]["get"]["responses"]["200"].as_object_mut() {
        ok.remove("description");
    }
    assert!(!problems(&validator, &broken).is_empty());

    // Every reference resolves.
    let mut all = Vec::new();
    refs(&doc, &mut all);
    assert!(!all.is_empty());
    for r in all {
        let pointer = r.strip_prefix('#').expect("local reference");
        assert!(doc.pointer(pointer).is_some(), "{r} does not resolve");
    }

    // Every route the gateway serves, with its methods.
    let routes: &[(&str, &[&str])] = &[
        ("/livez", &["get"]),
        ("/readyz", &["get"]),
        ("/metrics", &["get"]),
        ("/api/v1/openapi.json", &["get"]),
        ("/api/v1/links", &["get"]),
        ("/api/v1/links/{link}", &["get", "put"]),
        ("/api/v1/links/{link}/transactions", &["post"]),
        ("/api/v1/devices", &["get"]),
        ("/api/v1/devices/{device}", &["get", "put"]),
        ("/api/v1/devices/{device}/fields", &["patch"]),
        ("/api/v1/devices/{device}/fields/{field}", &["get", "put"]),
        ("/api/v1/devices/{device}/fields/{field}/simulate", &["put"]),
        ("/api/v1/writes/{generation}", &["get"]),
        ("/api/v1/profiles", &["get"]),
        ("/api/v1/profiles/{profile}", &["get"]),
        ("/api/v1/profiles/{profile}/st", &["get"]),
        ("/api/v1/events", &["get"]),
        ("/api/v1/map", &["get"]),
        ("/api/v1/map/{at}", &["get", "put"]),
        ("/api/v1/memory", &["get"]),
        ("/api/v1/transactions", &["get"]),
        ("/api/v1/transactions/{name}", &["get", "put"]),
        ("/api/v1/transactions/{name}/enable", &["post"]),
        ("/api/v1/transactions/{name}/disable", &["post"]),
        ("/api/v1/transactions/{name}/trigger", &["post"]),
        ("/api/v1/transactions/{name}/values", &["put"]),
        ("/api/v1/links/{link}/plan", &["get"]),
        ("/api/v1/mqtt", &["get"]),
        ("/api/v1/ha", &["get"]),
        ("/api/v1/config", &["get"]),
        ("/api/v1/config/reload", &["post"]),
        ("/api/v1/links/{link}/scan", &["post"]),
        ("/api/v1/scans/{id}", &["get", "delete"]),
        ("/api/v1/scans/{id}/events", &["get"]),
    ];
    let paths = doc["paths"].as_object().expect("paths");
    assert_eq!(paths.len(), routes.len(), "{:?}", paths.keys());
    for (path, methods) in routes {
        for method in *methods {
            let operation = &paths[*path][*method];
            assert!(operation.is_object(), "{method} {path} is not described");
            let responses = operation["responses"].as_object().expect("responses");
            assert!(!responses.is_empty(), "{method} {path} has no responses");
            // Every templated parameter is declared as a path parameter.
            for name in path.split('{').skip(1).filter_map(|p| p.split('}').next()) {
                let declared = operation["parameters"]
                    .as_array()
                    .is_some_and(|ps| ps.iter().any(|p| p["name"] == name && p["in"] == "path"));
                assert!(declared, "{method} {path}: parameter {name} not declared");
            }
        }
        // Writes and declarations describe their bodies and their refusals.
        for method in ["put", "patch", "post"] {
            let operation = &paths[*path][method];
            if operation.is_object() && operation["requestBody"].is_object() {
                assert!(
                    operation["requestBody"].is_object(),
                    "{method} {path} has no request body"
                );
                assert!(
                    operation["responses"]["400"].is_object(),
                    "{method} {path} does not describe 400"
                );
            }
        }
    }
    gw.shutdown().await;
}

const ADMIN: &str = "admin-token-0123456789";

/// schemathesis (an independent OpenAPI fuzzer) with every check, against a gateway with
/// tokens, simulated devices, a link to its own Modbus server and a standing transaction:
/// every answer's status and body as the document says, schema-valid requests accepted and
/// invalid ones refused, the token required, no 5xx. `tests/openapi/schemathesis.toml`
/// names what exists and says which refusals depend on a field's type at run time.
#[tokio::test]
async fn schemathesis_with_every_check_finds_nothing() {
    run_installer("openapi/install.sh").expect("schemathesis");
    let dir = temp_dir("schemathesis");
    let tokens = dir.join("tokens");
    std::fs::write(&tokens, format!("admin {ADMIN}\n")).expect("tokens");
    // From a file that stays, so that a reload reads it again.
    let config = dir.join("iogate.yaml");
    std::fs::write(
        &config,
        format!(
            "profiles: {}\nlisten: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\ndevices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}\n  - {{ name: plant, profile: SimPlant, refresh_rate: 100ms }}\nmodbus_server:\n  listen: 127.0.0.1:0\n  auto: true\nsecurity:\n  tokens_file: {}\n  declare:\n    tcp_hosts: [\"127.0.0.1\"]\n",
            iogate_tests::profiles_dir().display(),
            tokens.display()
        ),
    )
    .expect("config");
    let setup = iogate::app::Setup::from_file(&config).expect("a valid config");
    let gw = TestGateway::start_setup(setup).await.expect("gateway");
    let modbus = gw.modbus.expect("Modbus server");
    for (path, body) in [
        (
            "/api/v1/links/self",
            serde_json::json!({"tcp": {"host": "127.0.0.1", "port": modbus.port()}}),
        ),
        (
            "/api/v1/transactions/recipe",
            serde_json::json!({"link": "self", "function": 3, "slave": 1, "address": 1,
                "value_type": "UNSIGNED_NUMBER16", "byte_order": "BigEndian", "refresh_interval_ms": 1000}),
        ),
    ] {
        let answer = gw
            .client
            .put(gw.url(path))
            .bearer_auth(ADMIN)
            .json(&body)
            .send()
            .await
            .expect("declare");
        assert!(answer.status().is_success(), "{path}: {}", answer.status());
    }
    let output = tokio::process::Command::new(iogate_tests::python())
        .args(["-m", "schemathesis.cli", "--config-file"])
        .arg(repo_file("openapi/schemathesis.toml"))
        .arg("run")
        .arg(gw.url("/api/v1/openapi.json"))
        .args([
            "--checks",
            "all",
            "--max-examples",
            "30",
            "--seed",
            "1",
            "--url",
        ])
        .arg(&gw.base)
        .arg("-H")
        .arg(format!("Authorization: Bearer {ADMIN}"))
        .env("NO_COLOR", "1")
        // Its cache of failures goes with the test's files, not into the repository.
        .current_dir(&dir)
        .output()
        .await
        .expect("schemathesis runs");
    let report = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "schemathesis found problems:\n{report}\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    assert!(report.contains("passed"), "{report}");
    gw.shutdown().await;
}
