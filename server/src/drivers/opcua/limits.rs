//! How many items one request to a server may carry, per service: the server's operation
//! limits (OPC UA Part 5, `Server/ServerCapabilities/OperationLimits`), read when the
//! session opens, within the gateway's own bound. A server that enforces limits it does not
//! publish answers `BadTooManyOperations`: the request is sent again in halves, and the
//! smaller size is kept for the rest of the session.

use std::future::Future;
use std::ops::Range;
use std::sync::atomic::{AtomicUsize, Ordering};

use opcua::types::{DataValue, ReadValueId, StatusCode, TimestampsToReturn, VariableId, Variant};

use super::Connection;

/// The most items the gateway puts in one request, whatever a server allows.
pub(crate) const MOST: usize = 500;

/// A service whose requests carry many items.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Service {
    Read,
    Write,
    Browse,
    Translate,
    Monitor,
}

impl Service {
    const ALL: [Service; 5] = [
        Service::Read,
        Service::Write,
        Service::Browse,
        Service::Translate,
        Service::Monitor,
    ];

    /// The variable of `OperationLimits` that bounds it.
    fn limit(self) -> VariableId {
        use VariableId as V;
        match self {
            Service::Read => V::Server_ServerCapabilities_OperationLimits_MaxNodesPerRead,
            Service::Write => V::Server_ServerCapabilities_OperationLimits_MaxNodesPerWrite,
            Service::Browse => V::Server_ServerCapabilities_OperationLimits_MaxNodesPerBrowse,
            Service::Translate => {
                V::Server_ServerCapabilities_OperationLimits_MaxNodesPerTranslateBrowsePathsToNodeIds
            }
            Service::Monitor => {
                V::Server_ServerCapabilities_OperationLimits_MaxMonitoredItemsPerCall
            }
        }
    }

    fn name(self) -> &'static str {
        match self {
            Service::Read => "read",
            Service::Write => "write",
            Service::Browse => "browse",
            Service::Translate => "translate",
            Service::Monitor => "monitor",
        }
    }
}

/// The items per request of each service in one session.
#[derive(Debug)]
pub(crate) struct Limits([AtomicUsize; 5]);

impl Default for Limits {
    fn default() -> Self {
        Limits(std::array::from_fn(|_| AtomicUsize::new(MOST)))
    }
}

impl Limits {
    /// From what the server publishes (0, or nothing read: no limit of its own).
    pub(crate) fn published(values: &[Option<u32>]) -> Limits {
        let limits = Limits::default();
        for (slot, value) in limits.0.iter().zip(values) {
            if let Some(n) = value.filter(|n| *n > 0) {
                slot.store((n as usize).min(MOST), Ordering::Relaxed);
            }
        }
        limits
    }

    /// How many items a request of `service` carries at most.
    pub(crate) fn of(&self, service: Service) -> usize {
        self.0[service as usize].load(Ordering::Relaxed)
    }

    /// After a request of `tried` items was refused as too many: whether a smaller one is
    /// worth sending (half as many, kept).
    fn halve(&self, service: Service, tried: usize) -> bool {
        if tried <= 1 {
            return false;
        }
        self.0[service as usize].fetch_min(tried / 2, Ordering::Relaxed);
        true
    }

    /// Each service's size, for the log.
    pub(crate) fn says(&self) -> String {
        Service::ALL
            .iter()
            .map(|s| format!("{} {}", s.name(), self.of(*s)))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Reads the server's operation limits (a server without them: the gateway's own).
pub(crate) async fn read(session: &opcua::client::Session) -> Limits {
    let asked: Vec<ReadValueId> = Service::ALL
        .iter()
        .map(|s| ReadValueId::from(opcua::types::NodeId::from(s.limit())))
        .collect();
    // All five in one Read; a server that takes fewer nodes a Read is asked one at a time.
    let values = match session.read(&asked, TimestampsToReturn::Neither, 0.0).await {
        Ok(values) => values.iter().map(number).collect(),
        Err(_) => {
            let mut values = Vec::with_capacity(asked.len());
            for one in &asked {
                let read = session
                    .read(std::slice::from_ref(one), TimestampsToReturn::Neither, 0.0)
                    .await;
                values.push(read.ok().and_then(|v| v.first().and_then(number)));
            }
            values
        }
    };
    Limits::published(&values)
}

fn number(value: &DataValue) -> Option<u32> {
    match value.value.as_ref()? {
        Variant::UInt32(n) => Some(*n),
        Variant::UInt16(n) => Some(u32::from(*n)),
        Variant::Int32(n) => u32::try_from(*n).ok(),
        _ => None,
    }
}

/// Whether a request failed because it carried too many items.
fn too_many(e: &opcua::types::Error) -> bool {
    e.status().sub_code() == StatusCode::BadTooManyOperations.sub_code()
}

/// What one request got, with the items it carried (their place in the whole).
pub(crate) type Answered<R> = (Range<usize>, Result<Vec<R>, opcua::types::Error>);

/// Sends `items` in requests of `service` within the session's limit, each through `call`;
/// a request refused as too many operations is sent again smaller. Stops after a request
/// whose failure ends the link: the items after it were not sent.
pub(crate) async fn in_requests<'a, T, R, F, Fut>(
    conn: &Connection,
    service: Service,
    items: &'a [T],
    mut call: F,
) -> Vec<Answered<R>>
where
    F: FnMut(&'a [T]) -> Fut,
    Fut: Future<Output = Result<Vec<R>, opcua::types::Error>>,
{
    let mut answered = Vec::new();
    let mut at = 0;
    while at < items.len() {
        let n = conn.limits.of(service).min(items.len() - at);
        conn.started();
        let got = call(&items[at..at + n]).await;
        conn.ended();
        if let Err(e) = &got
            && too_many(e)
            && conn.limits.halve(service, n)
        {
            tracing::info!(url = %conn.settings.url, "the server takes at most {} items per {} request", conn.limits.of(service), service.name());
            continue;
        }
        let ends = matches!(&got, Err(e) if conn.fault(e).is_some());
        answered.push((at..at + n, got));
        at += n;
        if ends {
            break;
        }
    }
    answered
}

/// Every item's answer in order, or the first request's failure.
pub(crate) async fn all<'a, T, R, F, Fut>(
    conn: &Connection,
    service: Service,
    items: &'a [T],
    call: F,
) -> Result<Vec<R>, opcua::types::Error>
where
    F: FnMut(&'a [T]) -> Fut,
    Fut: Future<Output = Result<Vec<R>, opcua::types::Error>>,
{
    let mut out = Vec::with_capacity(items.len());
    for (_, got) in in_requests(conn, service, items, call).await {
        out.extend(got?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn published_limits_within_the_gateways_own() {
        let l = Limits::published(&[Some(100), Some(0), None, Some(10_000), Some(1)]);
        assert_eq!(l.of(Service::Read), 100);
        assert_eq!(l.of(Service::Write), MOST);
        assert_eq!(l.of(Service::Browse), MOST);
        assert_eq!(l.of(Service::Translate), MOST);
        assert_eq!(l.of(Service::Monitor), 1);
    }

    #[test]
    fn a_refusal_halves_down_to_one() {
        let l = Limits::default();
        assert!(l.halve(Service::Read, 500));
        assert_eq!(l.of(Service::Read), 250);
        assert!(l.halve(Service::Read, 3));
        assert_eq!(l.of(Service::Read), 1);
        assert!(!l.halve(Service::Read, 1));
        assert_eq!(l.of(Service::Write), MOST);
    }
}
