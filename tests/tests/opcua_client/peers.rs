//! Against node-opcua, a server of another stack with limits of its own: operation limits
//! published or only enforced, a server behind a port mapping, an import of 10,000
//! variables with one reachable by two paths.

use std::fmt::Write as _;

use iogate_tests::TestGateway;
use iogate_tests::cable::Cable;
use iogate_tests::devices::temp_dir;
use iogate_tests::node_ua::NodeUa;
use serde_json::Value;

/// A profile of `n` fields, Many.V0 .. V{n-1}.
fn many(n: usize) -> String {
    let mut text = "name: Many\nprotocol: opcua\nfields:\n".to_owned();
    for k in 0..n {
        let _ = writeln!(
            text,
            "  - {{ name: V{k}, type: DINT, direction: inout, node: \"ns=1;s=Many.V{k}\" }}"
        );
    }
    text
}

/// A gateway with two links to `url` (one subscribing, one reading every refresh), a
/// device of `n` fields on each.
async fn gateway(dir: &std::path::Path, url: &str, n: usize) -> anyhow::Result<TestGateway> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    std::fs::write(profiles.join("many.yaml"), many(n))?;
    let pki = dir.join("pki");
    let config = format!(
        "profiles: {}\nlinks:\n  - name: sub\n    opcua: {{ url: \"{url}\", pki_dir: {} }}\n  - name: poll\n    opcua: {{ url: \"{url}\", pki_dir: {}, subscribe: false }}\ndevices:\n  - {{ name: a, profile: Many, link: sub, refresh_rate: 200ms }}\n  - {{ name: b, profile: Many, link: poll, refresh_rate: 200ms }}\n",
        profiles.display(),
        pki.display(),
        pki.display()
    );
    TestGateway::start(&config).await
}

/// Every field of `device` good with its index as value.
async fn all_good(gw: &TestGateway, device: &str, n: usize) -> anyhow::Result<()> {
    let what = format!("every field of {device} good");
    gw.until(&format!("/api/v1/devices/{device}"), &what, |d| {
        (0..n).all(|k| {
            let f: &Value = &d["fields"][format!("V{k}")];
            f["quality"] == "good" && f["value"] == k
        })
    })
    .await?;
    Ok(())
}

