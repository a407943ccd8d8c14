//! Configuration reload: the config file and profiles are loaded and checked exactly as
//! `iogate check` does (any problem and nothing changes), compared with what runs
//! (`diff`), and only what changed is applied, while everything else keeps running: an
//! unchanged link keeps its port open and its devices their poll grid; a re-planned device
//! hands its kept fields' values, subscribers and waiting writes to its successor.
//! Reloads come one at a time (SIGHUP, `POST /api/v1/config/reload`, gRPC `ReloadConfig`,
//! the file watch in `watch.rs`).

mod apply;
mod clash;
pub mod compare;
pub(crate) mod diff;
mod watch;

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::SystemTime;

use futures_util::future::BoxFuture;

use crate::api::front_end::{Prepare, Starting};
use crate::auth::Tokens;
use crate::config;
use crate::service::{ConfigStatus, ReloadError, Reloading, Report, Service, Trigger};
use crate::setup::Setup;
use crate::yaml::Problems;
use diff::Diff;

/// A configuration loaded and checked, with what identifies its files' contents.
pub(crate) struct Loaded {
    pub(crate) setup: Setup,
    pub(crate) tokens: Tokens,
    pub(crate) hash: String,
}

/// Loads and checks the config file and its profiles as `iogate check` does, and hashes
/// their contents. `serving` is the Modbus server's map in force: its `auto` locations are
/// kept (`map::plan_after`).
pub(crate) fn load(path: &Path, serving: Option<&crate::map::Plan>) -> Result<Loaded, Problems> {
    let mut setup = Setup::from_file(path)?;
    if serving.is_some() && setup.map.is_some() {
        setup.map = crate::map::plan_after(&setup.config, &setup.catalog, serving)?;
    }
    let access = config::check_security(&setup.config)?;
    let hash = hash_files(
        path,
        setup.profiles_dir.as_deref(),
        &setup.config.sections.files(),
    );
    Ok(Loaded {
        setup,
        tokens: access.tokens,
        hash,
    })
}

/// SHA-256 over the config file, every file of the profiles directory (by name) and the
/// files the sections read (`outside`: an IEC 104 map), in hex: equal exactly when the
/// contents are, whatever the timestamps.
pub(crate) fn hash_files(config: &Path, profiles: Option<&Path>, outside: &[PathBuf]) -> String {
    let mut ctx = ring::digest::Context::new(&ring::digest::SHA256);
    let mut add = |name: &[u8], path: &Path| {
        let bytes = std::fs::read(path).unwrap_or_default();
        ctx.update(&(name.len() as u64).to_le_bytes());
        ctx.update(name);
        ctx.update(&(bytes.len() as u64).to_le_bytes());
        ctx.update(&bytes);
    };
    add(b"", config);
    for file in outside {
        add(file.to_string_lossy().as_bytes(), file);
    }
    if let Some(dir) = profiles {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map(|entries| {
                entries
                    .filter_map(|e| e.ok().map(|e| e.path()))
                    .filter(|p| p.is_file())
                    .collect()
            })
            .unwrap_or_default();
        files.sort();
        for file in files {
            let name = file.file_name().map(|n| n.to_string_lossy().into_owned());
            add(name.unwrap_or_default().as_bytes(), &file);
        }
    }
    ctx.finish()
        .as_ref()
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

fn unix_ms(at: SystemTime) -> i64 {
    at.duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}

/// The configuration in force.
struct InForce {
    setup: Setup,
    tokens: Tokens,
    hash: String,
    /// The front-ends with a section of their own that run.
    front_ends: Vec<crate::api::front_end::Held>,
}

/// Reloads the configuration of a gateway started from a file.
pub(crate) struct Reloader {
    path: PathBuf,
    in_force: tokio::sync::Mutex<InForce>,
    status: Mutex<ConfigStatus>,
    /// The certificate HTTP and gRPC present, when TLS is on.
    tls: Mutex<Option<Arc<crate::tls::Tls>>>,
    /// Counts the reloads applied, whatever started them: the watch looks at its settings
    /// (and the files it watches) again after each.
    applied: tokio::sync::watch::Sender<u64>,
}

impl std::fmt::Debug for Reloader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reloader")
            .field("path", &self.path)
            .finish()
    }
}

