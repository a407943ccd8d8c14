//! The tasks of a running gateway: one per link, one per simulated device, and the
//! long-lived streams of the APIs. All of them hang off one cancellation token and one
//! tracker, so shutdown cancels them together and waits for each.

use std::future::Future;
use std::sync::Arc;

use tokio_util::sync::CancellationToken;
use tokio_util::task::TaskTracker;

use crate::cache::{Device, Link};
use crate::metrics::Metrics;
use crate::poller::LinkTask;
use crate::role::Role;

/// Starts the tasks that own links and simulated devices, at start-up and when one is
/// declared at run time, and any other task that must end with the gateway.
#[derive(Debug, Clone)]
pub(crate) struct Tasks {
    tracker: TaskTracker,
    token: CancellationToken,
    metrics: Arc<Metrics>,
    /// This gateway's role in its pair: a link task owns its link only while it may.
    role: Arc<Role>,
}

impl Tasks {
    pub(crate) fn new(
        tracker: TaskTracker,
        token: CancellationToken,
        metrics: Arc<Metrics>,
    ) -> Self {
        Tasks {
            tracker,
            token,
            metrics,
            role: Arc::new(Role::alone()),
        }
    }

    /// The tasks of node `role` of an active/standby pair.
    pub(crate) fn with_role(mut self, role: Arc<Role>) -> Self {
        self.role = role;
        self
    }

    pub(crate) fn role(&self) -> &Arc<Role> {
        &self.role
    }

    pub(crate) fn metrics(&self) -> &Arc<Metrics> {
        &self.metrics
    }

    /// The token cancelled at shutdown.
    pub(crate) fn token(&self) -> &CancellationToken {
        &self.token
    }

    /// Starts a link's task; it ends at shutdown or when the link is removed.
    pub(crate) fn spawn_link(&self, link: Arc<Link>) {
        let token = self.token.child_token();
        link.attach_task(token.clone());
        let task = LinkTask::new(link, self.metrics.clone()).with_role(self.role.clone());
        self.tracker.spawn(task.run(token));
    }

    /// Starts a simulated device's task; it ends at shutdown or when the device is removed.
    pub(crate) fn spawn_sim(&self, device: Arc<Device>) {
        let token = self.token.child_token();
        device.attach_task(token.clone());
        self.tracker.spawn(crate::sim::run(device, token));
    }

    /// Runs `task` until it ends; shutdown waits for it, so it must watch [`Tasks::token`].
    pub(crate) fn spawn<F>(&self, task: F)
    where
        F: Future<Output = ()> + Send + 'static,
    {
        self.tracker.spawn(task);
    }
}
