//! Declaring links and devices at run time, the way a remote runtime's `SerialLink` and device
//! function-block calls do. A declaration is idempotent: declaring what exists is fine; a
//! declaration that contradicts what exists is refused and the contradiction named. The
//! rules a link or device obeys are the config file's ([`crate::config::rules`]).

mod device;
mod endpoint;
mod error;
mod link;

use std::sync::Arc;
use std::time::Duration;

use crate::cache::{AccessError, Binding, Cache, Device, Link, Registry};
use crate::config::rules::{self, RuleError};
use crate::config::security::DeclarePolicy;
use crate::config::{DeviceConfig, LinkConfig, Transport};
use crate::profile::Protocol;
use crate::runtime::Tasks;
use crate::text::quote;

pub(crate) use device::{ensure_device, remove_device};
pub(crate) use endpoint::Endpoint;
pub(crate) use error::{Conflict, DeclareError};
pub(crate) use link::{ensure_link, remove_link};

#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct LinkDeclaration {
    /// Optional: by default the name is made from the port (`/dev/ttyUSB0` → `dev_ttyUSB0`)
    /// or the endpoint (`192.0.2.10_502`).
    pub(crate) name: Option<String>,
    pub(crate) endpoint: Endpoint,
    pub(crate) guard_time: Duration,
}

#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct DeviceDeclaration {
    pub(crate) name: String,
    pub(crate) profile: String,
    /// A link name, or a serial port path as a `SerialLink` instance's `port` gives it.
    pub(crate) link: String,
    pub(crate) slave_id: u32,
    pub(crate) refresh_rate: Duration,
    pub(crate) timeout: Option<Duration>,
}

/// What a declaration resolved to, and whether it was created by it.
#[derive(Debug, Clone)]
pub(crate) struct Ensured<T> {
    pub(crate) value: Arc<T>,
    pub(crate) created: bool,
}

pub(super) fn valid_name(what: &'static str, name: &str) -> Result<(), DeclareError> {
    rules::name(name).map_err(|_| DeclareError::BadName {
        what,
        name: crate::text::quote(name),
    })
}

/// The most links and devices declarations may add to a gateway.
pub(crate) const MAX_DECLARED_LINKS: usize = 64;
pub(crate) const MAX_DECLARED_DEVICES: usize = 1024;
/// The timeouts a declared device may have.
pub(crate) const TIMEOUTS: std::ops::RangeInclusive<Duration> =
    Duration::from_millis(10)..=Duration::from_secs(10);
/// The refresh rates a declared device may have.
pub(crate) const REFRESH_RATES: std::ops::RangeInclusive<Duration> =
    Duration::from_millis(1)..=Duration::from_secs(3600);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cache::Refusal;
    use crate::config::{Framing, Parity};
    use crate::metrics::Metrics;
    use tokio_util::sync::CancellationToken;
    use tokio_util::task::TaskTracker;

    fn serial(baud: u64, parity: &str) -> Endpoint {
        Endpoint::Serial {
            port: "/nonexistent/ttyIOGATE7".into(),
            baud,
            parity: parity.into(),
            data_bits: 0,
            stop_bits: 0,
            framing: String::new(),
        }
    }

    #[test]
    fn a_declared_endpoint_obeys_the_config_rules_and_defaults() {
        let Ok(Transport::Serial(s)) = serial(9600, "").transport() else {
            panic!("valid serial settings")
        };
        assert_eq!((s.data_bits, s.stop_bits, s.parity), (8, 1, Parity::None));
        let err = serial(5, "X").transport().expect_err("bad parity and baud");
        assert_eq!(
            err.to_string(),
            "parity: Invalid parity configuration.\n`X` is not N, E or O; baud: Invalid baudrate configuration.\n5 baud is outside 300-4000000",
            "every problem at once"
        );
        let err = serial(5, "E").transport().expect_err("bad baud");
        assert_eq!(err.refusal(), Refusal::Invalid);
        assert!(
            err.to_string()
                .contains("Invalid baudrate configuration.\n5 baud")
        );
        let tcp = Endpoint::Tcp {
            host: "127.0.0.1".into(),
            port: 0,
            framing: String::new(),
        };
        assert_eq!(
            tcp.transport(),
            Ok(Transport::Tcp {
                host: "127.0.0.1".into(),
                port: rules::DEFAULT_TCP_PORT,
                framing: Framing::Mbap
            })
        );
    }

    #[tokio::test]
    async fn an_unbounded_guard_time_is_refused_before_anything_is_opened() {
        let setup = crate::app::Setup::demo_simulated().expect("demo");
        let cache = Cache::new(&setup.config, setup.catalog);
        let tasks = Tasks::new(
            TaskTracker::new(),
            CancellationToken::new(),
            Arc::new(Metrics::new()),
        );
        let everything = DeclarePolicy {
            serial_ports: vec!["*".into()],
            ..DeclarePolicy::default()
        };
        let err = ensure_link(
            &cache,
            &tasks,
            &everything,
            LinkDeclaration {
                name: None,
                endpoint: serial(9600, "N"),
                guard_time: Duration::from_millis(u64::from(u32::MAX)),
            },
        )
        .expect_err("refused");
        assert!(matches!(err, DeclareError::Rules(_)), "{err}");
        assert!(cache.links().is_empty(), "nothing was declared");
    }
}
