//! TLS end to end: REST and gRPC over TLS with a test CA, the certificate replaced on disk
//! while the gateway runs, and client certificates required when `client_ca` is set.

use std::path::{Path, PathBuf};
use std::time::Duration;

use iogate::app::{self, Running, Setup};
use iogate_proto::pb::ListDevicesRequest;
use iogate_proto::pb::gateway_client::GatewayClient;
use iogate_tests::devices::temp_dir;
use iogate_tests::pki::{Pem, TestCa};
use iogate_tests::{eventually, profiles_dir};
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Identity};

struct Files {
    dir: PathBuf,
}

impl Files {
    fn new(server: &Pem) -> Files {
        let files = Files {
            dir: temp_dir("tls"),
        };
        files.put(server);
        files
    }

    fn put(&self, server: &Pem) {
        // Key first, then the certificate: a reload in between sees a pair that does not
        // match, keeps the old one, and takes the new pair on its next look.
        std::fs::write(self.dir.join("server.key"), &server.key).expect("key");
        std::fs::write(self.dir.join("server.pem"), &server.cert).expect("cert");
    }

    fn config(&self, client_ca: Option<&str>) -> String {
        let client_ca = client_ca.map_or(String::new(), |pem| {
            let path = self.dir.join("ca.pem");
            std::fs::write(&path, pem).expect("client ca");
            format!(", client_ca: {}", path.display())
        });
        format!(
            "devices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 20ms }}\nsecurity:\n  tls: {{ cert: {}, key: {}{client_ca} }}\n",
            self.dir.join("server.pem").display(),
            self.dir.join("server.key").display(),
        )
    }
}

async fn start(yaml: &str) -> Running {
    let mut config = iogate::config::parse("tls.yaml", yaml).expect("config");
    config.http = "127.0.0.1:0".parse().expect("addr");
    config.grpc = "127.0.0.1:0".parse().expect("addr");
    config.profiles = Some(profiles_dir());
    let setup = Setup::from_config(config, Path::new(".")).expect("setup");
    app::start(setup).await.expect("start")
}

fn https(ca: &TestCa, identity: Option<&Pem>) -> reqwest::Client {
    let mut builder = reqwest::Client::builder()
        .use_rustls_tls()
        .tls_built_in_root_certs(false)
        .add_root_certificate(reqwest::Certificate::from_pem(ca.pem().as_bytes()).expect("ca"))
        .timeout(Duration::from_secs(5));
    if let Some(identity) = identity {
        builder = builder
            .identity(reqwest::Identity::from_pem(identity.identity().as_bytes()).expect("id"));
    }
    builder.build().expect("client")
}

async fn grpc(
    running: &Running,
    ca: &TestCa,
    identity: Option<&Pem>,
) -> Result<GatewayClient<Channel>, tonic::transport::Error> {
    let mut tls = ClientTlsConfig::new()
        .ca_certificate(Certificate::from_pem(ca.pem()))
        .domain_name("localhost");
    if let Some(identity) = identity {
        tls = tls.identity(Identity::from_pem(&identity.cert, &identity.key));
    }
    let channel = Channel::from_shared(format!("https://localhost:{}", running.grpc_addr.port()))
        .expect("uri")
        .tls_config(tls)?
        .connect()
        .await?;
    Ok(GatewayClient::new(channel))
}

fn url(running: &Running, path: &str) -> String {
    format!("https://localhost:{}{path}", running.http_addr.port())
}

async fn devices_over_rest(client: &reqwest::Client, running: &Running) -> Option<usize> {
    let response = client
        .get(url(running, "/api/v1/devices"))
        .send()
        .await
        .ok()?;
    let body: serde_json::Value = response.json().await.ok()?;
    body["devices"].as_array().map(Vec::len)
}

#[tokio::test]
async fn rest_and_grpc_are_served_over_tls_and_plain_text_is_not() {
    let ca = TestCa::new("iogate test CA").expect("ca");
    let files = Files::new(&ca.server().expect("server"));
    let running = start(&files.config(None)).await;

    let client = https(&ca, None);
    assert_eq!(devices_over_rest(&client, &running).await, Some(1));
    // HTTP/2 is offered by ALPN on the HTTP listener too.
    let response = client
        .get(url(&running, "/livez"))
        .send()
        .await
        .expect("livez");
    assert_eq!(response.version(), reqwest::Version::HTTP_2);

    let mut grpc_client = grpc(&running, &ca, None).await.expect("gRPC over TLS");
    let listed = grpc_client
        .list_devices(ListDevicesRequest::default())
        .await
        .expect("ListDevices");
    assert_eq!(listed.into_inner().devices.len(), 1);

    // Plain HTTP on the TLS port gets no answer; a client trusting another CA is refused.
    let plain = reqwest::Client::builder()
        .timeout(Duration::from_secs(5))
        .build()
        .expect("client");
    let answered = plain
        .get(format!(
            "http://127.0.0.1:{}/livez",
            running.http_addr.port()
        ))
        .send()
        .await;
    assert!(
        answered.is_err(),
        "plain text answered: {:?}",
        answered.map(|r| r.status())
    );
    let stranger = TestCa::new("another CA").expect("ca");
    assert_eq!(
        devices_over_rest(&https(&stranger, None), &running).await,
        None
    );
    assert!(grpc(&running, &stranger, None).await.is_err());
    running.shutdown().await;
}

