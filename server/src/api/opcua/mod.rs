//! The OPC UA front-end: an OPC UA server (the `async-opcua` library) whose address space
//! is the running devices and links (`space.rs`), fed from the service's change streams
//! (`feed.rs`, `nodes.rs`): values with status codes from their quality and the time the device was
//! read, subscriptions and monitored items with the library's sampling, queues and
//! deadband filters, writes checked and requested by the service as REST's are, and
//! sessions signed in with the gateway's bearer tokens (`auth.rs`).
//!
//! Like every front-end it only renders the service.

mod auth;
pub(crate) mod config;
mod exposure;
mod feed;
mod front_end;
mod live;
mod metrics;
mod nodes;
mod redundancy;
mod space;
mod status;

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;

use opcua::crypto::SecurityPolicy;
use opcua::server::{ServerBuilder, ServerHandle};
use opcua::types::{BuildInfo, DateTime, MessageSecurityMode, NodeId, VariableId, Variant};

use crate::api::opcua::config::{Endpoint, OpcUaConfig};
use crate::service::Service;
pub(crate) use front_end::OpcUaFrontEnd;
use metrics::OpcUaStatus;
use space::Ids;
pub(crate) use status::OpcUaState;
use status::Probe;

/// Nodes (or items) in one call of each service, at most, as advertised in
/// ServerCapabilities/OperationLimits.
const MAX_OPERATIONS: usize = 1000;
/// The shortest publishing and sampling interval a client is granted, and how often the
/// library's subscriptions are looked at: a change reaches a client asking for the
/// shortest interval within about this long (the library's default is 100 ms). A look
/// at subscriptions whose interval has not elapsed is a comparison each.
const MIN_INTERVAL_MS: u64 = 10;
/// Elements of an array in a message, at most (the message size bounds them too).
const MAX_ARRAY_LENGTH: usize = 10_000;

/// The namespace of the devices' and links' nodes.
pub(crate) const NAMESPACE: &str = "urn:iogate:devices";

fn security(e: Endpoint) -> (SecurityPolicy, MessageSecurityMode) {
    match e {
        Endpoint::None => (SecurityPolicy::None, MessageSecurityMode::None),
        Endpoint::Basic256Sha256Sign => (SecurityPolicy::Basic256Sha256, MessageSecurityMode::Sign),
        Endpoint::Basic256Sha256SignEncrypt => (
            SecurityPolicy::Basic256Sha256,
            MessageSecurityMode::SignAndEncrypt,
        ),
        Endpoint::Aes256Sha256RsaPssSign => (
            SecurityPolicy::Aes256Sha256RsaPss,
            MessageSecurityMode::Sign,
        ),
        Endpoint::Aes256Sha256RsaPssSignEncrypt => (
            SecurityPolicy::Aes256Sha256RsaPss,
            MessageSecurityMode::SignAndEncrypt,
        ),
    }
}

/// The host name endpoint URLs carry: the listener's address, or for a wildcard listener
/// the machine's name.
fn endpoint_host(addr: SocketAddr) -> String {
    if !addr.ip().is_unspecified() {
        return match addr {
            SocketAddr::V6(v6) => format!("[{}]", v6.ip()),
            SocketAddr::V4(v4) => v4.ip().to_string(),
        };
    }
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|h| h.trim().to_owned())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "localhost".to_owned())
}

/// The running server, to stop it (a reload that changes the `opcua:` section). Dropping
/// it leaves the server running until the gateway shuts down.
pub(crate) struct Running {
    stop: tokio_util::sync::CancellationToken,
    stopped: tokio::sync::oneshot::Receiver<()>,
    service: std::sync::Weak<Service>,
}

/// What differs between two `opcua:` sections, key by key, in a reload report's words (a
/// change restarts the server).
pub(crate) fn changed_keys(x: &OpcUaConfig, y: &OpcUaConfig) -> Vec<Option<String>> {
    use crate::service::{changed, changed_text};
    vec![
        changed_text("listen", x.listen, y.listen),
        changed_text("application_uri", &x.application_uri, &y.application_uri),
        (x.security != y.security).then(|| "security changed".to_owned()),
        changed("pki_dir", &x.pki_dir, &y.pki_dir),
        (x.certificate != y.certificate || x.private_key != y.private_key)
            .then(|| "certificate changed".to_owned()),
        changed_text(
            "trust_client_certs",
            x.trust_client_certs,
            y.trust_client_certs,
        ),
        changed("anonymous", &x.anonymous, &y.anonymous),
        changed_text("max_sessions", x.max_sessions, y.max_sessions),
        changed_text(
            "max_subscriptions_per_session",
            x.max_subscriptions_per_session,
            y.max_subscriptions_per_session,
        ),
        changed_text(
            "max_monitored_items_per_subscription",
            x.max_monitored_items_per_subscription,
            y.max_monitored_items_per_subscription,
        ),
    ]
}

