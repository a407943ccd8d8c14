//! A link's task around the driver's run: the driver of the link's protocol chosen (again
//! when a reload gives the link another), and the link owned only while this gateway owns
//! the field (alone, or the active of its pair).

use std::sync::Arc;

use tokio_util::sync::CancellationToken;

use super::{Driven, Ended};
use crate::cache::{Link, LinkDiagnostics, WriteError};
use crate::drivers::{Driver, ForDriver, with_driver};
use crate::link::LinkCode;
use crate::metrics::Metrics;
use crate::role::{self as ha, Role};

/// A link's task: it runs the link with the driver of its protocol, and with another one
/// when a reload gives the link another protocol.
pub(crate) struct LinkTask {
    link: Arc<Link>,
    metrics: Arc<Metrics>,
    role: Arc<Role>,
}

impl LinkTask {
    pub(crate) fn new(link: Arc<Link>, metrics: Arc<Metrics>) -> Self {
        LinkTask {
            link,
            metrics,
            role: Arc::new(Role::alone()),
        }
    }

    /// The task of a node of an active/standby pair: it opens the link only while the
    /// node is active, and closes it when the node stands down.
    pub(crate) fn with_role(mut self, role: Arc<Role>) -> Self {
        self.role = role;
        self
    }

    /// Runs the link until `token` is cancelled, while this gateway owns the field: a
    /// standby opens nothing, and a node that stands down closes what it opened and fails
    /// the writes still waiting (a new active takes the field).
    pub(crate) async fn run(self, token: CancellationToken) {
        let mut lease = self.role.watch();
        loop {
            while !self.role.owns_field() {
                self.standing_by();
                tokio::select! {
                    _ = token.cancelled() => return,
                    changed = lease.changed() => if changed.is_err() { return },
                }
            }
            let epoch = lease.borrow_and_update().epoch;
            let owned = token.child_token();
            let run = self.run_owned(owned.clone());
            tokio::pin!(run);
            tokio::select! {
                () = &mut run => return,
                () = ha::stood_down(&mut lease, epoch) => {
                    owned.cancel();
                    run.await;
                    if token.is_cancelled() {
                        return;
                    }
                    tracing::info!(link = %self.link.name(), "standing by: the link is closed");
                    self.fail_waiting();
                }
            }
        }
    }

    /// The link as a standby shows it: not connected, and why.
    fn standing_by(&self) {
        self.link.set_diagnostics(LinkDiagnostics {
            connected: false,
            error_code: LinkCode::Ok,
        });
        self.link.set_down(Some(
            "standby: the active gateway of the pair owns the field".into(),
        ));
    }

    /// The writes still waiting when this gateway stood down are not written by it.
    fn fail_waiting(&self) {
        for device in self.link.members() {
            for w in device.take_writes() {
                let fenced = self.role.may_write(w.generation).err();
                let why = fenced.unwrap_or(crate::role::Fenced::Standby);
                device.finish_write(w.generation, Err(WriteError::Fenced(why)));
            }
        }
    }

    /// Runs the link with its driver until `token` is cancelled.
    async fn run_owned(&self, token: CancellationToken) {
        loop {
            let config = self.link.config();
            let start = Start {
                link: self.link.clone(),
                metrics: self.metrics.clone(),
                role: self.role.clone(),
                token: token.clone(),
            };
            let ended = match with_driver(&config, start) {
                Some(running) => running.await,
                None => {
                    tracing::error!(link = %self.link.name(), "no driver serves this link");
                    token.cancelled().await;
                    Ended::Shutdown
                }
            };
            if matches!(ended, Ended::Shutdown) {
                break;
            }
        }
        tracing::debug!(link = %self.link.name(), "link task stopped");
    }
}

/// A link's task started with the driver of its protocol.
struct Start {
    link: Arc<Link>,
    metrics: Arc<Metrics>,
    role: Arc<Role>,
    token: CancellationToken,
}

impl ForDriver for Start {
    type Output = std::pin::Pin<Box<dyn std::future::Future<Output = Ended> + Send>>;

    fn with<D: Driver>(self) -> Self::Output {
        Box::pin(async move {
            Driven::<D>::new(self.link, self.metrics)
                .with_role(self.role)
                .run(&self.token)
                .await
        })
    }
}
