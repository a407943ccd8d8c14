//! The composition root: builds the gateway from its configuration (cache, tasks, service,
//! listeners), runs it, and shuts it down.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use crate::cache::Cache;
use crate::config;
use crate::metrics::Metrics;
use crate::runtime::Tasks;
use crate::service::Service;

pub use crate::setup::{Listeners, Setup};
/// How long shutdown waits for tasks before giving up on them.
pub(crate) const SHUTDOWN_GRACE: Duration = Duration::from_millis(1500);

/// A started gateway.
pub struct Running {
    pub service: Arc<Service>,
    pub http_addr: SocketAddr,
    pub grpc_addr: SocketAddr,
    /// The Modbus TCP server's address, when one is configured.
    pub modbus_addr: Option<SocketAddr>,
    tracker: TaskTracker,
}

impl Running {
    /// The address the listener `name` is bound to (`opcua`, `modbus_server`, ...), when
    /// it runs.
    pub fn bound(&self, name: &str) -> Option<SocketAddr> {
        self.service.listening.bound(name)
    }

    pub fn token(&self) -> &CancellationToken {
        self.service.tasks().token()
    }

    /// Cancels every task and waits for them, at most [`SHUTDOWN_GRACE`].
    pub async fn shutdown(self) {
        self.service.set_ready(false);
        self.token().cancel();
        self.tracker.close();
        if tokio::time::timeout(SHUTDOWN_GRACE, self.tracker.wait())
            .await
            .is_err()
        {
            tracing::warn!(
                tasks = self.tracker.len(),
                "tasks did not finish within the shutdown grace period"
            );
            for link in self.service.links() {
                if link.progress.in_transaction() {
                    tracing::warn!(
                        link = %link.name(),
                        "shutdown abandons the link in the middle of a transaction: what it was sending may or may not have reached the device"
                    );
                }
            }
        }
    }
}

/// Prepares every front-end (its listener bound, what its section names read) and starts
/// every task. The HTTP listener's address (port 0 picks a free port) is in the result.
/// Every front-end is prepared (and the access configuration and the Modbus memory read)
/// before any link is opened or any device polled, so a gateway that cannot serve stops
/// without having touched a bus.
pub async fn start(setup: Setup) -> anyhow::Result<Running> {
    let source = (!setup.demo).then(|| PathBuf::from(&setup.config.source));
    let demo = setup.demo;
    let Setup {
        mut config,
        catalog,
        map,
        profiles_dir,
        ..
    } = setup;
    let (reload_catalog, reload_map) = (catalog.clone(), map.clone());
    let config::Access { tokens, tls } =
        config::check_security(&config).map_err(|p| anyhow::anyhow!("{p}"))?;
    let reload_tokens = tokens.clone();
    let base = Path::new(&config.source)
        .parent()
        .unwrap_or_else(|| Path::new("."))
        .to_owned();
    let prepared = crate::front_ends::prepare_all(&config, &base)
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))?;

    // The demo's simulated field devices answer before its link first asks.
    let field = match demo {
        true => crate::demo::field::bind(&mut config).await,
        false => None,
    };
    let token = CancellationToken::new();
    let tracker = TaskTracker::new();
    let cache = Arc::new(Cache::new(&config, catalog));
    let image = match (&config.modbus_server, &map) {
        (Some(server), Some(plan)) => Some(
            crate::service::ModbusImage::new(server, plan, &cache)
                .map_err(|e| anyhow::anyhow!("{e} (modbus_server.memory_file)"))?,
        ),
        _ => None,
    };

    let tasks = Tasks::new(tracker.clone(), token.clone(), Arc::new(Metrics::new()))
        .with_role(crate::ha::role(&config));
    spawn_polling(&tasks, &cache, field, &token);

    let tls = tls.map(Arc::new);
    if let Some(tls) = &tls {
        tracker.spawn(tls.clone().watch(token.clone()));
        tracing::info!(
            client_certificates = tls.requires_client_certificates(),
            "HTTP and gRPC served over TLS"
        );
    }
    let service = build_service(&config, cache.clone(), tasks, tokens, image)?;
    let front_ends = crate::front_ends::start_all(&service, prepared, tls.clone())
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let bound = |name: &str| service.listening.bound(name);
    let (Some(http_addr), Some(grpc_addr)) = (bound("http"), bound("grpc")) else {
        anyhow::bail!("the HTTP and gRPC listeners did not start");
    };
    let modbus_addr = bound("modbus");
    crate::ha::start(&service, &config, &base);
    if let Some(path) = source {
        let setup = Setup {
            config: config.clone(),
            catalog: reload_catalog,
            profiles_dir,
            demo: false,
            map: reload_map,
        };
        crate::reload::Reloader::start(&service, path, setup, reload_tokens, tls, front_ends);
    }
    service.set_ready(true);
    Ok(Running {
        service,
        http_addr,
        grpc_addr,
        modbus_addr,
        tracker,
    })
}