/// How long a stopping server may take to close its sessions.
const STOP_WAIT: std::time::Duration = std::time::Duration::from_secs(10);

impl Running {
    /// Stops the server (its sessions are closed, its port released) and its feed.
    pub(crate) async fn stop(self) -> Result<(), String> {
        self.stop.cancel();
        if let Some(service) = self.service.upgrade() {
            service.doors.detach("opcua");
            service.listening.remove("opcua");
        }
        tokio::time::timeout(STOP_WAIT, self.stopped)
            .await
            .map(|_| ())
            .map_err(|_| {
                format!(
                    "the OPC UA server did not stop within {}s",
                    STOP_WAIT.as_secs()
                )
            })
    }
}

/// The server's bounds: sessions, every session's subscriptions together, monitored items.
fn limits(config: &OpcUaConfig) -> [usize; 5] {
    let subscriptions = config.max_sessions * config.max_subscriptions_per_session;
    [
        config.max_sessions,
        subscriptions,
        config.max_monitored_items,
        config.max_connections,
        config.max_connections_per_client,
    ]
}

/// Reads what only the library knows (its diagnostics summary) and counts the client
/// certificates waiting in `rejected`.
fn probe(handle: Arc<std::sync::OnceLock<ServerHandle>>, rejected: std::path::PathBuf) -> Probe {
    Box::new(move |s: &mut OpcUaStatus| {
        if let Some(handle) = handle.get() {
            let diagnostics = &handle.info().diagnostics;
            let count = |id| match diagnostics.get(id).and_then(|v| v.value) {
                Some(Variant::UInt32(n)) => u64::from(n),
                _ => 0,
            };
            s.sessions = count(
                VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary_CurrentSessionCount,
            );
            s.sessions_created = count(
                VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary_CumulatedSessionCount,
            );
            s.sessions_refused = count(
                VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary_RejectedSessionCount,
            );
            s.subscriptions = count(VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary_CurrentSubscriptionCount);
            s.security_rejected = count(VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary_SecurityRejectedSessionCount)
                + count(VariableId::Server_ServerDiagnostics_ServerDiagnosticsSummary_SecurityRejectedRequestsCount);
            let connections = &handle.info().connections;
            let (open, most) = connections.open();
            s.connections = open as u64;
            s.connections_most_from_one = most as u64;
            s.connections_refused = connections
                .refused
                .load(std::sync::atomic::Ordering::Relaxed);
            s.connections_refused_per_client = connections
                .refused_per_client
                .load(std::sync::atomic::Ordering::Relaxed);
        }
        s.rejected_certificates = std::fs::read_dir(&rejected)
            .map(|entries| {
                entries
                    .filter_map(Result::ok)
                    .filter(|e| e.path().is_file())
                    .count() as u64
            })
            .unwrap_or(0);
    })
}

/// Makes the server's private key (made by the library, world-readable) readable by the
/// gateway's user alone: the directory 0700, each file in it 0600.
fn keep_private(dir: &Path) -> Result<(), String> {
    use std::os::unix::fs::PermissionsExt;
    let set = |path: &Path, mode: u32| {
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode))
            .map_err(|e| format!("opcua.pki_dir {}: {e}", path.display()))
    };
    if !dir.is_dir() {
        return Ok(());
    }
    set(dir, 0o700)?;
    let entries =
        std::fs::read_dir(dir).map_err(|e| format!("opcua.pki_dir {}: {e}", dir.display()))?;
    for entry in entries.filter_map(Result::ok) {
        if entry.path().is_file() {
            set(&entry.path(), 0o600)?;
        }
    }
    Ok(())
}

