//! The composition root: builds the gateway from its configuration (cache, tasks, service,
//! listeners), runs it, and shuts it down.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use crate::api;
use crate::cache::Cache;
use crate::config::{self, Config};
use crate::metrics::Metrics;
use crate::profile::{self, Catalog};
use crate::runtime::Tasks;
use crate::service::Service;
use crate::yaml::{Problems, Report};

/// The config file looked for in the working directory when none is given.
pub(crate) const DEFAULT_CONFIG: &str = "iogate.yaml";
/// How long shutdown waits for tasks before giving up on them.
pub(crate) const SHUTDOWN_GRACE: Duration = Duration::from_millis(1500);

/// A checked configuration with its profiles: what `check` validates and `serve` runs.
#[derive(Debug, Clone)]
pub struct Setup {
    pub config: Config,
    pub catalog: Catalog,
    /// The profiles directory used, if any.
    pub profiles_dir: Option<PathBuf>,
    /// Whether this is the built-in demo.
    pub demo: bool,
    /// The Modbus TCP server's bindings, when it is configured.
    pub map: Option<crate::map::Plan>,
}

impl Setup {
    /// `path` if given; else `iogate.yaml` in the working directory; else the built-in demo.
    pub fn load(path: Option<&Path>) -> Result<Setup, Problems> {
        match path {
            Some(p) => Setup::from_file(p),
            None if Path::new(DEFAULT_CONFIG).is_file() => {
                Setup::from_file(Path::new(DEFAULT_CONFIG))
            }
            None => Setup::demo(),
        }
    }

    pub fn demo() -> Result<Setup, Problems> {
        let (config, catalog) = crate::demo::load()?;
        let map = crate::map::plan(&config, &catalog)?;
        Ok(Setup {
            config,
            catalog,
            profiles_dir: None,
            demo: true,
            map,
        })
    }

    /// Loads a config file, then its profiles, then checks the devices against both.
    /// Every problem of every file is reported: what could not be read is left out of the
    /// checks that follow, and the rest is still checked.
    pub fn from_file(path: &Path) -> Result<Setup, Problems> {
        let (config, mut problems) = Config::load_partial(path);
        let Some(config) = config else {
            return Err(problems);
        };
        let base = path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        match Setup::from_config(config, base) {
            Ok(setup) if problems.is_empty() => return Ok(setup),
            Ok(_) => {}
            Err(more) => problems.extend(more),
        }
        // File by file, in line order, as an editor shows them.
        problems
            .0
            .sort_by(|a, b| (&a.file, a.line).cmp(&(&b.file, b.line)));
        Err(problems)
    }

    /// What `check` and `serve` print without stopping anything: every profile field that
    /// relies on the default `word_count` of 1 although its type is wider, and every map
    /// binding that cannot show every value of its field (a TIME at `%MD`).
    pub fn warnings(&self) -> Vec<crate::yaml::Problem> {
        let profiles = self.catalog.iter().flat_map(|p| p.width_warnings());
        let map = self.map.iter().flat_map(|m| m.warnings.iter().cloned());
        profiles.chain(map).collect()
    }

    /// Loads the profiles for `config` (its `profiles` directory, else `profiles/` in
    /// `base` or up to six parents) and checks its devices, security, standing transactions
    /// and Modbus map: every problem of every stage at once.
    pub fn from_config(config: Config, base: &Path) -> Result<Setup, Problems> {
        let mut problems = Problems::default();
        let dir = profile::find_dir(config.profiles.as_deref(), base);
        let catalog = match &dir {
            Some(dir) => {
                let (catalog, more) = profile::load_catalog_partial(dir);
                problems.extend(more);
                catalog
            }
            None if config.devices.is_empty() => Catalog::default(),
            None => {
                let mut report = Report::new(&config.source);
                report.push(
                    config.lines.profiles.max(1),
                    "profiles",
                    format!(
                        "no profiles directory found in {} or its {} parents; set `profiles:`",
                        base.display(),
                        profile::PARENT_SEARCH_DEPTH
                    ),
                );
                return Err(report.into_problems());
            }
        };
        let checks = [
            config::check_devices(&config, &catalog).err(),
            config::check_security(&config).err(),
            crate::transaction::check_standing(&config).err(),
        ];
        problems.extend_all(checks.into_iter().flatten());
        if let Some(mqtt) = &config.mqtt
            && let Err(e) = crate::api::mqtt::prepare(mqtt, base)
        {
            let mut report = Report::new(&config.source);
            report.push(mqtt.line, "mqtt", e);
            problems.extend(report.into_problems());
        }
        let map = crate::map::plan(&config, &catalog).unwrap_or_else(|more| {
            problems.extend(more);
            None
        });
        if !problems.is_empty() {
            return Err(problems);
        }
        Ok(Setup {
            config,
            catalog,
            profiles_dir: dir,
            demo: false,
            map,
        })
    }
}

