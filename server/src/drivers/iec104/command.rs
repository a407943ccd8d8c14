//! Commands: an output's write as the command its type (or `asdu:`) calls for, its value
//! in the raw form the station stores, selected first where the field says `select: true`;
//! the station's positive confirmation (and with `termination: true` its termination) the
//! outcome. The line counts as busy while a command is under way.

use std::sync::Arc;

use tokio::time::Instant;

use super::asdu::{Asdu, cause};
use super::route::Answers;
use super::session::Station;
use super::types::TypeId;
use super::{Place, Plan, point, value};
use crate::cache::{Device, FieldError, Stamp, WriteError};
use crate::codec::Value;
use crate::drivers::{WriteItem, finish, written};
use crate::link::{LinkFault, TxError};

/// What a command is made of: where, at which common address, which type, which value.
struct Command {
    place: Place,
    ca: u16,
    type_id: TypeId,
    value: Value,
}

impl Station {
    /// Writes one output as its command, finishing the write with its outcome. `Err` only
    /// when the command could not be given to the connection (nothing of it was sent).
    pub(super) async fn command(
        &self,
        device: &Arc<Device>,
        plan: &Plan,
        item: WriteItem,
    ) -> Result<(), LinkFault> {
        let c = match made(device, plan, &item) {
            Ok(c) => c,
            Err(why) => {
                finish(device, &item, Err(WriteError::Refused(why)), 0);
                return Ok(());
            }
        };
        let t1 = self.settings.t1;
        let steps = 1 + u32::from(c.place.select) + u32::from(c.place.termination);
        self.link.progress.started(Instant::now() + t1 * steps);
        let outcome = self.exchange(&c).await;
        self.link.progress.ended();
        match outcome? {
            Ok(()) => written(device, &item, 1),
            Err(why @ WriteError::NoResponse(_)) => {
                unknown(device, item.field, c.type_id, c.place.ioa);
                finish(device, &item, Err(why), 1);
            }
            Err(why) => finish(device, &item, Err(why), 1),
        }
        Ok(())
    }

    /// Sends the command (its select first where it has one) and takes the answers.
    async fn exchange(&self, c: &Command) -> Result<Result<(), WriteError>, LinkFault> {
        let name = c.type_id.name();
        let steps: &[bool] = if c.place.select {
            &[true, false]
        } else {
            &[false]
        };
        let mut answers = None;
        let mut terminated = None;
        for &select in steps {
            let element = match value::command(c.type_id, &c.value, select) {
                Ok(e) => e,
                Err(why) => return Ok(Err(WriteError::Refused(why))),
            };
            let asdu = self.asdu(c.type_id.0, c.ca, c.place.ioa, element);
            let step = if select { "select" } else { "execute" };
            let answers = answers.insert(self.request(asdu).await?);
            match self.confirmation(answers, &mut terminated).await {
                Some(a) if a.cause == cause::ACT_CON && !a.negative => {}
                Some(a) => {
                    return Ok(Err(WriteError::Refused(format!(
                        "{name} {step} at IOA {}: {}{}",
                        c.place.ioa,
                        if a.negative { "negative " } else { "" },
                        cause::name(a.cause)
                    ))));
                }
                None => return Ok(Err(WriteError::NoResponse(TxError::Timeout))),
            }
        }
        let Some(answers) = answers.as_mut().filter(|_| c.place.termination) else {
            return Ok(Ok(()));
        };
        Ok(match terminated {
            Some(positive) => termination(positive, c.type_id, c.place.ioa),
            None => self.terminated(answers, c.type_id, c.place.ioa).await,
        })
    }

    /// The station's confirmation of a step within t1; a termination that comes before it
    /// (out of order) is kept for later, not taken as the answer.
    async fn confirmation(
        &self,
        answers: &mut Answers,
        terminated: &mut Option<bool>,
    ) -> Option<Asdu> {
        let deadline = Instant::now() + self.settings.t1;
        loop {
            let a = answers
                .next(deadline.saturating_duration_since(Instant::now()))
                .await?;
            if a.cause == cause::ACT_TERM {
                *terminated = Some(!a.negative);
                continue;
            }
            return Some(a);
        }
    }

    /// A confirmed command's termination (ACTTERM) within t1: positive, or why not.
    async fn terminated(
        &self,
        answers: &mut Answers,
        command: TypeId,
        ioa: u32,
    ) -> Result<(), WriteError> {
        let deadline = Instant::now() + self.settings.t1;
        while let Some(a) = answers
            .next(deadline.saturating_duration_since(Instant::now()))
            .await
        {
            if a.cause == cause::ACT_TERM {
                return termination(!a.negative, command, ioa);
            }
        }
        Err(WriteError::NoResponse(TxError::Timeout))
    }
}

/// A command with no answer may have been executed: the value shown for its field is not
/// vouched for any more (kept, stale, with why), until a command's outcome is known.
fn unknown(device: &Device, idx: usize, command: TypeId, ioa: u32) {
    let why = FieldError::Device(format!(
        "{} at IOA {ioa} was not answered: the station may hold the value asked",
        command.name()
    ));
    match device.sample(idx).value {
        Some(v) => device.publish_from(idx, Ok(v), Some(why), None, Stamp::now()),
        None => device.publish(idx, Err(why)),
    }
}

fn termination(positive: bool, command: TypeId, ioa: u32) -> Result<(), WriteError> {
    if positive {
        Ok(())
    } else {
        Err(WriteError::Refused(format!(
            "{} at IOA {ioa}: confirmed, then a negative actterm",
            command.name()
        )))
    }
}

/// The command an output's write makes, or why there is none.
fn made(device: &Device, plan: &Plan, item: &WriteItem) -> Result<Command, String> {
    let (place, ca) = match (&plan.places[item.field], &plan.common_address) {
        (Ok(p), Ok(ca)) => (*p, *ca),
        (Err(why), _) | (_, Err(why)) => return Err(why.clone()),
    };
    let field = &device.profile.fields[item.field];
    let ty = field.stored_type();
    let type_id = point::command_for(ty, place.fixed)
        .ok_or_else(|| format!("IEC 104 has no command for a {ty}"))?;
    let value = field.to_raw(item.value()?)?;
    Ok(Command {
        place,
        ca,
        type_id,
        value,
    })
}
