//! IEC 60870-5-101/104's ASDU as 104 fixes its sizes (a two-octet cause of transmission
//! with the originator address, a two-octet common address, three-octet information object
//! addresses): the data unit identifier, then its information objects, each with its
//! elements and time tag as its type says (`types.rs`). Bytes only, both directions; an
//! ASDU whose type is unknown or whose objects do not fill it exactly is an error naming
//! what was wrong.

use super::element::Element;
use super::time::{Cp24, Cp56};
use super::types::{Kind, Tag, TypeId};

/// Causes of transmission used here (IEC 60870-5-101, 7.2.3).
pub(crate) mod cause {
    pub(crate) const PERIODIC: u8 = 1;
    pub(crate) const BACKGROUND: u8 = 2;
    pub(crate) const SPONTANEOUS: u8 = 3;
    pub(crate) const INITIALISED: u8 = 4;
    pub(crate) const REQUEST: u8 = 5;
    pub(crate) const ACTIVATION: u8 = 6;
    pub(crate) const ACT_CON: u8 = 7;
    pub(crate) const DEACTIVATION: u8 = 8;
    pub(crate) const DEACT_CON: u8 = 9;
    pub(crate) const ACT_TERM: u8 = 10;
    pub(crate) const RETURN_REMOTE: u8 = 11;
    pub(crate) const RETURN_LOCAL: u8 = 12;
    pub(crate) const INTERROGATED: u8 = 20;
    pub(crate) const COUNTER_INTERROGATED: u8 = 37;
    pub(crate) const UNKNOWN_TYPE: u8 = 44;
    pub(crate) const UNKNOWN_CAUSE: u8 = 45;
    pub(crate) const UNKNOWN_ADDRESS: u8 = 46;
    pub(crate) const UNKNOWN_OBJECT: u8 = 47;

    /// A cause as the standard names it.
    pub(crate) fn name(cause: u8) -> String {
        match cause {
            PERIODIC => "per/cyc".into(),
            BACKGROUND => "back".into(),
            SPONTANEOUS => "spont".into(),
            INITIALISED => "init".into(),
            REQUEST => "req".into(),
            ACTIVATION => "act".into(),
            ACT_CON => "actcon".into(),
            DEACTIVATION => "deact".into(),
            DEACT_CON => "deactcon".into(),
            ACT_TERM => "actterm".into(),
            RETURN_REMOTE => "retrem".into(),
            RETURN_LOCAL => "retloc".into(),
            INTERROGATED => "inrogen".into(),
            21..=36 => format!("inro{}", cause - 20),
            COUNTER_INTERROGATED => "reqcogen".into(),
            38..=41 => format!("reqco{}", cause - 37),
            UNKNOWN_TYPE => "unknown type".into(),
            UNKNOWN_CAUSE => "unknown cause".into(),
            UNKNOWN_ADDRESS => "unknown common address".into(),
            UNKNOWN_OBJECT => "unknown object address".into(),
            other => format!("cause {other}"),
        }
    }
}

/// The largest information object address (three octets).
pub(crate) const MAX_IOA: u32 = 0xFF_FFFF;

/// One information object: its address, its element, its time tag.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Object {
    pub(crate) ioa: u32,
    pub(crate) element: Element,
    pub(crate) time: Option<Time>,
}

/// A time tag as the object carried it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Time {
    Short(Cp24),
    Full(Cp56),
}

/// An ASDU.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Asdu {
    pub(crate) type_id: TypeId,
    /// SQ: the objects are one sequence from the first one's address.
    pub(crate) sequence: bool,
    pub(crate) cause: u8,
    /// P/N: the activation is refused.
    pub(crate) negative: bool,
    /// T: a test, not to be executed.
    pub(crate) test: bool,
    pub(crate) originator: u8,
    pub(crate) common_address: u16,
    pub(crate) objects: Vec<Object>,
}

