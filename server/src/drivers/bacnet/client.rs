//! The client on a link's port, and what its failures mean: shared by the reads, the
//! writes, the subscriptions, the scan and the import.

use std::sync::Arc;

use bacnet_client::client::BACnetClient;
use bacnet_transport::bip::{BipTransport, ForeignDeviceConfig};
use bacnet_types::enums::AbortReason;
use bacnet_types::error::{Error, RemoteError};

use super::config::Settings;
use crate::cache::FieldError;
use crate::link::{LinkFault, TxError};

/// Starts the client on the link's port.
pub(super) async fn start(s: &Settings) -> Result<BACnetClient<BipTransport>, Error> {
    let mut transport = BipTransport::new(*s.bind.ip(), s.bind.port(), s.broadcast);
    if let Some((bbmd, ttl)) = s.bbmd {
        transport.register_as_foreign_device(ForeignDeviceConfig {
            bbmd_ip: *bbmd.ip(),
            bbmd_port: bbmd.port(),
            ttl: u16::try_from(ttl.as_secs()).unwrap_or(u16::MAX).max(1),
            renewal_interval: None,
        });
    }
    let config = bacnet_client::client::ClientConfig {
        interface: *s.bind.ip(),
        port: s.bind.port(),
        broadcast_address: s.broadcast,
        apdu_timeout_ms: u64::try_from(s.timeout.as_millis()).unwrap_or(u64::MAX),
        apdu_retries: s.retries,
        ..Default::default()
    };
    BACnetClient::start(config, transport).await
}

/// What a failed request means: the port itself failed (`Err`), or the device's answer or
/// silence (`Ok`, its field error, and whether it was silence).
pub(super) fn failure(e: Error) -> Result<(FieldError, bool), LinkFault> {
    match e {
        Error::Transport(io) => Err(LinkFault::Lost(Arc::new(io))),
        Error::Timeout(_) => Ok((FieldError::NoResponse(TxError::Timeout), true)),
        // The client's own transaction timer, after the retries.
        Error::Remote(RemoteError::Abort { reason }) if reason == AbortReason::TSM_TIMEOUT => {
            Ok((FieldError::NoResponse(TxError::Timeout), true))
        }
        Error::Remote(RemoteError::Abort { reason }) => Ok((
            FieldError::Device(format!("the device aborted the request ({reason})")),
            false,
        )),
        Error::Remote(RemoteError::Reject { reason }) => Ok((
            FieldError::Device(format!("the device rejected the request ({reason})")),
            false,
        )),
        e @ (Error::Remote(_) | Error::Structured { .. }) => {
            Ok((FieldError::Device(e.to_string()), false))
        }
        e => Ok((
            FieldError::Device(format!("the answer does not decode: {e}")),
            false,
        )),
    }
}
