//! The outstation's side of the wire for fuzzing: a master's APDUs taken as a master's task
//! takes them (through the windows; a broken sequence ends it as it ends a connection),
//! every ASDU decoded, answered as a refusal would answer it, and each command's element
//! read as a write of every field type; and text as a map file.

use std::time::Duration;

use super::{table, values};
use crate::codec::IecType;
use crate::drivers::iec104::apci::Frame;
use crate::drivers::iec104::asdu::Asdu;
use crate::drivers::iec104::window::{Limits, Window};

pub(crate) fn master(data: &[u8]) {
    let mut window = Window::new(Limits {
        k: 2,
        w: 2,
        t1: Duration::from_secs(1),
        t2: Duration::from_millis(500),
        t3: Duration::from_secs(2),
    });
    let mut at = 0;
    while let Ok(Some((frame, used))) = Frame::decode(&data[at..]) {
        at += used;
        let ok = match frame {
            Frame::I { send, recv, asdu } => {
                take(&asdu);
                window.received(send, recv).is_ok()
            }
            Frame::S { recv } => window.acknowledged(recv).is_ok(),
            Frame::U(_) => {
                // What the outstation sends between: an I-frame of its own to acknowledge.
                let _ = window.send();
                true
            }
        };
        if !ok {
            break;
        }
    }
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = table::parse_some_entries(text, "map.yaml");
    }
}

fn take(octets: &[u8]) {
    let Ok(asdu) = Asdu::decode(octets) else {
        return;
    };
    for cause in [7, 10, 44, 45, 46, 47] {
        let _ = asdu.answer(cause, true).encode();
    }
    for o in &asdu.objects {
        for ty in IecType::ALL {
            if let Ok((value, _)) = values::commanded(&o.element, ty) {
                assert!(
                    value.is_of(ty),
                    "a command read as a {ty:?} write: {value:?}"
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    /// c104's STARTDT, interrogation, clock synchronisation and set-point as a master
    /// sent them, every octet changed in turn to every value: no panic.
    #[test]
    fn a_masters_frames_changed_anywhere_are_taken_or_refused() {
        let frames = [
            "680407000000680e0000000064010600ffff00000014",
            "681402000c0067010600ffff00000070c20c11030c1a",
            "681204000e003201060001000900000000324200",
            "680e06000e002d01060001000300000081",
        ];
        for hex in frames {
            let bytes: Vec<u8> = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("hex"))
                .collect();
            for at in 0..bytes.len() {
                for octet in 0..=255u8 {
                    let mut changed = bytes.clone();
                    changed[at] = octet;
                    super::master(&changed);
                    super::master(&changed[..at]);
                }
            }
        }
    }
}