impl Reloader {
    /// The reloader of a gateway started with `setup` from `path`; with `reload.watch`,
    /// its watch is started as a task of the gateway.
    pub(crate) fn start(
        service: &Arc<Service>,
        path: PathBuf,
        setup: Setup,
        tokens: Tokens,
        tls: Option<Arc<crate::tls::Tls>>,
        front_ends: Vec<crate::api::front_end::Held>,
    ) -> Arc<Reloader> {
        let hash = hash_files(
            &path,
            setup.profiles_dir.as_deref(),
            &setup.config.sections.files(),
        );
        let status = ConfigStatus {
            file: path.display().to_string(),
            profiles: setup.profiles_dir.as_ref().map(|d| d.display().to_string()),
            hash: hash.clone(),
            loaded_at_unix_ms: unix_ms(SystemTime::now()),
            watch: setup.config.reload.watch,
            last_report: None,
            last_problems: Vec::new(),
            listening: Vec::new(),
        };
        let reloader = Arc::new(Reloader {
            path,
            in_force: tokio::sync::Mutex::new(InForce {
                setup,
                tokens,
                hash,
                front_ends,
            }),
            status: Mutex::new(status),
            tls: Mutex::new(tls),
            applied: tokio::sync::watch::Sender::new(0),
        });
        service.attach_reloader(reloader.clone());
        watch::spawn(service, &reloader);
        reloader
    }

    fn set_status(&self, f: impl FnOnce(&mut ConfigStatus)) {
        f(&mut self.status.lock().unwrap_or_else(|e| e.into_inner()));
    }

    /// The files the watch looks at: the config file and the profiles directory in force.
    pub(crate) async fn watched(&self) -> (PathBuf, Option<PathBuf>, config::ReloadConfig) {
        let in_force = self.in_force.lock().await;
        (
            self.path.clone(),
            in_force.setup.profiles_dir.clone(),
            in_force.setup.config.reload,
        )
    }

    /// The files outside the config file its sections read, in force.
    pub(crate) async fn outside(&self) -> Vec<PathBuf> {
        self.in_force.lock().await.setup.config.sections.files()
    }

    /// Told after every reload applied, whatever started it.
    pub(crate) fn follow_applied(&self) -> tokio::sync::watch::Receiver<u64> {
        self.applied.subscribe()
    }

    /// The hash of the files in force.
    pub(crate) async fn hash(&self) -> String {
        self.in_force.lock().await.hash.clone()
    }

    async fn run(
        self: Arc<Self>,
        service: Arc<Service>,
        trigger: Trigger,
        dry_run: bool,
    ) -> Result<Report, ReloadError> {
        let started = std::time::Instant::now();
        let mut in_force = self.in_force.lock().await;
        let path = self.path.clone();
        let serving = in_force.setup.map.clone();
        let loaded = tokio::task::spawn_blocking(move || load(&path, serving.as_ref()))
            .await
            .map_err(|e| ReloadError::Failed(format!("loading the configuration failed: {e}")))?;
        let result = match loaded {
            Ok(loaded) => match clash::clashes(&service, &in_force.setup, &loaded.setup) {
                Some(problems) => Err(ReloadError::Invalid(problems)),
                None => Ok(loaded),
            },
            Err(problems) => Err(ReloadError::Invalid(problems)),
        };
        let loaded = match result {
            Ok(loaded) => loaded,
            Err(e) if dry_run => return Err(e),
            Err(e) => return Err(self.refused(&service, trigger, e)),
        };
        let diff = diff::diff(
            &in_force.setup,
            &in_force.tokens,
            &loaded.setup,
            &loaded.tokens,
        );
        let mut report = Report {
            trigger,
            dry_run,
            changes: diff.items.clone(),
            reopened: diff.links.changed.clone(),
            took_ms: 0.0,
            config_hash: loaded.hash.clone(),
            at_unix_ms: unix_ms(SystemTime::now()),
        };
        if dry_run {
            report.took_ms = started.elapsed().as_secs_f64() * 1000.0;
            return Ok(report);
        }
        if let Err(e) = self.apply(&service, &mut in_force, &loaded, &diff).await {
            service.metrics.config_reload("failed");
            tracing::error!(trigger = trigger.name(), error = %e, "configuration not reloaded; the gateway runs on what it had");
            self.set_status(|s| s.last_problems = vec![e.clone()]);
            return Err(ReloadError::Failed(e));
        }
        report.took_ms = (started.elapsed().as_secs_f64() * 1e6).round() / 1000.0;
        let watch = loaded.setup.config.reload.watch;
        in_force.setup = loaded.setup;
        in_force.tokens = loaded.tokens;
        in_force.hash = loaded.hash.clone();
        drop(in_force);
        self.applied.send_modify(|n| *n = n.wrapping_add(1));
        self.said(&service, &report, diff.is_empty(), loaded.hash, watch);
        Ok(report)
    }

    /// A configuration refused: counted, logged and kept in the status.
    fn refused(&self, service: &Service, trigger: Trigger, e: ReloadError) -> ReloadError {
        service.metrics.config_reload("invalid");
        tracing::error!(trigger = trigger.name(), problems = %e, "configuration not reloaded; the gateway runs on what it had");
        if let ReloadError::Invalid(problems) = &e {
            let lines = problems.0.iter().map(ToString::to_string).collect();
            self.set_status(|s| s.last_problems = lines);
        }
        e
    }