/// Why octets are not an ASDU.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum Malformed {
    #[error("an ASDU of {0} octets is shorter than its data unit identifier")]
    Short(usize),
    #[error("type identification {0} is not one this gateway knows")]
    UnknownType(u8),
    #[error("an ASDU of type {type_id} says {count} objects and has {octets} octets for them")]
    Objects {
        type_id: &'static str,
        count: usize,
        octets: usize,
    },
    #[error("an ASDU with no information object")]
    NoObjects,
    #[error("information object {ioa}: {why}")]
    Element { ioa: u32, why: String },
    #[error("{0} information objects do not fit in one ASDU")]
    TooMany(usize),
}

impl Asdu {
    /// An ASDU of `objects` of one type, each with its own address.
    pub(crate) fn new(
        type_id: TypeId,
        cause: u8,
        common_address: u16,
        objects: Vec<Object>,
    ) -> Asdu {
        Asdu {
            type_id,
            sequence: false,
            cause,
            negative: false,
            test: false,
            originator: 0,
            common_address,
            objects,
        }
    }

    /// The answer to this activation with `cause` (its confirmation or termination),
    /// negative when refused: the same type, addresses and objects.
    pub(crate) fn answer(&self, cause: u8, negative: bool) -> Asdu {
        Asdu {
            cause,
            negative,
            ..self.clone()
        }
    }

    pub(crate) fn encode(&self) -> Result<Vec<u8>, Malformed> {
        let count = self.objects.len();
        if count == 0 {
            return Err(Malformed::NoObjects);
        }
        if count > 127 {
            return Err(Malformed::TooMany(count));
        }
        let mut out = vec![
            self.type_id.0,
            (count as u8) | if self.sequence { 0x80 } else { 0 },
            self.cause & 0x3F
                | if self.negative { 0x40 } else { 0 }
                | if self.test { 0x80 } else { 0 },
            self.originator,
        ];
        out.extend_from_slice(&self.common_address.to_le_bytes());
        for (i, o) in self.objects.iter().enumerate() {
            if i == 0 || !self.sequence {
                out.extend_from_slice(&o.ioa.to_le_bytes()[..3]);
            }
            o.element.encode(self.type_id, &mut out);
            match o.time {
                Some(Time::Full(t)) => out.extend_from_slice(&t.encode()),
                Some(Time::Short(t)) => out.extend_from_slice(&t.encode()),
                None => {}
            }
        }
        if out.len() > super::apci::MAX_ASDU {
            return Err(Malformed::TooMany(count));
        }
        Ok(out)
    }

    pub(crate) fn decode(b: &[u8]) -> Result<Asdu, Malformed> {
        if b.len() < 6 {
            return Err(Malformed::Short(b.len()));
        }
        let type_id = TypeId(b[0]);
        let kind = type_id.kind().ok_or(Malformed::UnknownType(b[0]))?;
        let sequence = b[1] & 0x80 != 0;
        let count = usize::from(b[1] & 0x7F);
        if count == 0 {
            return Err(Malformed::NoObjects);
        }
        let size = kind.size() + type_id.tag().len();
        let octets = b.len() - 6;
        let wanted = if sequence {
            3 + count * size
        } else {
            count * (3 + size)
        };
        if octets != wanted {
            return Err(Malformed::Objects {
                type_id: type_id.name(),
                count,
                octets,
            });
        }
        let mut objects = Vec::with_capacity(count);
        let mut at = 6;
        let mut ioa = 0;
        for i in 0..count {
            if i == 0 || !sequence {
                ioa = u32::from_le_bytes([b[at], b[at + 1], b[at + 2], 0]);
                at += 3;
            } else {
                ioa = (ioa + 1) & MAX_IOA;
            }
            let bad = |why: String| Malformed::Element { ioa, why };
            let element = Element::decode(kind, &b[at..at + kind.size()]).map_err(bad)?;
            at += kind.size();
            let time = match type_id.tag() {
                Tag::None => None,
                Tag::Short => {
                    let t: [u8; 3] = b[at..at + 3].try_into().unwrap_or_default();
                    Some(Time::Short(Cp24::decode(&t).map_err(bad)?))
                }
                Tag::Full => {
                    let t: [u8; 7] = b[at..at + 7].try_into().unwrap_or_default();
                    Some(Time::Full(Cp56::decode(&t).map_err(bad)?))
                }
            };
            at += type_id.tag().len();
            objects.push(Object { ioa, element, time });
        }
        Ok(Asdu {
            type_id,
            sequence,
            cause: b[2] & 0x3F,
            negative: b[2] & 0x40 != 0,
            test: b[2] & 0x80 != 0,
            originator: b[3],
            common_address: u16::from_le_bytes([b[4], b[5]]),
            objects,
        })
    }