/// Starts the server on `config.listen` (bound here: a listener that cannot be bound stops
/// the start) and the task that keeps its address space; both end with the gateway or
/// [`Running::stop`].
pub(crate) async fn start(
    service: &Arc<Service>,
    config: &OpcUaConfig,
    base: &Path,
) -> Result<Running, String> {
    let pki = base.join(&config.pki_dir);
    // Without a secure endpoint no certificate is used: nothing is made or written.
    let secure = config.security.iter().any(|e| *e != Endpoint::None);
    if secure {
        std::fs::create_dir_all(&pki)
            .map_err(|e| format!("opcua.pki_dir {}: {e}", pki.display()))?;
    }
    let listener = tokio::net::TcpListener::bind(config.listen)
        .await
        .map_err(|e| {
            format!(
                "cannot listen on {} (opcua.listen, or serve --opcua ADDR; port 0 takes any free one): {e}",
                config.listen
            )
        })?;
    let addr = listener
        .local_addr()
        .map_err(|e| format!("opcua.listen {}: {e}", config.listen))?;
    service
        .listening
        .set("opcua", addr, format!("opc.tcp://{addr}/"));
    let token = service.tasks().token().child_token();
    let server_handle: Arc<std::sync::OnceLock<ServerHandle>> = Arc::default();
    let counts = Arc::new(OpcUaState::new(
        probe(server_handle.clone(), pki.join("rejected")),
        limits(config),
        service.metrics.kept(metrics::OpcUaMetrics::new),
    ));
    let mut builder =
        builder(service, config, &pki, addr, secure, counts.clone()).token(token.clone());
    builder = with_certificate(builder, config, base)?;
    set_limits(&mut builder, config);
    for endpoint in &config.security {
        let (policy, mode) = security(*endpoint);
        let none: &[&str] = &[];
        builder = builder.add_endpoint(endpoint.name(), ("/", policy, mode, none));
    }
    let (server, handle) = builder.build().map_err(|e| format!("OPC UA server: {e}"))?;
    if secure {
        keep_private(&pki.join("private"))?;
    }
    let _ = server_handle.set(handle.clone());
    if secure && handle.info().server_certificate.is_none() {
        return Err(format!(
            "OPC UA server: no application certificate (looked for it and could not make one in {})",
            pki.display()
        ));
    }
    let (manager, ids) = address_space(&handle)?;
    let feed = feed::Feed {
        service: service.clone(),
        manager,
        subscriptions: handle.subscriptions().clone(),
        ids,
        counts: counts.clone(),
    };
    service.tasks().spawn(feed.run(token.clone()));
    service.tasks().spawn(redundancy::follow(
        handle.clone(),
        service.tasks().role().clone(),
        config.application_uri.clone(),
        token.clone(),
    ));
    let (done, stopped) = tokio::sync::oneshot::channel();
    service.tasks().spawn(async move {
        if let Err(e) = server.run_with(listener).await {
            tracing::error!(error = %e, "the OPC UA server stopped");
        }
        let _ = done.send(());
    });
    tracing::info!(%addr, endpoints = ?config.security.iter().map(|e| e.name()).collect::<Vec<_>>(), "serving OPC UA");
    service.doors.attach(counts);
    Ok(Running {
        stop: token,
        stopped,
        service: Arc::downgrade(service),
    })
}

/// The server as the library builds it: its identity, address, PKI directory, access and
/// node manager.
fn builder(
    service: &Arc<Service>,
    config: &OpcUaConfig,
    pki: &Path,
    addr: std::net::SocketAddr,
    secure: bool,
    counts: Arc<OpcUaState>,
) -> ServerBuilder {
    let host = endpoint_host(addr);
    ServerBuilder::new()
        .application_name("iogate")
        .application_uri(redundancy::application_uri(
            &config.application_uri,
            service.tasks().role().node(),
        ))
        .product_uri("urn:iogate")
        .build_info(BuildInfo {
            product_uri: "urn:iogate".into(),
            manufacturer_name: "iogate".into(),
            product_name: "iogate I/O gateway".into(),
            software_version: env!("CARGO_PKG_VERSION").into(),
            build_number: env!("CARGO_PKG_VERSION").into(),
            build_date: DateTime::now(),
        })
        .host(host.clone())
        .port(addr.port())
        .discovery_urls(vec![format!("opc.tcp://{host}:{}/", addr.port())])
        .pki_dir(pki)
        .create_sample_keypair(secure && config.certificate.is_none())
        .trust_client_certs(config.trust_client_certs)
        .with_authenticator(Arc::new(auth::Authenticator::new(
            service.clone(),
            config.anonymous,
        )))
        .with_node_manager(nodes::builder(NAMESPACE, Arc::downgrade(service), counts))
        .max_sessions(config.max_sessions)
        .subscription_poll_interval_ms(MIN_INTERVAL_MS)
        // The library's counts (sessions, subscriptions, rejections) for the metrics; the
        // Server's diagnostics nodes stay unreadable to sessions (no diagnostics role).
        .diagnostics_enabled(true)
}

