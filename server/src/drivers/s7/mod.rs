//! Siemens S7 PLCs as devices (`protocol: s7`): S7comm over ISO-on-TCP, written here (the
//! crates read were synchronous or a first release). A link is a PLC (`s7:` with `host`,
//! rack and slot or TSAPs); a field names its `address` as S7 users write it. A device's
//! fields are read in the fewest jobs the negotiated PDU allows; a BOOL is written as a
//! bit, never by rewriting its byte.

mod config;
mod conn;
pub(crate) mod pdu;
mod plan;

use std::sync::Arc;
use std::time::Duration;

use super::{Driver, Read, Session, finish, written};
use crate::cache::{Device, FieldError, Link, Progress, WriteError};
use crate::codec::IecType;
use crate::config::{LinkConfig, Transport};
use crate::link::LinkFault;
use crate::metrics::Metrics;
use crate::plan::WriteItem;
use crate::profile::s7_address::Width;
use conn::{Connection, S7Error};
use pdu::Item;
use plan::{Batch, Place};

/// The S7 driver.
pub(crate) struct S7;

/// Its links' key and its profiles' protocol.
pub(crate) const PROTOCOL: &str = "s7";

/// What is kept of a device: its fields' places and the jobs planned for a PDU size.
pub(crate) struct Plan {
    places: Vec<Result<Place, String>>,
    batches: Vec<Batch>,
    /// The PDU size the batches were planned for (0: not yet).
    pdu: u16,
}

/// An open PLC connection.
pub(crate) struct Plc {
    conn: Connection,
    progress: Arc<Progress>,
    timeout: Duration,
}

fn lost(e: &S7Error) -> LinkFault {
    LinkFault::Lost(Arc::new(std::io::Error::other(e.to_string())))
}

impl Driver for S7 {
    type Plan = Plan;
    type Session = Plc;
    const NAME: &'static str = PROTOCOL;

    fn serves(config: &LinkConfig) -> bool {
        matches!(&config.transport, Transport::Driver(d) if d.protocol == PROTOCOL)
    }

    fn check(config: &LinkConfig, report: &mut crate::yaml::Report) {
        if let Transport::Driver(d) = &config.transport {
            config::read(&config.name, d, report);
        }
    }

    fn plan(device: &Device) -> Plan {
        Plan {
            places: plan::places(&device.profile),
            batches: Vec::new(),
            pdu: 0,
        }
    }

    async fn open(
        config: &LinkConfig,
        link: &Arc<Link>,
        _metrics: &Arc<Metrics>,
    ) -> Result<Plc, LinkFault> {
        let Transport::Driver(d) = &config.transport else {
            return Err(LinkFault::NoPort);
        };
        let mut report = crate::yaml::Report::new("config");
        let Some(s) = config::read(&config.name, d, &mut report) else {
            return Err(LinkFault::OpenFailed {
                port: d.endpoint.clone(),
                reason: report.into_problems().to_string(),
            });
        };
        let conn = Connection::open(
            (s.host.as_str(), s.port),
            s.local_tsap,
            s.remote_tsap,
            s.pdu,
            s.timeout,
        )
        .await
        .map_err(|e| LinkFault::ConnectFailed {
            endpoint: format!("{}:{}", s.host, s.port),
            reason: Arc::new(std::io::Error::other(e.to_string())),
        })?;
        Ok(Plc {
            conn,
            progress: link.progress.clone(),
            timeout: s.timeout,
        })
    }
}

impl Plc {
    fn started(&self) {
        self.progress
            .started(tokio::time::Instant::now() + self.timeout);
    }
}

/// Publishes one answered item's fields.
fn publish_item(
    device: &Device,
    plan: &Plan,
    fields: &[(usize, u32)],
    answer: &Result<Vec<u8>, u8>,
) {
    for &(idx, offset) in fields {
        let Some(Ok(place)) = plan.places.get(idx) else {
            continue;
        };
        let value = match answer {
            Ok(bytes) => {
                let at = usize::try_from(offset).unwrap_or(usize::MAX);
                let mine = bytes.get(at..).unwrap_or_default();
                plan::decode(device.field(idx).ty, &place.address, mine).map_err(FieldError::Device)
            }
            Err(code) => Err(FieldError::Device(pdu::item_error(*code).to_owned())),
        };
        device.publish(idx, value);
    }
}