async fn reads_within(args: &[&str], dir: &str) -> anyhow::Result<()> {
    let dir = temp_dir(dir);
    let server = NodeUa::start(dir.join("server-pki"), args).await?;
    let gw = gateway(&dir, &server.url, 500).await?;
    all_good(&gw, "a", 500).await?;
    all_good(&gw, "b", 500).await?;
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_taking_100_items_per_request_has_500_fields_read() -> anyhow::Result<()> {
    reads_within(&["--limits", "100", "--many", "500"], "ua-limits").await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn limits_enforced_but_not_published_are_learned() -> anyhow::Result<()> {
    reads_within(
        &["--limits", "100", "--hide-limits", "--many", "500"],
        "ua-hidden-limits",
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn limits_below_the_five_a_first_read_asks_are_read_and_kept() -> anyhow::Result<()> {
    let dir = temp_dir("ua-limits-3");
    let count = dir.join("refusals");
    let args = ["--limits", "3", "--many", "20", "--count-refusals"];
    let mut with_count: Vec<&str> = args.to_vec();
    let count_arg = count.display().to_string();
    with_count.push(&count_arg);
    let server = NodeUa::start(dir.join("server-pki"), &with_count).await?;
    let gw = gateway(&dir, &server.url, 20).await?;
    all_good(&gw, "a", 20).await?;
    all_good(&gw, "b", 20).await?;
    // Each link's first Read of the five limits is refused as too many; nothing after it.
    let refused: u32 = std::fs::read_to_string(&count)?.trim().parse()?;
    assert!(
        refused <= 2,
        "{refused} requests refused as too many operations"
    );
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_behind_a_port_mapping_is_dialled_where_configured() -> anyhow::Result<()> {
    let dir = temp_dir("ua-mapped");
    let server = NodeUa::start(dir.join("server-pki"), &["--many", "3"]).await?;
    // The server advertises its own port; the gateway knows only the mapped one.
    let mapped = Cable::to(server.port).await?;
    let url = format!("opc.tcp://127.0.0.1:{}/UA/Peer", mapped.port);
    let gw = gateway(&dir, &url, 3).await?;
    all_good(&gw, "a", 3).await?;
    all_good(&gw, "b", 3).await?;
    // Both sessions go through the mapping, not to the port the server advertises.
    assert_eq!(mapped.open(), 2, "sessions through the mapped port");
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ten_thousand_variables_import_and_one_reached_twice_is_one_field() -> anyhow::Result<()> {
    let dir = temp_dir("ua-import-10k");
    let server = NodeUa::start(
        dir.join("server-pki"),
        &["--limits", "1000", "--many", "10000", "--twice"],
    )
    .await?;
    let out = dir.join("profiles");
    let (url, to) = (server.url.clone(), out.clone());
    let started = std::time::Instant::now();
    let code = tokio::task::spawn_blocking(move || {
        iogate::drivers::opcua::import::run(&url, Some("ns=1;s=Line1"), Some(&to))
    })
    .await?;
    eprintln!("10,000 variables imported in {:?}", started.elapsed());
    assert_eq!(code, 0);
    let text = std::fs::read_to_string(out.join("Line1.yaml"))?;
    let fields = text.lines().filter(|l| l.starts_with("  - {")).count();
    assert_eq!(fields, 10_000, "{}", &text[..text.len().min(2000)]);
    assert_eq!(text.matches("s=Many.V0\"").count(), 1, "V0 once");
    assert!(text.contains("name: Many_V9999,"), "last variable");
    // The profile loads and reads: the last of them through a gateway.
    let config = format!(
        "profiles: {}\nlinks:\n  - name: plc\n    opcua: {{ url: \"{}\", pki_dir: {} }}\ndevices:\n  - {{ name: line1, profile: Line1, link: plc, refresh_rate: 500ms }}\n",
        out.display(),
        server.url,
        dir.join("pki").display()
    );
    let gw = TestGateway::start(&config).await?;
    gw.until("/api/v1/devices/line1", "Many_V9999 read", |d| {
        d["fields"]["Many_V9999"]["value"] == 9999
    })
    .await?;
    gw.shutdown().await;
    Ok(())
}

/// A gateway with one secure link to `url` trusting `server`'s certificate, `extra` more
/// of the link's settings.
async fn secure(
    dir: &std::path::Path,
    server: &NodeUa,
    url: &str,
    extra: &str,
) -> anyhow::Result<TestGateway> {
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles)?;
    std::fs::write(profiles.join("many.yaml"), many(3))?;
    let config = format!(
        "profiles: {}\nlinks:\n  - name: sub\n    opcua: {{ url: \"{url}\", pki_dir: {}, security_policy: Basic256Sha256, security_mode: SignAndEncrypt, trusted: [{}]{extra} }}\ndevices:\n  - {{ name: a, profile: Many, link: sub, refresh_rate: 200ms }}\n",
        profiles.display(),
        dir.join("pki").display(),
        server.pki.join("own/certs/certificate.pem").display()
    );
    TestGateway::start(&config).await
}

/// The machine's host name, which node-opcua's certificate carries as its first entry.
fn host_name() -> anyhow::Result<String> {
    let out = std::process::Command::new("hostname").output()?;
    Ok(String::from_utf8(out.stdout)?.trim().to_owned())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_trusted_certificate_listing_its_dns_name_first_is_accepted() -> anyhow::Result<()> {
    let dir = temp_dir("ua-dns-first");
    let server = NodeUa::start(dir.join("server-pki"), &["--many", "3", "--secure"]).await?;
    let url = format!("opc.tcp://{}:{}/UA/Peer", host_name()?, server.port);
    let gw = secure(&dir, &server, &url, "").await?;
    all_good(&gw, "a", 3).await?;
    gw.shutdown().await;
    // Started again: the key pair made the first time is read from the PKI directory.
    let gw = secure(&dir, &server, &url, "").await?;
    all_good(&gw, "a", 3).await?;
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_host_the_certificate_does_not_name_is_refused_unless_accepted() -> anyhow::Result<()> {
    let dir = temp_dir("ua-host-mismatch");
    let server = NodeUa::start(dir.join("server-pki"), &["--many", "3", "--secure"]).await?;
    // 127.0.0.1 is not among the certificate's names.
    let url = format!("opc.tcp://127.0.0.1:{}/UA/Peer", server.port);
    let gw = secure(&dir, &server, &url, "").await?;
    let refused = gw
        .until("/api/v1/devices/a", "the refusal", |d| {
            d["fields"]["V0"]["error"]
                .as_str()
                .is_some_and(|e| e.contains("BadCertificateHostNameInvalid"))
        })
        .await?;
    assert_eq!(refused["fields"]["V0"]["quality"], "bad", "{refused}");
    // The link's view says why it is down, in words.
    let (_, link) = gw.get("/api/v1/links/sub").await?;
    let why = link["error"].as_str().unwrap_or_default();
    assert!(why.contains("BadCertificateHostNameInvalid"), "{link}");
    gw.shutdown().await;
    let gw = secure(&dir, &server, &url, ", accept_host_mismatch: true").await?;
    all_good(&gw, "a", 3).await?;
    gw.shutdown().await;
    Ok(())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_that_refuses_anonymous_users_is_named_so() -> anyhow::Result<()> {
    let dir = temp_dir("ua-no-anonymous");
    let server = NodeUa::start(dir.join("server-pki"), &["--many", "3", "--no-anonymous"]).await?;
    let gw = gateway(&dir, &server.url, 3).await?;
    let link = gw
        .until("/api/v1/links/sub", "the refusal", |l| {
            l["error"].is_string()
        })
        .await?;
    let why = link["error"].as_str().unwrap_or_default();
    assert!(why.contains("does not take anonymous users"), "{link}");
    gw.shutdown().await;
    Ok(())
}
