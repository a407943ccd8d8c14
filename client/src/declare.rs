//! Declarations as a runtime's `SerialLink` and device function-block calls make them, a
//! raw transaction, and the removal of what was declared.

use std::time::Duration;

use iogate_proto::pb;

use crate::{Client, DeviceInfo, Error, LinkInfo, TransactOutcome};

/// A serial link as a runtime's `SerialLink` call declares it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialLink {
    /// The serial port path; empty declares a link without one yet.
    pub port: String,
    /// Baud rate.
    pub baud: u32,
    /// 'N', 'E' or 'O'.
    pub parity: char,
    /// 7 or 8.
    pub data_bits: u8,
    /// 1 or 2.
    pub stop_bits: u8,
}

/// A device as a runtime's device function-block call declares it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceDeclaration {
    /// The device's name.
    pub name: String,
    /// Its profile's name.
    pub profile: String,
    /// A link name or the serial port path (`serial.port`); empty for simulated profiles.
    pub link: String,
    /// 1-247; 0 declares the device without one yet.
    pub slave_id: u32,
    /// How often it is polled.
    pub refresh_rate: Duration,
}

impl Client {
    /// Declares a serial link; answers it and whether it was created now.
    pub async fn ensure_serial_link(
        &mut self,
        link: &SerialLink,
    ) -> Result<(LinkInfo, bool), Error> {
        self.ensure_named_serial_link("", link).await
    }

    /// One raw Modbus transaction on a link (`iogatectl tx`): a read FC01-04 or a write
    /// FC05/06/15/16, queued between the gateway's polls.
    pub async fn transact(
        &mut self,
        request: pb::TransactRequest,
    ) -> Result<TransactOutcome, Error> {
        let r = self.inner.transact(request).await?.into_inner();
        Ok(TransactOutcome {
            actual: r.actual,
            state: r.state,
            value: r.value,
            error: (!r.error.is_empty()).then_some(r.error),
            request: r.request,
            response: (!r.response.is_empty()).then_some(r.response),
            elapsed_ms: r.elapsed_ms,
        })
    }

    /// Declares a serial link by name, as a named `SerialLink` instance does: its port may
    /// be empty (the link then reports error 1, no port configured) and given later by
    /// declaring it again.
    pub async fn ensure_named_serial_link(
        &mut self,
        name: &str,
        link: &SerialLink,
    ) -> Result<(LinkInfo, bool), Error> {
        let r = self
            .inner
            .ensure_link(pb::EnsureLinkRequest {
                name: name.to_owned(),
                transport: Some(pb::ensure_link_request::Transport::Serial(
                    pb::SerialSettings {
                        port: link.port.clone(),
                        baud: link.baud,
                        parity: link.parity.to_string(),
                        data_bits: link.data_bits.into(),
                        stop_bits: link.stop_bits.into(),
                        framing: String::new(),
                    },
                )),
                guard_time_ms: 0,
            })
            .await?
            .into_inner();
        let info = r
            .link
            .ok_or_else(|| Error::Protocol("no link in the answer".into()))?;
        Ok((LinkInfo::from_pb(info), r.created))
    }

    /// Declares a device; answers it and whether it was created now.
    pub async fn ensure_device(
        &mut self,
        device: &DeviceDeclaration,
    ) -> Result<(DeviceInfo, bool), Error> {
        let r = self
            .inner
            .ensure_device(pb::EnsureDeviceRequest {
                name: device.name.clone(),
                profile: device.profile.clone(),
                link: device.link.clone(),
                slave_id: device.slave_id,
                refresh_rate_ms: u32::try_from(device.refresh_rate.as_millis()).unwrap_or(u32::MAX),
                timeout_ms: 0,
            })
            .await?
            .into_inner();
        let info = r
            .device
            .ok_or_else(|| Error::Protocol("no device in the answer".into()))?;
        Ok((DeviceInfo::from_pb(info), r.created))
    }

    /// Removes a device declared at run time.
    pub async fn remove_device(&mut self, name: &str) -> Result<(), Error> {
        self.inner
            .remove_device(pb::RemoveDeviceRequest {
                name: name.to_owned(),
            })
            .await?;
        Ok(())
    }

    /// Removes a standing transaction declared at run time.
    pub async fn remove_transaction(&mut self, name: &str) -> Result<(), Error> {
        self.inner
            .remove_transaction(pb::RemoveTransactionRequest {
                name: name.to_owned(),
            })
            .await?;
        Ok(())
    }

    /// Removes a link declared at run time (its devices and transactions first).
    pub async fn remove_link(&mut self, name: &str) -> Result<(), Error> {
        self.inner
            .remove_link(pb::RemoveLinkRequest {
                name: name.to_owned(),
            })
            .await?;
        Ok(())
    }
}