impl Session for Plc {
    type Plan = Plan;

    async fn read(&mut self, device: &Arc<Device>, plan: &mut Plan) -> Result<Read, LinkFault> {
        if plan.pdu != self.conn.pdu {
            plan.batches = plan::batches(&plan.places, self.conn.pdu);
            plan.pdu = self.conn.pdu;
            let room = plan::max_item(plan.pdu);
            for (idx, p) in plan.places.iter().enumerate() {
                let why = match p {
                    Err(why) => why.clone(),
                    Ok(p) if u32::from(p.bytes) > room => format!(
                        "{} bytes do not fit one item of the PLC's PDU ({room} bytes)",
                        p.bytes
                    ),
                    Ok(_) => continue,
                };
                device.publish(idx, Err(FieldError::Device(why)));
            }
        }
        let started = tokio::time::Instant::now();
        for batch in &plan.batches {
            self.started();
            let answered = self.conn.read(&batch.items).await;
            self.progress.ended();
            let answers = answered.map_err(|e| lost(&e))?;
            for (fields, answer) in batch.fields.iter().zip(&answers) {
                publish_item(device, plan, fields, answer);
            }
        }
        Ok(Read::Answered(started.elapsed()))
    }

    async fn write(
        &mut self,
        device: &Arc<Device>,
        plan: &mut Plan,
        items: Vec<WriteItem>,
    ) -> Result<Option<FieldError>, LinkFault> {
        let mut jobs = Vec::new();
        for item in items {
            let ty = device.field(item.field).ty;
            let place = match plan.places.get(item.field) {
                Some(Ok(p)) => *p,
                Some(Err(why)) => {
                    finish(device, &item, Err(WriteError::Refused(why.clone())), 0);
                    continue;
                }
                None => continue,
            };
            match plan::encode(ty, &item.value) {
                Ok(bytes) => {
                    let a = place.address;
                    let target = match (a.width, ty) {
                        (Width::Bit(b), _) => Item {
                            area: a.area,
                            db: a.db,
                            byte: a.byte,
                            bit: Some(b),
                            length: 1,
                        },
                        (_, IecType::String) => Item {
                            area: a.area,
                            db: a.db,
                            byte: a.byte + 1,
                            bit: None,
                            length: bytes.len() as u16,
                        },
                        _ => Item {
                            area: a.area,
                            db: a.db,
                            byte: a.byte,
                            bit: None,
                            length: bytes.len() as u16,
                        },
                    };
                    jobs.push((item, target, bytes));
                }
                Err(why) => finish(device, &item, Err(WriteError::Refused(why)), 0),
            }
        }
        for chunk in jobs.chunks(8) {
            let request: Vec<(Item, Vec<u8>)> =
                chunk.iter().map(|(_, t, b)| (*t, b.clone())).collect();
            self.started();
            let answered = self.conn.write(&request).await;
            self.progress.ended();
            let outcomes = match answered {
                Ok(o) => o,
                Err(e) => {
                    let fault = lost(&e);
                    for (item, _, _) in chunk {
                        finish(device, item, Err(WriteError::LinkDown(fault.clone())), 1);
                    }
                    return Err(fault);
                }
            };
            for ((item, _, _), outcome) in chunk.iter().zip(outcomes) {
                match outcome {
                    Ok(()) => {
                        written(device, item, 1);
                    }
                    Err(code) => finish(
                        device,
                        item,
                        Err(WriteError::Refused(pdu::item_error(code).to_owned())),
                        1,
                    ),
                }
            }
        }
        Ok(None)
    }
}

#[cfg(test)]
mod tests;
