//! What the outstation answers one master, bytes apart: a general interrogation confirmed,
//! every point with cause 20 by type, then terminated (a counter interrogation the same
//! with the counters, cause 37); a read answered with its point; the clock
//! synchronisation and test confirmed; every command checked as a write is (the field
//! writable, the value one its type holds), confirmed (ACTCON) when requested or selected,
//! refused (negative ACTCON) when not, and terminated (ACTTERM) by its outcome, negative
//! when it failed. Anything else is mirrored negative with the standard's cause: an
//! unknown type (44), cause (45), common address (46) or information object (47). A
//! confirmation or termination mirrors its request's common address, the broadcast one
//! too (as lib60870's masters match them: answered with the station's own, c104 waits out
//! its command timeout); the objects an interrogation answers carry the station's own.

use super::selection::{Selected, Selections};
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Duration;

use super::served::Served;
use super::spontaneous::{Reading, Spontaneous};
use super::values;
use crate::codec::CodecError;
use crate::drivers::iec104::apci::MAX_ASDU;
use crate::drivers::iec104::asdu::{Asdu, Object, Time, cause};
use crate::drivers::iec104::element::Element;
use crate::drivers::iec104::time::Cp56;
use crate::drivers::iec104::types::{Kind, TypeId, id};
use crate::service::Service;
use crate::write_log::WriteStatus;

/// Answers waiting for the master's window, at most: a master that asks faster than it
/// takes answers loses its connection.
pub(crate) const MAX_REPLIES: usize = 1024;
/// Commands waiting for their outcome per master, at most (more are refused).
pub(crate) const MAX_PENDING: usize = 64;
/// The broadcast common address.
const BROADCAST: u16 = 0xFFFF;

/// A command requested, waiting for its outcome (its ACTTERM).
struct Pending {
    generation: u64,
    command: Asdu,
}

/// An interrogation being answered.
struct Interrogation {
    counters: bool,
    request: Asdu,
    at: usize,
}

pub(crate) struct Station {
    pub(crate) common_address: u16,
    pub(crate) time_tags: bool,
    /// A time-tagged command this far from the gateway's clock is refused.
    pub(crate) command_max_age: Option<Duration>,
    service: Arc<Service>,
    replies: VecDeque<Vec<u8>>,
    /// Under way, in the order asked: at most one general and one counter interrogation.
    interrogations: VecDeque<Interrogation>,
    pending: Vec<Pending>,
    selected: Selected,
    pub(crate) spontaneous: Spontaneous,
}

/// The octets of `asdu` (every ASDU made here encodes).
fn octets(asdu: &Asdu) -> Vec<u8> {
    asdu.encode().unwrap_or_default()
}

/// Objects of `type_id` one ASDU holds.
fn per_asdu(type_id: TypeId) -> usize {
    let kind = type_id.kind().map_or(5, Kind::size);
    ((MAX_ASDU - 6) / (3 + kind + type_id.tag().len())).min(127)
}

/// The time-tagged form of an untagged monitor type.
fn tagged(ty: u8) -> u8 {
    match ty {
        id::M_SP_NA_1 => id::M_SP_TB_1,
        id::M_DP_NA_1 => id::M_DP_TB_1,
        id::M_BO_NA_1 => id::M_BO_TB_1,
        id::M_ME_NA_1 => id::M_ME_TD_1,
        id::M_ME_NB_1 => id::M_ME_TE_1,
        id::M_ME_NC_1 => id::M_ME_TF_1,
        id::M_IT_NA_1 => id::M_IT_TB_1,
        other => other,
    }
}

impl Station {
    /// A station answering as the section `c` says.
    pub(crate) fn new(
        service: Arc<Service>,
        c: &super::config::Iec104ServerConfig,
        selections: Selections,
    ) -> Station {
        Station {
            common_address: c.common_address,
            time_tags: c.time_tags,
            command_max_age: c.command_max_age,
            service,
            replies: VecDeque::new(),
            interrogations: VecDeque::new(),
            pending: Vec::new(),
            selected: Selected::new(selections, c.select_timeout),
            spontaneous: Spontaneous::default(),
        }
    }

    /// Whether more answers wait than the bound allows.
    pub(crate) fn overflowing(&self) -> bool {
        self.replies.len() > MAX_REPLIES
    }