    /// The kind of its elements.
    pub(crate) fn kind(&self) -> Kind {
        self.type_id.kind().unwrap_or(Kind::Single)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drivers::iec104::element::Quality;
    use crate::drivers::iec104::types::id;

    #[test]
    fn a_general_interrogation_is_the_octets_the_standard_shows() {
        let gi = Asdu::new(
            TypeId(id::C_IC_NA_1),
            cause::ACTIVATION,
            1,
            vec![Object {
                ioa: 0,
                element: Element::Interrogation(20),
                time: None,
            }],
        );
        let b = gi.encode().expect("fits");
        assert_eq!(b, [100, 1, 6, 0, 1, 0, 0, 0, 0, 20]);
        assert_eq!(Asdu::decode(&b), Ok(gi));
    }

    #[test]
    fn a_sequence_of_measured_values_with_time_tags_goes_both_ways() {
        let t = Cp56::at(1_795_711_845_123);
        let objects = (0..3)
            .map(|i| Object {
                ioa: 700 + i,
                element: Element::Float {
                    value: i as f32 * 1.5,
                    quality: Quality(if i == 1 { Quality::IV } else { 0 }),
                },
                time: Some(Time::Full(t)),
            })
            .collect();
        let mut asdu = Asdu::new(TypeId(id::M_ME_TF_1), cause::SPONTANEOUS, 7, objects);
        asdu.sequence = true;
        let b = asdu.encode().expect("fits");
        assert_eq!(b.len(), 6 + 3 + 3 * (5 + 7));
        assert_eq!(Asdu::decode(&b), Ok(asdu.clone()));
        asdu.sequence = false;
        let b = asdu.encode().expect("fits");
        assert_eq!(b.len(), 6 + 3 * (3 + 5 + 7));
        assert_eq!(Asdu::decode(&b), Ok(asdu));
    }

    #[test]
    fn an_asdu_that_its_objects_do_not_fill_is_named() {
        // M_SP_NA_1 saying 2 objects, with one.
        let e = Asdu::decode(&[1, 2, 3, 0, 1, 0, 1, 0, 0, 1]).expect_err("short");
        assert_eq!(
            e.to_string(),
            "an ASDU of type M_SP_NA_1 says 2 objects and has 4 octets for them"
        );
        assert_eq!(
            Asdu::decode(&[0, 1, 3, 0, 1, 0]),
            Err(Malformed::UnknownType(0))
        );
        assert_eq!(Asdu::decode(&[1, 0, 3, 0, 1, 0]), Err(Malformed::NoObjects));
        assert_eq!(Asdu::decode(&[1, 1, 3]), Err(Malformed::Short(3)));
        // A double point's CP56Time2a of month 13.
        let e = Asdu::decode(&[31, 1, 3, 0, 1, 0, 5, 0, 0, 2, 0, 0, 0, 0, 1, 13, 26])
            .expect_err("month");
        assert!(e.to_string().starts_with("information object 5: "), "{e}");
    }

    #[test]
    fn a_negative_confirmation_keeps_the_command() {
        let cmd = Asdu::new(
            TypeId(id::C_SE_NC_1),
            cause::ACTIVATION,
            1,
            vec![Object {
                ioa: 4001,
                element: Element::SetFloat {
                    value: 2.5,
                    select: false,
                    ql: 0,
                },
                time: None,
            }],
        );
        let con = cmd.answer(cause::ACT_CON, true);
        let b = con.encode().expect("fits");
        assert_eq!(b[2], 7 | 0x40);
        let back = Asdu::decode(&b).expect("an ASDU");
        assert!(back.negative);
        assert_eq!(back.objects, cmd.objects);
    }
}
