//! One id probed: the discovery probe, the follow-up reads and identification of a device
//! that answered, and the profiles that fit it.

use std::sync::Arc;

use super::Prober;
use super::judge::{self, Heard};
use super::probe::{read, read_pdu};
use super::{Found, Identification, ScanError, Setting, ident, matching};
use crate::profile::{Profile, RegisterKind};

/// The discovery probe (FC 03, address 0, one register): any answer, data or exception,
/// means a device. A garbled one is tried once more.
pub(super) async fn discover(
    prober: &mut dyn Prober,
    id: u8,
    setting: Setting,
    profiles: &[Arc<Profile>],
) -> Result<Discovered, ScanError> {
    let pdu = read_pdu(RegisterKind::HoldingRegister, 0, 1);
    let first = prober.probe(id, &pdu, false).await?;
    let mut heard = judge::judge(&first, id, 3);
    let mut garbled = None;
    let mut damaged = 0;
    if matches!(heard, Heard::Garbled(_)) {
        // Once more: what the two hearings show (the same damage twice is one device).
        damaged += 1;
        let again = prober.probe(id, &pdu, false).await?;
        heard = judge::judge(&again, id, 3);
        if matches!(heard, Heard::Garbled(_)) {
            garbled = Some(judge::garbled(&first, &again, id, 3));
        }
    }
    let mut collision = match &heard {
        Heard::Silent => {
            if let Some(other) = judge::foreign(&first, id, 3) {
                return Ok(Discovered::Foreign(other));
            }
            return Ok(Discovered::Nothing);
        }
        Heard::Two(_) => Some("two answers to one request".to_owned()),
        Heard::Garbled(_) | Heard::One(_) => None,
    };
    let first = judge::read_answer(RegisterKind::HoldingRegister, 0, 1, &heard);
    let mut device = Found {
        slave_id: id,
        setting,
        reads: vec![first],
        identification: None,
        collision: None,
        garbled,
        unsteady: None,
        profiles: Vec::new(),
    };
    for kind in [
        RegisterKind::InputRegister,
        RegisterKind::Coil,
        RegisterKind::DiscreteInput,
    ] {
        let (answer, two) = read(prober, id, kind, 0, 1).await?;
        collision = collision.or(two);
        damaged += usize::from(answer.answer == "garbled");
        device.reads.push(answer);
    }
    if damaged > 0 && device.garbled.is_none() {
        device.unsteady = Some(format!(
            "{damaged} of its answers to {} requests were garbled, the others not: a noisy line, or a baud rate or parity at its edge; check the line before relying on it",
            device.reads.len() + damaged
        ));
    }
    device.identification = identify(prober, id, &mut collision).await?;
    device.collision = collision;
    matching::suggest(prober, &mut device, profiles).await?;
    Ok(Discovered::Device(Box::new(device)))
}

/// What one id's discovery probe found.
pub(super) enum Discovered {
    Nothing,
    Device(Box<Found>),
    /// Only an answer as another id (the one given): a device that answers with an id of
    /// its own whatever is asked.
    Foreign(u8),
}

/// FC 43 / MEI 14: the basic objects, then the regular ones where the device offers them,
/// following "more follows" at most twice each.
async fn identify(
    prober: &mut dyn Prober,
    id: u8,
    collision: &mut Option<String>,
) -> Result<Option<Identification>, ScanError> {
    let mut found = Identification::default();
    let mut any = false;
    let mut conformity = 0;
    for code in [ident::BASIC, ident::REGULAR] {
        if code == ident::REGULAR && conformity & 0x7F < 2 {
            break;
        }
        let mut object = 0;
        for _ in 0..2 {
            let pdu = ident::request(code, object);
            let heard = judge::judge(&prober.probe(id, &pdu, true).await?, id, ident::FUNCTION);
            if matches!(heard, Heard::Two(_)) {
                collision.get_or_insert_with(|| "two answers to one request".to_owned());
            }
            let (Heard::One(pdu) | Heard::Two(pdu)) = heard else {
                break;
            };
            let Ok(answer) = ident::parse(&pdu) else {
                break;
            };
            any |= !answer.objects.is_empty();
            conformity = answer.conformity;
            for (k, v) in &answer.objects {
                found.add(*k, v);
            }
            match answer.next {
                Some(next) if next > object => object = next,
                _ => break,
            }
        }
    }
    Ok(any.then_some(found))
}
