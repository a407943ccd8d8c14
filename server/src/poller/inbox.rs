//! What of a link's inbox goes on the line: requests and probes whose callers are still
//! waiting and whose deadlines an answer can still meet, sent as they are.

use super::{Driven, Step};
use crate::cache::{Inbox, Passthrough, PassthroughError};
use crate::drivers::{Driver, Session};
use tokio::time::Instant;

impl<D: Driver> Driven<D> {
    /// What of the inbox may go on the line: a request or probe whose caller has gone, or
    /// whose deadline would pass before its answer could come, is never sent.
    pub(super) fn admit(&self, queued: Inbox) -> Option<Inbox> {
        if queued.abandoned() {
            self.metrics.inbox_dropped(self.link.name(), "abandoned");
            return None;
        }
        if queued.too_late(Instant::now()) {
            self.metrics.inbox_dropped(self.link.name(), "expired");
            queued.refuse(PassthroughError::Expired);
            return None;
        }
        Some(queued)
    }

    /// Sends a queued request as it is (a Modbus request to a unit), and answers it.
    pub(super) async fn pass_through(
        &mut self,
        queued: Passthrough,
        session: &mut D::Session,
    ) -> Step {
        if let Some(stage) = &queued.stage {
            stage.send_replace(crate::cache::Stage::Taken);
        }
        let label = self
            .devices
            .iter()
            .find(|p| p.device.slave_id().unwrap_or(0) == queued.slave)
            .map_or_else(
                || format!("unit{}", queued.slave),
                |p| p.device.name().to_owned(),
            );
        session.pass_through(queued, &label).await
    }
}
