//! One raw transaction on a link, queued in its task between polls (the same queue the
//! Modbus server's pass-through uses), answered as the function blocks report it.

use std::time::Duration;

use tokio::sync::oneshot;
use tokio::time::Instant;

use super::{Service, ServiceError};
use crate::cache::{Link, Passthrough, PassthroughError, Stage};
use crate::config::{Framing, Transport};
use crate::link::frame::{Request, Response};
use crate::link::rtu_frame;
use crate::transaction::params::ParamError;
use crate::transaction::{Outcome, Plan, TransactionSpec, codec, failure, hex, state};

/// The frame as it goes on the line: RTU (slave, PDU, CRC) on serial links and RTU over
/// TCP; unit id and PDU on Modbus TCP links.
fn frame(rtu: bool, slave: u8, pdu: &[u8]) -> String {
    if rtu {
        return hex(&rtu_frame::seal(slave, pdu));
    }
    let mut bytes = vec![slave];
    bytes.extend_from_slice(pdu);
    hex(&bytes)
}

/// Beyond a request's deadline and timeout, how long its caller waits for the link's task
/// before taking it as gone.
const TASK_GRACE: Duration = Duration::from_secs(2);

impl Service {
    /// Queues `request` for `slave` in `link`'s inbox and waits for the answer. A request
    /// the link cannot send before `deadline` is dropped unsent (`Expired`; `Busy` when
    /// the inbox is full); a task that gives no answer within the deadline, the timeout
    /// and a grace is `NoAnswer`.
    pub(crate) async fn pass_through(
        &self,
        link: &Link,
        slave: u8,
        request: &Request,
        timeout: Duration,
        deadline: Instant,
        stage: Option<tokio::sync::watch::Sender<Stage>>,
    ) -> Result<Response, PassthroughError> {
        let (reply, answer) = oneshot::channel();
        link.submit(Passthrough {
            slave,
            request: request.clone(),
            timeout,
            deadline,
            reply,
            stage,
        });
        let answered = tokio::time::timeout_at(deadline + timeout + TASK_GRACE, answer)
            .await
            .ok()
            .and_then(Result::ok)
            .unwrap_or(Err(PassthroughError::NoAnswer));
        if let Err(PassthroughError::Busy) = answered {
            self.metrics.inbox_dropped(link.name(), "busy");
        }
        answered
    }
}

fn request_pdu(request: &Request) -> Vec<u8> {
    let mut pdu = Vec::new();
    request.encode(&mut pdu);
    pdu
}

impl Service {
    /// Runs one transaction on `link`: every parameter problem at once (with the read
    /// block's messages), else the outcome (a transaction that ran and failed is an
    /// outcome, not an error).
    pub(crate) async fn transact(
        &self,
        link: &str,
        spec: &TransactionSpec,
    ) -> Result<Outcome, ServiceError> {
        self.transact_staged(link, spec, None).await
    }

    /// [`Service::transact`], telling `stage` where the request is on its way.
    pub(crate) async fn transact_staged(
        &self,
        link: &str,
        spec: &TransactionSpec,
        stage: Option<tokio::sync::watch::Sender<Stage>>,
    ) -> Result<Outcome, ServiceError> {
        self.accepting()?;
        self.owning_field()?;
        let link = self.cache.link(link).ok();
        let checked = spec.check();
        let checked = match (checked, &link) {
            (Ok(c), Some(_)) => c,
            (result, _) => {
                let mut errors = result.err().unwrap_or_default();
                if link.is_none() {
                    errors.push(ParamError::MissingRs485);
                }
                return Err(ServiceError::Transaction(errors));
            }
        };
        let Some(link) = link else {
            return Err(ServiceError::Transaction(vec![ParamError::MissingRs485]));
        };
        if matches!(checked.plan, Plan::Write(_)) {
            self.accepting_writes()?;
        }
        let config = link.config();
        let rtu = !matches!(
            config.transport,
            Transport::Tcp {
                framing: Framing::Mbap,
                ..
            }
        );
        let request = checked.request();
        let said = Said {
            rtu,
            slave: checked.slave(),
            request: frame(rtu, checked.slave(), &request_pdu(&request)),
            started: Instant::now(),
        };
        if !config.transport.is_configured() {
            return Ok(said.outcome(
                false,
                state::INTERFACE_UNAVAILABLE,
                None,
                Some("RS485 setup incomplete."),
                None,
            ));
        }
        // The request waits at most its timeout plus a second in the link's inbox; one the
        // link cannot send by then is dropped (busy), never sent late.
        let deadline = said.started + checked.timeout * 2 + Duration::from_secs(1);
        let answered = self
            .pass_through(
                &link,
                said.slave,
                &request,
                checked.timeout,
                deadline,
                stage,
            )
            .await;
        said.answered(answered, &checked.plan, &request)
            .map_err(|()| ServiceError::Busy(link.name().to_owned()))
    }
}

/// A transaction's request as sent, and when: what its outcome says with it.
struct Said {
    rtu: bool,
    slave: u8,
    request: String,
    started: Instant,
}

impl Said {
    fn outcome(
        &self,
        actual: bool,
        state: i32,
        value: Option<f64>,
        error: Option<&'static str>,
        response: Option<String>,
    ) -> Outcome {
        Outcome {
            actual,
            state,
            value,
            error,
            request: self.request.clone(),
            response,
            elapsed_ms: (self.started.elapsed().as_secs_f64() * 1e6).round() / 1e3,
        }
    }

    /// The outcome of the link's answer; `Err` when the link was too busy to send it.
    fn answered(
        &self,
        answered: Result<Response, PassthroughError>,
        plan: &Plan,
        request: &Request,
    ) -> Result<Outcome, ()> {
        let (rtu, slave) = (self.rtu, self.slave);
        let outcome = |actual, state, value, error, response| {
            self.outcome(actual, state, value, error, response)
        };
        Ok(match answered {
            Err(PassthroughError::Busy | PassthroughError::Expired) => return Err(()),
            Ok(response) => {
                let response_frame = Some(frame(rtu, slave, &response.to_pdu(request)));
                match plan {
                    Plan::Read(read) => match codec::read_value(read, &response) {
                        Ok(v) => outcome(true, state::DONE, Some(v), None, response_frame),
                        Err(_) => outcome(
                            false,
                            state::UNKNOWN_ERROR,
                            None,
                            Some("Value parse failed"),
                            response_frame,
                        ),
                    },
                    Plan::Write(_) => outcome(true, state::DONE, None, None, response_frame),
                }
            }
            Err(PassthroughError::Tx(e)) => {
                let (code, message) = failure(&e);
                let response_frame = match &e {
                    crate::link::TxError::Exception(x) => {
                        Some(frame(rtu, slave, &x.to_pdu(request.function().code())))
                    }
                    _ => None,
                };
                outcome(false, code, None, Some(message), response_frame)
            }
            Err(PassthroughError::LinkDown(_) | PassthroughError::NotModbus) => outcome(
                false,
                state::INTERFACE_UNAVAILABLE,
                None,
                Some("RS485 port missing."),
                None,
            ),
            Err(PassthroughError::NoAnswer) => outcome(
                false,
                state::TIMEOUT,
                None,
                Some("Master/RS485 timeout"),
                None,
            ),
        })
    }
}
