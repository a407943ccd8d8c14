//! The links' watchdog: every transaction is bounded (its timeout and its wire time), so a
//! link's task still inside one past that bound and [`Progress::GRACE`] makes no progress.
//! Such a link is reported as it is (`connected: false`, error 3, its devices error 10, the
//! `iogate_link_stalled` metric, `/readyz`), and again as connected once the task moves on.
//! The same look tells the subscribers of fields whose values went stale (not refreshed
//! within their device's `stale_after`), which no read would tell them.

use std::collections::HashSet;
use std::sync::Arc;
use std::time::Duration;

use tokio_util::sync::CancellationToken;

use crate::cache::{Cache, LinkDiagnostics, Progress};
use crate::link::LinkCode;

/// How often the links are looked at.
pub(crate) const EVERY: Duration = Duration::from_secs(1);

/// Looks at every link each [`EVERY`] until `token` is cancelled.
pub(crate) async fn run(cache: Arc<Cache>, token: CancellationToken) {
    let mut tick = tokio::time::interval(EVERY);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut stalled = HashSet::new();
    loop {
        tokio::select! {
            _ = token.cancelled() => return,
            _ = tick.tick() => {}
        }
        look(&cache, &mut stalled);
        let now = tokio::time::Instant::now();
        for device in cache.devices() {
            device.tell_stale(now);
        }
    }
}

/// One look: reports links that stalled since the last look, and links that moved on.
fn look(cache: &Cache, stalled: &mut HashSet<String>) {
    let links = cache.links();
    stalled.retain(|name| links.iter().any(|l| l.name() == name));
    for link in links {
        let name = link.name().to_owned();
        match link.stalled() {
            Some(overdue) if !stalled.contains(&name) => {
                tracing::error!(link = %name, overdue = ?overdue + Progress::GRACE, "link stalled: its task is in a transaction past its bound");
                link.set_diagnostics(LinkDiagnostics {
                    connected: false,
                    error_code: LinkCode::Lost,
                });
                for device in link.members() {
                    device.set_unreachable();
                }
                stalled.insert(name);
            }
            None if stalled.remove(&name) => {
                tracing::warn!(link = %name, "link makes progress again");
                link.set_diagnostics(LinkDiagnostics {
                    connected: true,
                    error_code: LinkCode::Ok,
                });
            }
            _ => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{LinkConfig, Transport};
    use tokio::time::Instant;

    #[tokio::test(start_paused = true)]
    async fn a_link_past_its_bound_is_reported_and_recovers() {
        let setup = crate::app::Setup::demo_simulated().expect("demo");
        let mut config = setup.config.clone();
        config.links.push(LinkConfig {
            name: "line".into(),
            transport: Transport::Tcp {
                host: "192.0.2.1".into(),
                port: 502,
                framing: crate::config::Framing::Mbap,
            },
            guard_time: Duration::ZERO,
            line: 1,
        });
        let cache = Cache::new(&config, setup.catalog);
        let link = cache.link("line").expect("link");
        link.set_diagnostics(LinkDiagnostics {
            connected: true,
            error_code: LinkCode::Ok,
        });
        let mut stalled = HashSet::new();

        // Within its bound: nothing to report.
        link.progress
            .started(Instant::now() + Duration::from_millis(200));
        tokio::time::advance(Duration::from_secs(2)).await;
        look(&cache, &mut stalled);
        assert!(link.diagnostics().connected);

        tokio::time::advance(Progress::GRACE).await;
        assert!(link.stalled().is_some());
        look(&cache, &mut stalled);
        assert_eq!(
            link.diagnostics(),
            LinkDiagnostics {
                connected: false,
                error_code: LinkCode::Lost
            }
        );
        link.progress.ended();
        look(&cache, &mut stalled);
        assert!(link.diagnostics().connected);
        assert!(stalled.is_empty());
    }
}