#[tokio::test]
async fn a_replaced_certificate_serves_new_connections_and_open_ones_stay() {
    let old_ca = TestCa::new("old CA").expect("ca");
    let files = Files::new(&old_ca.server().expect("server"));
    let running = start(&files.config(None)).await;
    let mut open = grpc(&running, &old_ca, None).await.expect("gRPC");
    let old_client = https(&old_ca, None);
    assert_eq!(devices_over_rest(&old_client, &running).await, Some(1));

    let new_ca = TestCa::new("new CA").expect("ca");
    files.put(&new_ca.server().expect("server"));
    let new_client = https(&new_ca, None);
    eventually("the new certificate is served", || async {
        devices_over_rest(&https(&new_ca, None), &running).await == Some(1)
    })
    .await
    .expect("reloaded");
    assert_eq!(devices_over_rest(&new_client, &running).await, Some(1));
    assert_eq!(
        devices_over_rest(&https(&old_ca, None), &running).await,
        None,
        "a new connection no longer gets the old certificate"
    );
    // The connection opened before the change was not dropped.
    let listed = open
        .list_devices(ListDevicesRequest::default())
        .await
        .expect("the open gRPC connection still answers");
    assert_eq!(listed.into_inner().devices.len(), 1);
    running.shutdown().await;
}

#[tokio::test]
async fn with_client_ca_a_client_certificate_is_required() {
    let server_ca = TestCa::new("server CA").expect("ca");
    let client_ca = TestCa::new("client CA").expect("ca");
    let files = Files::new(&server_ca.server().expect("server"));
    let running = start(&files.config(Some(&client_ca.pem()))).await;
    let operator = client_ca.client("operator").expect("client cert");

    assert_eq!(
        devices_over_rest(&https(&server_ca, None), &running).await,
        None,
        "no client certificate"
    );
    let outsider = TestCa::new("outsider")
        .expect("ca")
        .client("x")
        .expect("cert");
    assert_eq!(
        devices_over_rest(&https(&server_ca, Some(&outsider)), &running).await,
        None,
        "a certificate from another CA"
    );
    assert_eq!(
        devices_over_rest(&https(&server_ca, Some(&operator)), &running).await,
        Some(1)
    );
    let mut client = grpc(&running, &server_ca, Some(&operator))
        .await
        .expect("gRPC with a client certificate");
    client
        .list_devices(ListDevicesRequest::default())
        .await
        .expect("ListDevices");
    // Without one, the handshake fails at the first call at the latest.
    let refused = match grpc(&running, &server_ca, None).await {
        Err(_) => true,
        Ok(mut c) => c.list_devices(ListDevicesRequest::default()).await.is_err(),
    };
    assert!(refused, "gRPC without a client certificate");
    running.shutdown().await;
}

#[tokio::test]
async fn tls_files_that_do_not_load_are_config_problems() {
    let dir = temp_dir("tls-bad");
    let cert = dir.join("server.pem");
    let key = dir.join("server.key");
    let ca = TestCa::new("ca").expect("ca");
    let other = ca.server().expect("server");
    let server = ca.server().expect("server");
    std::fs::write(&cert, &server.cert).expect("cert");
    // A key that belongs to another certificate.
    std::fs::write(&key, &other.key).expect("key");
    let yaml = format!(
        "devices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 20ms }}\nsecurity:\n  tls: {{ cert: {}, key: {} }}\n",
        cert.display(),
        key.display()
    );
    let mut config = iogate::config::parse("tls.yaml", &yaml).expect("parses");
    config.profiles = Some(profiles_dir());
    let problems = Setup::from_config(config, Path::new("."))
        .expect_err("mismatched key")
        .to_string();
    assert!(problems.contains("security.tls"), "{problems}");
    assert!(
        !problems.contains("PRIVATE KEY"),
        "never the key: {problems}"
    );

    std::fs::write(&key, "garbage").expect("key");
    let mut config = iogate::config::parse("tls.yaml", &yaml).expect("parses");
    config.profiles = Some(profiles_dir());
    let problems = Setup::from_config(config, Path::new("."))
        .expect_err("no key")
        .to_string();
    assert!(
        problems.contains("server.key") && problems.contains("private key"),
        "{problems}"
    );

    let problems = iogate::config::parse("tls.yaml", "security:\n  tls: { cert: a.pem }\n")
        .expect_err("no key")
        .to_string();
    assert!(problems.contains("security.tls"), "{problems}");
}