/// The listeners' servers, each stopped by its own token, so a reload that moves one
/// listener (or turns TLS on or off) rebinds that one only.
pub(crate) struct Servers {
    token: CancellationToken,
    tracker: TaskTracker,
    tls: std::sync::Mutex<Option<Arc<crate::tls::Tls>>>,
    running: tokio::sync::Mutex<Served>,
}

/// Each server's address and the token that stops it.
struct Served {
    http: Option<(SocketAddr, CancellationToken, api::http::Limits)>,
    grpc: Option<(SocketAddr, CancellationToken)>,
    modbus: Option<(SocketAddr, CancellationToken)>,
}

/// Listeners bound for a reload before anything else is applied.
#[derive(Default)]
pub(crate) struct Bound {
    http: Option<TcpListener>,
    grpc: Option<TcpListener>,
    modbus: Option<TcpListener>,
}

async fn bind(addr: SocketAddr, key: &str) -> Result<TcpListener, String> {
    TcpListener::bind(addr)
        .await
        .map_err(|e| format!("cannot listen on {addr} ({key}): {e}"))
}

impl Servers {
    fn tls(&self) -> Option<Arc<crate::tls::Tls>> {
        self.tls.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    async fn serve_modbus(
        &self,
        service: &Arc<Service>,
        listener: TcpListener,
    ) -> anyhow::Result<SocketAddr> {
        let addr = listener.local_addr()?;
        let stop = self.token.child_token();
        self.tracker.spawn(api::modbus_server::serve_modbus(
            listener,
            service.clone(),
            stop.clone(),
        ));
        self.running.lock().await.modbus = Some((addr, stop));
        Ok(addr)
    }

    async fn serve_grpc(
        &self,
        service: &Arc<Service>,
        listener: TcpListener,
        limits: api::http::Limits,
    ) -> anyhow::Result<SocketAddr> {
        let addr = listener.local_addr()?;
        let stop = self.token.child_token();
        let (service, shutdown, tls) = (service.clone(), stop.clone(), self.tls());
        self.tracker.spawn(async move {
            let served = api::serve_grpc(
                listener,
                service,
                limits.header_timeout,
                tls,
                shutdown.cancelled_owned(),
            )
            .await;
            if let Err(e) = served {
                tracing::error!(error = %e, "gRPC server failed");
            }
        });
        self.running.lock().await.grpc = Some((addr, stop));
        Ok(addr)
    }

    async fn serve_http(
        &self,
        service: &Arc<Service>,
        listener: TcpListener,
        limits: api::http::Limits,
    ) -> anyhow::Result<SocketAddr> {
        let addr = listener.local_addr()?;
        let stop = self.token.child_token();
        let (service, shutdown, tls) = (service.clone(), stop.clone(), self.tls());
        self.tracker.spawn(async move {
            let served =
                api::serve_http(listener, service, limits, tls, shutdown.cancelled_owned()).await;
            if let Err(e) = served {
                tracing::error!(error = %e, "HTTP server failed");
            }
        });
        self.running.lock().await.http = Some((addr, stop, limits));
        Ok(addr)
    }

    /// Binds the listeners a reload moves to another address, before anything is applied:
    /// one that cannot be bound refuses the reload.
    pub(crate) async fn bind(
        &self,
        config: &Config,
        diff: &crate::reload::diff::Diff,
    ) -> Result<Bound, String> {
        let running = self.running.lock().await;
        let moved = |now: Option<SocketAddr>, to: SocketAddr| now.is_some_and(|a| a != to);
        let mut bound = Bound::default();
        if diff.http_listen && moved(running.http.as_ref().map(|h| h.0), config.http) {
            bound.http = Some(bind(config.http, "listen.http").await?);
        }
        if diff.grpc_listen && moved(running.grpc.as_ref().map(|g| g.0), config.grpc) {
            bound.grpc = Some(bind(config.grpc, "listen.grpc").await?);
        }
        if let Some(server) = &config.modbus_server
            && diff.modbus_listen
        {
            let now = running.modbus.as_ref().map(|m| m.0);
            if now.is_none() || moved(now, server.listen) {
                bound.modbus = Some(bind(server.listen, "modbus_server.listen").await?);
            }
        }
        Ok(bound)
    }

    /// Applies a reload's listener changes: a moved listener serves on its new address
    /// (bound by [`Servers::bind`]) and the old one stops; one whose TLS or timeouts
    /// changed is served again on its address; TLS files that changed serve the next
    /// connections.
    pub(crate) async fn apply(
        &self,
        service: &Arc<Service>,
        config: &Config,
        diff: &crate::reload::diff::Diff,
        bound: Bound,
        tls: Option<Arc<crate::tls::Tls>>,
    ) {
        let limits = api::http::Limits {
            header_timeout: config.header_timeout,
            body_timeout: config.body_timeout,
        };
        let toggled = diff.tls && self.tls().is_some() != config.security.tls.is_some();
        match (self.tls(), tls) {
            (Some(current), Some(new)) if !toggled => current.replace(&new),
            (_, new) if toggled => {
                if let Some(new) = &new {
                    self.token_spawn_watch(new.clone());
                }
                *self.tls.lock().unwrap_or_else(|e| e.into_inner()) = new;
            }
            _ => {}
        }
        let mut running = self.running.lock().await;
        let old_http = running.http.take();
        let old_grpc = running.grpc.take();
        let old_modbus = running.modbus.take();
        drop(running);
        // HTTP.
        let http = match (bound.http, old_http) {
            (Some(listener), old) => {
                if let Some((_, stop, _)) = old {
                    stop.cancel();
                }
                Some(listener)
            }
            (None, Some((addr, stop, _))) if toggled || diff.limits => {
                stop.cancel();
                rebind(addr, "listen.http").await
            }
            (None, old) => {
                self.running.lock().await.http = old;
                None
            }
        };
        if let Some(listener) = http
            && let Err(e) = self.serve_http(service, listener, limits).await
        {
            tracing::error!(error = %e, "HTTP server not started");
        }
        // gRPC.
        let grpc = match (bound.grpc, old_grpc) {
            (Some(listener), old) => {
                if let Some((_, stop)) = old {
                    stop.cancel();
                }
                Some(listener)
            }
            (None, Some((addr, stop))) if toggled || diff.limits => {
                stop.cancel();
                rebind(addr, "listen.grpc").await
            }
            (None, old) => {
                self.running.lock().await.grpc = old;
                None
            }
        };
        if let Some(listener) = grpc
            && let Err(e) = self.serve_grpc(service, listener, limits).await
        {
            tracing::error!(error = %e, "gRPC server not started");
        }
        // Modbus TCP.
        match (bound.modbus, old_modbus) {
            (Some(listener), old) => {
                if let Some((_, stop)) = old {
                    stop.cancel();
                }
                if let Err(e) = self.serve_modbus(service, listener).await {
                    tracing::error!(error = %e, "Modbus TCP server not started");
                }
            }
            (None, Some((_, stop))) if config.modbus_server.is_none() => stop.cancel(),
            (None, old) => self.running.lock().await.modbus = old,
        }
    }

    fn token_spawn_watch(&self, tls: Arc<crate::tls::Tls>) {
        self.tracker.spawn(tls.watch(self.token.clone()));
    }
}

/// Binds `addr` again after its server was stopped (TLS turned on or off, timeouts
/// changed); the old listener may take a moment to close.
async fn rebind(addr: SocketAddr, key: &str) -> Option<TcpListener> {
    for _ in 0..50 {
        if let Ok(listener) = TcpListener::bind(addr).await {
            return Some(listener);
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    tracing::error!(%addr, key, "cannot listen again after a reload");
    None
}

/// A started gateway.
pub struct Running {
    pub service: Arc<Service>,
    pub http_addr: SocketAddr,
    pub grpc_addr: SocketAddr,
    /// The Modbus TCP server's address, when one is configured.
    pub modbus_addr: Option<SocketAddr>,
    /// Whether HTTP and gRPC are served over TLS.
    pub(crate) secure: bool,
    tracker: TaskTracker,
}

impl Running {
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
        }
    }
}

/// Binds the listeners and starts every task. The HTTP listener's address (port 0 picks a
/// free port) is in the result. Every listener is bound (and the access configuration and
/// the Modbus memory read) before any link is opened or any device polled, so a gateway
/// that cannot serve stops without having touched a bus.
pub async fn start(setup: Setup) -> anyhow::Result<Running> {
    let source = (!setup.demo).then(|| PathBuf::from(&setup.config.source));
    let Setup {
        config,
        catalog,
        map,
        profiles_dir,
        ..
    } = setup;
    let (reload_catalog, reload_map) = (catalog.clone(), map.clone());
    let config::Access { tokens, tls } =
        config::check_security(&config).map_err(|p| anyhow::anyhow!("{p}"))?;
    let reload_tokens = tokens.clone();
    let modbus_listener = match &config.modbus_server {
        Some(server) => Some(TcpListener::bind(server.listen).await.map_err(|e| {
            anyhow::anyhow!(
                "cannot listen on {} (modbus_server.listen): {e}",
                server.listen
            )
        })?),
        None => None,
    };
    let listener = TcpListener::bind(config.http)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {} (listen.http): {e}", config.http))?;
    let http_addr = listener.local_addr()?;
    let grpc_listener = TcpListener::bind(config.grpc)
        .await
        .map_err(|e| anyhow::anyhow!("cannot listen on {} (listen.grpc): {e}", config.grpc))?;
    let grpc_addr = grpc_listener.local_addr()?;

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

    let tasks = Tasks::new(tracker.clone(), token.clone(), Arc::new(Metrics::new()));
    for device in cache.devices() {
        if device.is_simulated() {
            tasks.spawn_sim(device);
        }
    }
    for link in cache.links() {
        tasks.spawn_link(link);
    }
    tasks.spawn(crate::poller::watchdog::run(cache.clone(), token.clone()));

    let tls = tls.map(Arc::new);
    if let Some(tls) = &tls {
        tracker.spawn(tls.clone().watch(token.clone()));
        tracing::info!(
            client_certificates = tls.requires_client_certificates(),
            "HTTP and gRPC served over TLS"
        );
    }
    if tokens.is_empty() {
        tracing::info!(
            "no tokens configured: every client may read and write (listeners on loopback)"
        );
    }
    let mut service = Service::new(cache.clone(), tasks)
        .with_policy(config.security.declare.clone())
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
    if let Some(mqtt) = &config.mqtt {
        let base = Path::new(&config.source)
            .parent()
            .unwrap_or_else(|| Path::new("."));
        let prepared = api::mqtt::prepare(mqtt, base).map_err(|e| anyhow::anyhow!("{e}"))?;
        api::mqtt::spawn(service.clone(), prepared).map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let servers = Arc::new(Servers {
        token: token.clone(),
        tracker: tracker.clone(),
        tls: std::sync::Mutex::new(tls.clone()),
        running: tokio::sync::Mutex::new(Served {
            http: None,
            grpc: None,
            modbus: None,
        }),
    });
    let limits = api::http::Limits {
        header_timeout: config.header_timeout,
        body_timeout: config.body_timeout,
    };
    let secure = tls.is_some();
    let modbus_addr = match modbus_listener {
        Some(listener) => Some(servers.serve_modbus(&service, listener).await?),
        None => None,
    };
    servers.serve_grpc(&service, grpc_listener, limits).await?;
    servers.serve_http(&service, listener, limits).await?;
    if let Some(path) = source {
        crate::reload::Reloader::start(
            &service,
            path,
            Setup {
                config: config.clone(),
                catalog: reload_catalog,
                profiles_dir,
                demo: false,
                map: reload_map,
            },
            reload_tokens,
            servers.clone(),
        );
    }
    service.set_ready(true);
    Ok(Running {
        service,
        http_addr,
        grpc_addr,
        modbus_addr,
        secure,
        tracker,
    })
}

/// Runs the gateway until SIGINT or SIGTERM.
pub async fn run(setup: Setup) -> anyhow::Result<()> {
    let demo = setup.demo;
    let signal = shutdown_signal();
    let running = start(setup).await?;
    let scheme = if running.secure { "https" } else { "http" };
    let base = format!("{scheme}://{}", running.http_addr);
    if demo {
        println!("iogate is running its built-in demo (simulated devices sim and plant).");
    }
    println!("Web page:  {base}/ui");
    println!("REST API:  {base}/api/v1/devices");
    println!(
        "gRPC:      {} (iogate.v1.Gateway, reflection, health)",
        running.grpc_addr
    );
    if let Some(addr) = running.modbus_addr {
        println!("Modbus TCP: {addr} (iogate map prints the located addresses)");
    }
    println!("Events:    {base}/api/v1/events");
    println!("OpenAPI:   {base}/api/v1/openapi.json");
    println!("Metrics:   {base}/metrics");
    println!("Health:    {base}/livez  {base}/readyz");
    tracing::info!(http = %running.http_addr, "iogate started");
    if demo {
        running.service.tasks().spawn(demo_hangup());
    }
    signal.await;
    tracing::info!("shutting down");
    running.shutdown().await;
    Ok(())
}

/// The built-in demo has no file to reload: a SIGHUP is logged, and stops nothing.
async fn demo_hangup() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let Ok(mut hangup) = signal(SignalKind::hangup()) else {
            return;
        };
        while hangup.recv().await.is_some() {
            tracing::info!("SIGHUP: the built-in demo has no configuration file to reload");
        }
    }
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