/// The application certificate and key the section names, when it names them.
fn with_certificate(
    mut builder: ServerBuilder,
    config: &OpcUaConfig,
    base: &Path,
) -> Result<ServerBuilder, String> {
    if let (Some(cert), Some(key)) = (&config.certificate, &config.private_key) {
        let (cert, key) = (base.join(cert), base.join(key));
        for (what, file) in [("opcua.certificate", &cert), ("opcua.private_key", &key)] {
            if !file.is_file() {
                return Err(format!("{what} {}: no such file", file.display()));
            }
        }
        builder = builder.certificate_path(cert).private_key_path(key);
    }
    Ok(builder)
}

/// Browse continuation points a session keeps, and every session together.
pub(crate) const BROWSE_POINTS_PER_SESSION: usize = 100;
pub(crate) const BROWSE_POINTS: usize = 5_000;

/// The limits the server advertises and keeps.
fn set_limits(builder: &mut ServerBuilder, config: &OpcUaConfig) {
    {
        let limits = builder.limits_mut();
        limits.subscriptions.max_subscriptions_per_session = config.max_subscriptions_per_session;
        limits.subscriptions.max_monitored_items_per_sub =
            config.max_monitored_items_per_subscription;
        limits.max_connections = config.max_connections;
        limits.max_connections_per_client = config.max_connections_per_client;
        // A browse continuation point holds about 5.4 KiB: a session keeps its newest 100
        // (the oldest gives way), every session together 5,000 (Bad_NoContinuationPoints).
        limits.max_browse_continuation_points = BROWSE_POINTS_PER_SESSION;
        limits.max_browse_continuation_points_total = BROWSE_POINTS;
        // A publish answer carries at most this many notifications (a thousand by default,
        // what async-opcua's clients decode) and is closed at about 160 KiB (the vendored
        // library's `MAX_NOTIFICATION_BYTES`), well within the message size clients
        // negotiate: a burst of changes goes in several answers, each one a client takes.
        limits.subscriptions.max_notifications_per_publish =
            config.max_notifications_per_publish as u64;
        limits.subscriptions.max_lifetime_ms = config.subscription_lifetime.as_millis() as f64;
        limits.subscriptions.min_publishing_interval_ms = MIN_INTERVAL_MS as f64;
        limits.subscriptions.min_sampling_interval_ms = MIN_INTERVAL_MS as f64;
        // The operation limits the server advertises are the ones it keeps: a request past
        // one is refused with Bad_TooManyOperations. Arrays may be longer than the limits
        // (within the message size), so that a request of 1,001 reads is that refusal and
        // not a decoding error.
        limits.max_array_length = MAX_ARRAY_LENGTH;
        let ops = &mut limits.operational;
        for limit in [
            &mut ops.max_nodes_per_read,
            &mut ops.max_nodes_per_write,
            &mut ops.max_nodes_per_browse,
            &mut ops.max_nodes_per_translate_browse_paths_to_node_ids,
            &mut ops.max_nodes_per_register_nodes,
            &mut ops.max_nodes_per_method_call,
            &mut ops.max_nodes_per_history_read_data,
            &mut ops.max_nodes_per_history_read_events,
            &mut ops.max_nodes_per_history_update,
            &mut ops.max_monitored_items_per_call,
        ] {
            *limit = MAX_OPERATIONS;
        }
    }
}

/// The built server's node manager and the gateway's namespace, with the gateway's folders
/// made under Objects.
fn address_space(handle: &ServerHandle) -> Result<(Arc<nodes::Manager>, Ids), String> {
    let manager = handle
        .node_managers()
        .get_of_type::<nodes::Manager>()
        .ok_or("OPC UA server: its node manager is missing")?;
    let ns = handle
        .get_namespace_index(NAMESPACE)
        .ok_or("OPC UA server: its namespace is missing")?;
    let ids = Ids { ns };
    add_folders(&manager, ids);
    Ok((manager, ids))
}

/// The gateway's folders under Objects: `iogate`, its `Devices` and `Links`.
fn add_folders(manager: &nodes::Manager, ids: Ids) {
    {
        let mut space = manager.address_space().write();
        space.add_folder(
            &ids.folder(space::ROOT),
            ids.name("iogate"),
            "iogate",
            &NodeId::objects_folder_id(),
        );
        space.add_folder(
            &ids.folder(space::DEVICES),
            ids.name("Devices"),
            "Devices",
            &ids.folder(space::ROOT),
        );
        space.add_folder(
            &ids.folder(space::LINKS),
            ids.name("Links"),
            "Links",
            &ids.folder(space::ROOT),
        );
    }
}