    /// Whether a command waits for its outcome.
    pub(crate) fn waiting(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Whether anything waits to be sent.
    pub(crate) fn has_next(&self) -> bool {
        !self.replies.is_empty() || !self.interrogations.is_empty() || self.spontaneous.any()
    }

    /// The next ASDU to send: answers first, then an interrogation's, then spontaneous data.
    pub(crate) fn next(&mut self, served: &Served) -> Option<Vec<u8>> {
        if let Some(reply) = self.replies.pop_front() {
            return Some(reply);
        }
        if let Some(asdu) = self.interrogated(served) {
            return Some(octets(&asdu));
        }
        let time_tags = self.time_tags;
        let most = |ty: u8| per_asdu(TypeId(if time_tags { tagged(ty) } else { ty }));
        let (ty, readings) = self.spontaneous.take(most)?;
        let ty = if time_tags { tagged(ty) } else { ty };
        let objects = readings
            .into_iter()
            .map(|(i, r)| self.object(served, i, r, time_tags))
            .collect();
        Some(octets(&Asdu::new(
            TypeId(ty),
            cause::SPONTANEOUS,
            self.common_address,
            objects,
        )))
    }

    fn object(
        &self,
        served: &Served,
        i: usize,
        (value, quality, at): Reading,
        tag: bool,
    ) -> Object {
        let p = served.point(i);
        let element = values::element(p.kind(), value.as_ref(), quality);
        let time = tag.then(|| {
            let millis = values::millis(at.unwrap_or_else(std::time::SystemTime::now));
            Time::Full(Cp56::at(millis))
        });
        Object {
            ioa: p.ioa,
            element,
            time,
        }
    }

    /// The next ASDU of the interrogation under way, or its termination.
    fn interrogated(&mut self, served: &Served) -> Option<Asdu> {
        let gi = self.interrogations.front_mut()?;
        let order = if gi.counters {
            &served.counters
        } else {
            &served.general
        };
        let Some(&first) = order.get(gi.at) else {
            let done = self.interrogations.pop_front()?;
            return Some(done.request.answer(cause::ACT_TERM, false));
        };
        let ty = served.point(first).asdu;
        let mut points = Vec::new();
        while let Some(&i) = order.get(gi.at) {
            if served.point(i).asdu != ty || points.len() >= per_asdu(ty) {
                break;
            }
            points.push(i);
            gi.at += 1;
        }
        let (reason, originator) = match gi.counters {
            true => (cause::COUNTER_INTERROGATED, gi.request.originator),
            false => (cause::INTERROGATED, gi.request.originator),
        };
        let objects = points
            .into_iter()
            .map(|i| self.object(served, i, served.current(i), false))
            .collect();
        let mut asdu = Asdu::new(ty, reason, self.common_address, objects);
        asdu.originator = originator;
        Some(asdu)
    }

    fn reply(&mut self, asdu: Asdu) {
        self.replies.push_back(octets(&asdu));
    }

    fn refuse(&mut self, asdu: &Asdu, reason: u8, why: &str) {
        tracing::info!(
            asdu = asdu.type_id.name(),
            ioa = asdu.objects.first().map_or(0, |o| o.ioa),
            why,
            "IEC 104 request refused"
        );
        let mut answer = asdu.answer(reason, true);
        answer.common_address = asdu.common_address;
        self.reply(answer);
    }

    /// Takes an ASDU the master sent.
    pub(crate) fn take(&mut self, served: &Served, raw: &[u8]) {
        let asdu = match Asdu::decode(raw) {
            Ok(asdu) => asdu,
            Err(e) => return self.undecoded(raw, &e.to_string()),
        };
        let ty = asdu.type_id.0;
        let broadcast = asdu.common_address == BROADCAST
            && matches!(
                ty,
                id::C_IC_NA_1 | id::C_CI_NA_1 | id::C_CS_NA_1 | id::C_RP_NA_1
            );
        if asdu.common_address != self.common_address && !broadcast {
            return self.refuse(&asdu, cause::UNKNOWN_ADDRESS, "another common address");
        }
        match ty {
            id::C_IC_NA_1 | id::C_CI_NA_1 => self.interrogation(asdu),
            id::C_RD_NA_1 => self.read(served, asdu),
            id::C_CS_NA_1 | id::C_TS_TA_1 if asdu.cause == cause::ACTIVATION => {
                let mut answer = asdu.answer(cause::ACT_CON, false);
                if ty == id::C_CS_NA_1 {
                    let now = values::millis(std::time::SystemTime::now());
                    answer.objects[0].element = Element::ClockSync(Cp56::at(now));
                }
                self.reply(answer);
            }
            id::C_CS_NA_1 | id::C_TS_TA_1 => self.refuse(
                &asdu,
                cause::UNKNOWN_CAUSE,
                "a clock synchronisation or test is an activation (cause 6)",
            ),
            id::C_RP_NA_1 => {
                self.refuse(&asdu, cause::ACT_CON, "a reset of the process is not done")
            }
            id::C_SC_NA_1..=id::C_BO_NA_1 | 58..=64 => self.command(served, asdu),
            _ => self.refuse(
                &asdu,
                cause::UNKNOWN_TYPE,
                "not a request an outstation takes",
            ),
        }
    }

    /// An ASDU that did not decode, mirrored with cause 44 when its header is whole.
    fn undecoded(&mut self, raw: &[u8], why: &str) {
        tracing::info!(why, "IEC 104 ASDU from a master not understood");
        if raw.len() >= 6 {
            let mut answer = raw.to_vec();
            answer[2] = cause::UNKNOWN_TYPE | 0x40 | (raw[2] & 0x80);
            self.replies.push_back(answer);
        }
    }

    fn interrogation(&mut self, asdu: Asdu) {
        let qualifier = match asdu.objects[0].element {
            Element::Interrogation(q) | Element::CounterInterrogation(q) => q,
            _ => 0,
        };
        let counters = asdu.type_id.0 == id::C_CI_NA_1;
        match asdu.cause {
            cause::ACTIVATION => {}
            cause::DEACTIVATION => {
                self.interrogations.retain(|i| i.counters != counters);
                return self.reply(asdu.answer(cause::DEACT_CON, false));
            }
            _ => {
                return self.refuse(
                    &asdu,
                    cause::UNKNOWN_CAUSE,
                    "an interrogation is activated or deactivated",
                );
            }
        }
        let (valid, station) = match counters {
            // RQT 1-5 (groups, general).
            true => ((1..=5).contains(&(qualifier & 0x3F)), qualifier & 0x3F == 5),
            false => ((20..=36).contains(&qualifier), qualifier == 20),
        };
        if !valid {
            return self.refuse(
                &asdu,
                cause::ACT_CON,
                "an interrogation qualifier the standard does not have",
            );
        }
        if counters && qualifier >> 6 != 0 {
            // FRZ 1-3: the counters frozen or reset, which the gateway does not do.
            return self.refuse(
                &asdu,
                cause::ACT_CON,
                "counters are read, not frozen or reset (FRZ 0 only)",
            );
        }
        if !station {
            // Groups have no points: confirmed and terminated.
            self.reply(asdu.answer(cause::ACT_CON, false));
            return self.reply(asdu.answer(cause::ACT_TERM, false));
        }
        if self.interrogations.iter().any(|i| i.counters == counters) {
            // The one under way is answered whole and terminated; this one is not begun.
            return self.refuse(
                &asdu,
                cause::ACT_CON,
                "an interrogation of this kind is under way",
            );
        }
        self.reply(asdu.answer(cause::ACT_CON, false));
        self.interrogations.push_back(Interrogation {
            counters,
            request: asdu,
            at: 0,
        });
    }

    fn read(&mut self, served: &Served, asdu: Asdu) {
        if asdu.cause != cause::REQUEST {
            return self.refuse(&asdu, cause::UNKNOWN_CAUSE, "a read is a request (cause 5)");
        }
        let ioa = asdu.objects[0].ioa;
        let found = served
            .table
            .get(ioa)
            .filter(|p| !p.is_command())
            .map(|p| p.asdu);
        let Some(ty) = found else {
            return self.refuse(&asdu, cause::UNKNOWN_OBJECT, "no point to read there");
        };
        let Some(i) = served.table.index(ioa) else {
            return;
        };
        let object = self.object(served, i, served.current(i), false);
        let mut answer = Asdu::new(ty, cause::REQUEST, self.common_address, vec![object]);
        answer.originator = asdu.originator;
        self.reply(answer);
    }

    fn command(&mut self, served: &Served, asdu: Asdu) {
        let ioa = asdu.objects[0].ioa;
        let Some(point) = served.table.get(ioa).filter(|p| p.is_command()).cloned() else {
            return self.refuse(&asdu, cause::UNKNOWN_OBJECT, "no command point there");
        };
        let ty = asdu.type_id.0;
        let base = if ty >= 58 { ty - 13 } else { ty };
        if base != point.asdu.0 || asdu.objects.len() != 1 {
            let why = format!("the point takes one {}", point.asdu.name());
            return self.refuse(&asdu, cause::UNKNOWN_TYPE, &why);
        }
        match asdu.cause {
            cause::ACTIVATION => self.activate(served, &point, asdu),
            cause::DEACTIVATION => {
                let selected = self.selected.deselect(ioa);
                let answer = asdu.answer(cause::DEACT_CON, !selected);
                self.reply(answer);
            }
            _ => self.refuse(
                &asdu,
                cause::UNKNOWN_CAUSE,
                "a command is activated or deactivated",
            ),
        }
    }

    fn activate(&mut self, served: &Served, point: &super::table::Point, asdu: Asdu) {
        let (value, select) = match values::commanded(&asdu.objects[0].element, point.ty) {
            Ok(v) => v,
            Err(why) => return self.refuse(&asdu, cause::ACT_CON, &why),
        };
        if let Some(why) = self.stale(&asdu) {
            return self.refuse(&asdu, cause::ACT_CON, &why);
        }
        let Some(device) = served.device(&point.device) else {
            return self.refuse(&asdu, cause::ACT_CON, "the device is not running");
        };
        let prepared = self.service.prepare(&device, &point.field, |_| {
            Ok::<_, CodecError>(value.clone())
        });
        let prepared = match prepared {
            Ok(p) => p,
            Err(e) => return self.refuse(&asdu, cause::ACT_CON, &e.to_string()),
        };
        if asdu.test {
            return self.reply(asdu.answer(cause::ACT_CON, false));
        }
        let ioa = point.ioa;
        if select {
            return match self.selected.select(ioa, value) {
                Ok(()) => self.reply(asdu.answer(cause::ACT_CON, false)),
                Err(why) => self.refuse(&asdu, cause::ACT_CON, why),
            };
        }
        if let Err(why) = self.selected.execute(ioa, &value) {
            return self.refuse(&asdu, cause::ACT_CON, why);
        }
        if self.pending.len() >= MAX_PENDING {
            return self.refuse(
                &asdu,
                cause::ACT_CON,
                "too many commands of this master wait for their outcome",
            );
        }
        match self.service.write(prepared) {
            Ok(accepted) => {
                self.reply(asdu.answer(cause::ACT_CON, false));
                let generation = accepted.generation;
                self.pending.push(Pending {
                    generation,
                    command: asdu,
                });
            }
            Err(e) => self.refuse(&asdu, cause::ACT_CON, &e.to_string()),
        }
    }

    /// Why a time-tagged command is not executed: its time too far from the gateway's
    /// clock (a command delayed, or stored and sent again), or marked invalid.
    fn stale(&self, asdu: &Asdu) -> Option<String> {
        let most = self.command_max_age?;
        let Some(Time::Full(t)) = asdu.objects.first()?.time else {
            return None;
        };
        if t.invalid {
            return Some("its time tag is marked invalid (IV)".to_owned());
        }
        let off = values::millis(std::time::SystemTime::now()) - t.millis;
        (off.unsigned_abs() > most.as_millis() as u64).then(|| {
            format!("its time tag is {off} ms from the gateway's clock (command_max_age {most:?})")
        })
    }

    /// Terminates the commands whose writes have their outcome: ACTTERM, negative when the
    /// write did not reach the device.
    pub(crate) fn outcomes(&mut self) {
        let mut done = Vec::new();
        self.pending.retain(|p| match self.service.write_outcome(p.generation) {
            Ok(record) if record.status == WriteStatus::Pending => true,
            Ok(record) => {
                let ok = matches!(record.status, WriteStatus::Written);
                if !ok {
                    tracing::info!(status = record.status.name(), error = ?record.error, "IEC 104 command ended without being written");
                }
                done.push(p.command.answer(cause::ACT_TERM, !ok));
                false
            }
            Err(_) => {
                done.push(p.command.answer(cause::ACT_TERM, true));
                false
            }
        });
        for answer in done {
            self.reply(answer);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_asdu_holds_what_fits_in_249_octets() {
        assert_eq!(per_asdu(TypeId(id::M_ME_TF_1)), 243 / 15);
        assert_eq!(per_asdu(TypeId(id::M_SP_NA_1)), 243 / 4);
    }
}
