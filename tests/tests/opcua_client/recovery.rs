//! Recovery without an operator: the server restarted with its namespaces reordered, a
//! server without subscriptions, a dropped subscription; a secure channel refused until
//! each side trusts the other.

use iogate_tests::devices::temp_dir;
use iogate_tests::plc::UaPlc;
use serde_json::json;

use super::{gateway, until_field};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_restarted_with_its_namespaces_reordered_is_read_again_without_an_operator()
-> anyhow::Result<()> {
    let dir = temp_dir("uaclient-restart");
    let mut plc = UaPlc::start(&[]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    until_field(&gw, "I", "read", |f| f["quality"] == "good").await?;
    plc.set("Int", json!(11)).await?;
    until_field(&gw, "I", "11", |f| f["value"] == json!(11)).await?;
    let port = plc.port();
    plc.kill().await?;
    // While the server is away its values stay, stale, with why.
    let away = until_field(&gw, "I", "stale", |f| f["quality"] == "stale").await?;
    assert_eq!(away["value"], json!(11), "{away}");
    assert!(away["error"].is_string(), "{away}");
    let link = gw
        .until("/api/v1/links/plc", "link down", |l| {
            l["connected"] == false
        })
        .await?;
    assert_eq!(link["kind"], "opcua", "{link}");
    // Back with two namespaces before ours: the profile's `ns=2` is found by its URI.
    let mut plc = UaPlc::start(&["--port", &port, "--reorder"]).await?;
    assert_eq!(plc.ns, 4);
    plc.set("Int", json!(22)).await?;
    let back = until_field(&gw, "I", "fresh again", |f| {
        f["quality"] == "good" && f["value"] == json!(22)
    })
    .await?;
    assert!(back["error"].is_null(), "{back}");
    gw.until("/api/v1/links/plc", "link up", |l| l["connected"] == true)
        .await?;
    let reconnects = gw.metrics().await?;
    assert!(
        reconnects.contains("iogate_link_reconnects_total{link=\"plc\"} 1"),
        "{}",
        reconnects
            .lines()
            .filter(|l| l.contains("reconnect"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_without_subscriptions_is_read_every_refresh() -> anyhow::Result<()> {
    let dir = temp_dir("uaclient-reads");
    let mut plc = UaPlc::start(&["--no-subscriptions"]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    until_field(&gw, "UI", "read", |f| f["value"] == json!(60000)).await?;
    plc.set("UInt", json!(5)).await?;
    until_field(&gw, "UI", "read again", |f| f["value"] == json!(5)).await?;
    let subscriptions = plc.cmd(json!({"cmd": "subscriptions"})).await?;
    assert_eq!(subscriptions["count"], 0);
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscription_the_server_drops_is_made_again() -> anyhow::Result<()> {
    let dir = temp_dir("uaclient-dropped");
    let mut plc = UaPlc::start(&[]).await?;
    let gw = gateway(&dir, &plc, "").await?;
    until_field(&gw, "UDI", "read", |f| f["quality"] == "good").await?;
    let dropped_at = std::time::Instant::now();
    let dropped = plc.cmd(json!({"cmd": "drop_subscriptions"})).await?;
    assert_eq!(dropped["dropped"], 1);
    plc.set("UDInt", json!(77)).await?;
    // The server answers the next publish request "no subscription": it is made again at
    // once and reports the change (waiting for three keep-alives and a request's timeout
    // took 11 s and more, the old value good all the while).
    until_field(&gw, "UDI", "the change after the drop", |f| {
        f["value"] == json!(77) && f["quality"] == "good"
    })
    .await?;
    let took = dropped_at.elapsed();
    assert!(
        took < std::time::Duration::from_secs(8),
        "fresh after {took:?}"
    );
    println!("a deleted subscription's values fresh again after {took:?}");
    assert_eq!(plc.cmd(json!({"cmd": "subscriptions"})).await?["count"], 1);
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sign_and_encrypt_connects_once_each_side_trusts_the_others_certificate()
-> anyhow::Result<()> {
    let dir = temp_dir("uaclient-secure");
    let trusted = dir.join("plc-trusted");
    std::fs::create_dir_all(&trusted)?;
    let (cert, key) = (dir.join("plc.der"), dir.join("plc.pem"));
    let security = |plc_args: &mut Vec<String>| {
        plc_args.extend(["--security".into(), cert.display().to_string()]);
        plc_args.extend([key.display().to_string(), trusted.display().to_string()]);
    };
    let mut args = Vec::new();
    security(&mut args);
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let plc = UaPlc::start(&refs).await?;
    // The gateway's application certificate, made by the PLC's library.
    let (own, own_key) = (dir.join("iogate.der"), dir.join("iogate.pem"));
    let made = std::process::Command::new(iogate_tests::python())
        .arg(iogate_tests::repo_file("opcua/plc.py"))
        .args(["--client-cert", &own.display().to_string()])
        .arg(&own_key)
        .output()?;
    anyhow::ensure!(made.status.success(), "{made:?}");
    // The gateway trusts the PLC's certificate; the PLC does not know the gateway's yet.
    let extra = format!(
        ", security_policy: Basic256Sha256, certificate: {}, private_key: {}, trusted: [{}]",
        own.display(),
        own_key.display(),
        cert.display()
    );
    let gw = gateway(&dir, &plc, &extra).await?;
    let refused = gw
        .until("/api/v1/links/plc", "refused", |l| l["error_code"] == 2)
        .await?;
    assert_eq!(refused["connected"], false, "{refused}");
    // Named in the server's words where users look: the field and the link.
    let untrusted = until_field(&gw, "I", "the refusal", |f| {
        f["error"]
            .as_str()
            .is_some_and(|e| e.contains("BadCertificateUntrusted"))
    })
    .await?;
    assert_eq!(untrusted["quality"], "bad", "{untrusted}");
    // Trusted by the PLC (restarted, on the same port), the gateway's next attempt gets in.
    std::fs::copy(&own, trusted.join("iogate.der"))?;
    let port = plc.port();
    plc.kill().await?;
    let mut args = vec!["--port".to_owned(), port];
    security(&mut args);
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let mut plc = UaPlc::start(&refs).await?;
    until_field(&gw, "I", "read over a secure channel", |f| {
        f["quality"] == "good"
    })
    .await?;
    plc.set("Int", json!(5)).await?;
    until_field(&gw, "I", "a change over it", |f| f["value"] == json!(5)).await?;
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_that_wants_a_user_gets_the_one_in_the_password_file() -> anyhow::Result<()> {
    let dir = temp_dir("uaclient-user");
    let plc = UaPlc::start(&["--user", "operator", "s3cret"]).await?;
    let wrong = dir.join("wrong.pw");
    std::fs::write(&wrong, "guess\n")?;
    let extra = format!(
        ", user: {{ username: operator, password_file: {} }}",
        wrong.display()
    );
    let gw = gateway(&dir, &plc, &extra).await?;
    let refused = until_field(&gw, "I", "refused", |f| {
        f["error"].as_str().is_some_and(|e| e.contains("Bad"))
    })
    .await?;
    assert_eq!(refused["quality"], "bad", "{refused}");
    gw.shutdown().await;

    let right = dir.join("right.pw");
    std::fs::write(&right, "s3cret\n")?;
    let extra = format!(
        ", user: {{ username: operator, password_file: {} }}",
        right.display()
    );
    let gw = gateway(&dir, &plc, &extra).await?;
    until_field(&gw, "I", "read as the user", |f| f["quality"] == "good").await?;
    gw.shutdown().await;
    plc.kill().await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reload_moves_an_opcua_link_to_another_server() -> anyhow::Result<()> {
    let mut a = UaPlc::start(&[]).await?;
    let mut b = UaPlc::start(&[]).await?;
    a.set("Int", json!(1)).await?;
    b.set("Int", json!(2)).await?;
    let config = |url: &str| {
        format!(
            "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: profiles\nlinks:\n  - name: plc\n    opcua: {{ url: \"{url}\", pki_dir: pki }}\ndevices:\n  - {{ name: line1, profile: TestPlc, link: plc, refresh_rate: 100ms }}\n"
        )
    };
    let (_, path) = iogate_tests::config_files(
        "uaclient-reload",
        &[("plc.yaml", super::PROFILE)],
        &config(&a.url),
    );
    let gw = iogate_tests::start_file(&path).await;
    until_field(&gw, "I", "server A's value", |f| f["value"] == json!(1)).await?;
    std::fs::write(&path, config(&b.url))?;
    let (status, report) = gw
        .send(reqwest::Method::POST, "/api/v1/config/reload", "")
        .await?;
    assert_eq!(status, 200, "{report}");
    until_field(&gw, "I", "server B's value", |f| {
        f["value"] == json!(2) && f["quality"] == "good"
    })
    .await?;
    let link = gw.get("/api/v1/links/plc").await?.1;
    assert_eq!(link["endpoint"], b.url.as_str(), "{link}");
    gw.shutdown().await;
    a.kill().await?;
    b.kill().await
}
