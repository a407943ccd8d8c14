//! What starts a reload without a client: SIGHUP (always: a hangup never stops the
//! gateway), and with `reload.watch` a change of the config file or of a profile file.
//!
//! Files are really replaced in several ways: written in place, written beside and renamed
//! over (editors), moved into the directory (`mv`), or swapped as a whole directory behind a
//! symlink (a Kubernetes ConfigMap's `..data`). So the directories are watched, not the
//! files; any event starts the debounce period again, and when it has passed quietly the
//! files' contents are hashed and compared with those in force: a reload happens only when
//! the contents differ, once per change however many events it made. A directory replaced
//! as a whole (rsync, ansible: a new one renamed over the old) leaves a watch on a directory
//! that is gone, so the watch is made anew after every look and every reload, and the
//! profiles directory's parent is watched too (the rename itself is an event there). A
//! reload from any trigger (SIGHUP, the API, gRPC) puts its `reload.watch` in force at once.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc;
use tokio::time::Instant;

use super::{Reloader, hash_files};
use crate::service::{Service, Trigger};

/// Events kept while the task is busy; more are dropped (the next look compares contents,
/// so a dropped event loses nothing).
const EVENTS: usize = 64;

pub(super) fn spawn(service: &Arc<Service>, reloader: &Arc<Reloader>) {
    service
        .tasks()
        .spawn(run(service.clone(), reloader.clone()));
}

/// Watches the directories of the config file and of the profiles; events go to `tx`.
fn watcher(
    config: &Path,
    profiles: Option<&Path>,
    tx: mpsc::Sender<()>,
) -> notify::Result<notify::RecommendedWatcher> {
    use notify::{EventKind, RecursiveMode, Watcher};
    let mut watcher = notify::recommended_watcher(move |event: notify::Result<notify::Event>| {
        let relevant = match event {
            // Reading a file (the gateway's own look at it) is not a change.
            Ok(e) => !matches!(
                e.kind,
                EventKind::Access(notify::event::AccessKind::Open(_))
                    | EventKind::Access(notify::event::AccessKind::Read)
                    | EventKind::Access(notify::event::AccessKind::Close(
                        notify::event::AccessMode::Read
                    ))
            ),
            Err(_) => true,
        };
        if relevant {
            let _ = tx.try_send(());
        }
    })?;
    let dir = config
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    watcher.watch(dir, RecursiveMode::NonRecursive)?;
    if let Some(profiles) = profiles {
        if let Some(parent) = profiles.parent().filter(|p| !p.as_os_str().is_empty())
            && parent != dir
        {
            watcher.watch(parent, RecursiveMode::NonRecursive)?;
        }
        // Between the two renames of a directory swap it is not there: its parent's watch
        // sees it come back, and the next watch is made on it then.
        if let Err(e) = watcher.watch(profiles, RecursiveMode::NonRecursive) {
            tracing::debug!(error = %e, profiles = %profiles.display(), "the profiles directory is not there to watch");
        }
    }
    Ok(watcher)
}

#[cfg(unix)]
fn hangup() -> Option<tokio::signal::unix::Signal> {
    use tokio::signal::unix::{SignalKind, signal};
    match signal(SignalKind::hangup()) {
        Ok(s) => Some(s),
        Err(e) => {
            tracing::error!(error = %e, "cannot listen for SIGHUP");
            None
        }
    }
}

#[cfg(unix)]
async fn next_hangup(hangup: &mut Option<tokio::signal::unix::Signal>) {
    match hangup {
        Some(s) => {
            if s.recv().await.is_none() {
                std::future::pending::<()>().await;
            }
        }
        None => std::future::pending::<()>().await,
    }
}

#[cfg(not(unix))]
fn hangup() -> Option<()> {
    None
}

#[cfg(not(unix))]
async fn next_hangup(_: &mut Option<()>) {
    std::future::pending::<()>().await;
}

async fn reload(service: &Arc<Service>, trigger: Trigger) {
    // The outcome is logged and counted by the reload itself.
    let _ = service.reload(trigger, false).await;
}

async fn run(service: Arc<Service>, reloader: Arc<Reloader>) {
    let token = service.tasks().token().clone();
    let mut hangup = hangup();
    let mut applied = reloader.follow_applied();
    // The contents the watch last loaded and refused, with the contents then in force: a
    // refused file is not loaded again until it (or what runs) changes.
    let mut refused: Option<(String, String)> = None;
    let mut again = false;
    loop {
        applied.borrow_and_update();
        let (config, profiles, settings) = reloader.watched().await;
        let (tx, mut rx) = mpsc::channel(EVENTS);
        let _watcher = if settings.watch {
            match watcher(&config, profiles.as_deref(), tx) {
                Ok(w) => {
                    tracing::info!(config = %config.display(), profiles = ?profiles, "watching the configuration for changes");
                    Some(w)
                }
                Err(e) => {
                    tracing::error!(error = %e, "cannot watch the configuration files; reload with SIGHUP or the API");
                    None
                }
            }
        } else {
            None
        };
        if std::mem::take(&mut again) && settings.watch {
            look(&service, &reloader, &config, &profiles, &mut refused).await;
        }
        let mut due: Option<Instant> = None;
        loop {
            let wait = due.unwrap_or_else(|| Instant::now() + Duration::from_secs(3600));
            tokio::select! {
                _ = token.cancelled() => return,
                _ = next_hangup(&mut hangup) => {
                    tracing::info!("SIGHUP: reloading the configuration");
                    reload(&service, Trigger::Sighup).await;
                }
                // Any trigger's reload: its settings, and directories, anew.
                Ok(()) = applied.changed() => break,
                Some(()) = rx.recv() => due = Some(Instant::now() + settings.debounce),
                _ = tokio::time::sleep_until(wait), if due.is_some() => {
                    look(&service, &reloader, &config, &profiles, &mut refused).await;
                    // Made anew: a directory renamed over the watched one is followed (and
                    // what changed while it was made is looked at once more, below).
                    again = true;
                    break;
                }
            }
        }
    }
}

/// Reloads when the files' contents differ from those in force, unless the same contents
/// were refused while the same ones ran.
async fn look(
    service: &Arc<Service>,
    reloader: &Reloader,
    config: &Path,
    profiles: &Option<PathBuf>,
    refused: &mut Option<(String, String)>,
) {
    let now = contents(config, profiles.clone(), reloader.outside().await).await;
    let in_force = reloader.hash().await;
    if now == in_force || refused.as_ref() == Some(&(now.clone(), in_force.clone())) {
        return;
    }
    let outcome = service.reload(Trigger::Watch, false).await;
    *refused = outcome.is_err().then_some((now, in_force));
}

/// The hash of the files' contents now.
async fn contents(config: &Path, profiles: Option<PathBuf>, outside: Vec<PathBuf>) -> String {
    let path = config.to_path_buf();
    tokio::task::spawn_blocking(move || hash_files(&path, profiles.as_deref(), &outside))
        .await
        .unwrap_or_default()
}