    /// A reload applied: counted, logged a line per change, and its report and files'
    /// hash kept in the status.
    fn said(&self, service: &Service, report: &Report, unchanged: bool, hash: String, watch: bool) {
        let result = if unchanged { "unchanged" } else { "applied" };
        service.metrics.config_reload(result);
        tracing::info!(
            trigger = report.trigger.name(),
            changes = report.changes.len(),
            reopened = ?report.reopened,
            took_ms = report.took_ms,
            "configuration reloaded"
        );
        for line in report.lines() {
            tracing::info!(change = %line, "reload");
        }
        let kept = report.clone();
        self.set_status(move |s| {
            s.hash = hash;
            s.loaded_at_unix_ms = kept.at_unix_ms;
            s.watch = watch;
            s.last_report = Some(kept);
            s.last_problems.clear();
        });
    }

    /// Applies `diff` (from `in_force` to `loaded`). Listeners that move are bound first,
    /// so a reload that cannot bind one changes nothing.
    async fn apply(
        &self,
        service: &Arc<Service>,
        in_force: &mut InForce,
        loaded: &Loaded,
        diff: &Diff,
    ) -> Result<(), String> {
        let new = &loaded.setup;
        // The front-ends that restart are prepared before anything changes: their
        // listeners bound, what their sections name read.
        let starting = self.prepare(in_force, &new.config).await?;
        let tls = match (&new.config.security.tls, diff.tls) {
            (Some(files), true) => Some(
                crate::tls::Tls::load(files.clone())
                    .map(Arc::new)
                    .map_err(|e| e.to_string())?,
            ),
            _ => None,
        };
        let modbus = match (&new.config.modbus_server, &new.map) {
            (Some(server), Some(plan)) if diff.modbus || diff.modbus_listen => {
                Some((server.clone(), plan.clone()))
            }
            _ => None,
        };
        apply::registry(service, new, diff);
        apply::transactions(service, new, diff);
        if diff.max_streams {
            service.set_max_streams([new.config.max_streams, new.config.max_streams_per_client]);
        }
        // Access.
        if diff.access {
            service.set_access(loaded.tokens.clone(), new.config.security.read_only);
            service.set_policy(new.config.security.declare.clone());
        }
        apply::image(service, modbus, &in_force.setup, new);
        let tls = self.swap_tls(service, &new.config, diff.tls, tls);
        for (name, starting) in starting {
            let held = &mut in_force.front_ends;
            crate::api::front_end::restart(service, held, name, starting, tls.clone()).await;
        }
        Ok(())
    }
}

impl Reloader {
    /// Prepares every front-end a reload to `new` restarts, in the list's order.
    async fn prepare(
        &self,
        in_force: &InForce,
        new: &config::Config,
    ) -> Result<Vec<(&'static str, Option<Box<dyn Starting>>)>, String> {
        let base = Path::new(&new.source)
            .parent()
            .unwrap_or_else(|| Path::new("."));
        let old = &in_force.setup.config;
        let mut starting = Vec::new();
        for front_end in crate::front_ends::all() {
            if !front_end.restarts(old, new) {
                continue;
            }
            let now = in_force
                .front_ends
                .iter()
                .find(|h| h.name == front_end.name())
                .and_then(|h| h.running.address());
            let prepare = Prepare {
                config: new,
                old: Some(old),
                now,
                base,
            };
            starting.push((front_end.name(), front_end.prepare(&prepare).await?));
        }
        Ok(starting)
    }

    /// The certificate from now on: new files (TLS still on) serve the next connections;
    /// TLS turned on or off is served by HTTP and gRPC started again with it.
    fn swap_tls(
        &self,
        service: &Service,
        config: &config::Config,
        changed: bool,
        loaded: Option<Arc<crate::tls::Tls>>,
    ) -> Option<Arc<crate::tls::Tls>> {
        let mut tls = self.tls.lock().unwrap_or_else(|e| e.into_inner());
        let toggled = changed && tls.is_some() != config.security.tls.is_some();
        match (tls.as_ref(), loaded) {
            (Some(current), Some(new)) if !toggled => current.replace(&new),
            (_, new) if toggled => {
                if let Some(new) = &new {
                    let token = service.tasks().token().clone();
                    service.tasks().spawn(new.clone().watch(token));
                }
                *tls = new;
            }
            _ => {}
        }
        tls.clone()
    }
}

impl Reloading for Reloader {
    fn reload(
        self: Arc<Self>,
        service: Arc<Service>,
        trigger: Trigger,
        dry_run: bool,
    ) -> BoxFuture<'static, Result<Report, ReloadError>> {
        Box::pin(self.run(service, trigger, dry_run))
    }

    fn status(&self) -> ConfigStatus {
        self.status
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }
}