/// Starts what reads the devices: the simulated ones, the demo's field devices, a task a
/// link, and the watchdog.
fn spawn_polling(
    tasks: &Tasks,
    cache: &Arc<Cache>,
    field: Option<TcpListener>,
    token: &CancellationToken,
) {
    for device in cache.devices() {
        if device.is_simulated() {
            tasks.spawn_sim(device);
        }
    }
    if let Some(field) = field {
        tasks.spawn(crate::demo::field::run(field, token.clone()));
    }
    for link in cache.links() {
        tasks.spawn_link(link);
    }
    tasks.spawn(crate::poller::watchdog::run(cache.clone(), token.clone()));
}

/// The service over the cache, with the configuration's access rules and standing
/// transactions.
fn build_service(
    config: &config::Config,
    cache: Arc<Cache>,
    tasks: Tasks,
    tokens: crate::auth::Tokens,
    image: Option<crate::service::ModbusImage>,
) -> anyhow::Result<Arc<Service>> {
    if tokens.is_empty() {
        tracing::info!(
            "no tokens configured: every client may read and write (listeners on loopback)"
        );
    }
    let mut service = Service::new(cache, tasks)
        .with_policy(config.security.declare.clone())
        .with_max_streams([config.max_streams, config.max_streams_per_client])
        .with_described(crate::front_ends::described())
        .with_access(tokens, config.security.read_only);
    if let Some(image) = image {
        service = service.with_modbus(image);
    }
    let service = Arc::new(service);
    for standing in &config.transactions {
        service
            .ensure_transaction(standing.clone())
            .map_err(|e| anyhow::anyhow!("transaction {}: {e}", standing.name))?;
    }
    Ok(service)
}

/// Prints a line of the banner; standard output closed (a supervisor that does not read
/// it) is no reason to stop serving, so a failed write is ignored, never a panic.
macro_rules! say {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

/// Runs the gateway until SIGINT or SIGTERM.
pub async fn run(setup: Setup) -> anyhow::Result<()> {
    let demo = setup.demo;
    let signal = shutdown_signal();
    let running = start(setup).await?;
    if demo {
        say!("iogate is running its built-in demo: the simulated devices sim and plant,");
        if let Ok(link) = running.service.cache.link(crate::demo::field::LINK)
            && let config::Transport::Tcp { host, port, .. } = link.config().transport
        {
            say!(
                "and on link {} (Modbus TCP, {host}:{port}) an energy meter (meter) and an I/O module (io)",
                crate::demo::field::LINK
            );
        }
    }
    for line in crate::front_ends::banners(&running.service) {
        say!("{line}");
    }
    tracing::info!(http = %running.http_addr, "iogate started");
    if demo {
        let token = running.service.tasks().token().clone();
        running.service.tasks().spawn(demo_hangup(token.clone()));
        running
            .service
            .tasks()
            .spawn(crate::demo::motion::run(running.service.clone(), token));
    }
    signal.await;
    tracing::info!("shutting down");
    running.shutdown().await;
    Ok(())
}

/// The built-in demo has no file to reload: a SIGHUP is logged, and stops nothing. Ends
/// with the gateway (a task that outlived the token held the shutdown to its grace period).
async fn demo_hangup(token: tokio_util::sync::CancellationToken) {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let Ok(mut hangup) = signal(SignalKind::hangup()) else {
            return;
        };
        loop {
            tokio::select! {
                _ = token.cancelled() => return,
                got = hangup.recv() => match got {
                    Some(()) => tracing::info!("SIGHUP: the built-in demo has no configuration file to reload"),
                    None => return,
                },
            }
        }
    }
    #[cfg(not(unix))]
    token.cancelled().await;
}

/// Registers for SIGINT and SIGTERM now (so a signal that comes during start-up is not
/// lost) and returns a future that resolves on the first of them.
fn shutdown_signal() -> impl std::future::Future<Output = ()> {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let interrupt = signal(SignalKind::interrupt());
        let terminate = signal(SignalKind::terminate());
        async move {
            match (interrupt, terminate) {
                (Ok(mut interrupt), Ok(mut terminate)) => {
                    tokio::select! {
                        _ = interrupt.recv() => {}
                        _ = terminate.recv() => {}
                    }
                }
                (Err(e), _) | (_, Err(e)) => {
                    tracing::error!(error = %e, "cannot listen for signals; stop with SIGKILL");
                    std::future::pending::<()>().await;
                }
            }
        }
    }
    #[cfg(not(unix))]
    async {
        if tokio::signal::ctrl_c().await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}
