//! An information object's element: a value with its quality descriptor, a command with
//! its qualifier, a system element; as octets both ways, as its type's kind says.

use super::time::Cp56;
use super::types::{Kind, TypeId};

/// A quality descriptor's bits (QDS; SIQ and DIQ carry the same ones but OV).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Quality(pub(crate) u8);

impl Quality {
    pub(crate) const OV: u8 = 0x01;
    pub(crate) const BL: u8 = 0x10;
    pub(crate) const SB: u8 = 0x20;
    pub(crate) const NT: u8 = 0x40;
    pub(crate) const IV: u8 = 0x80;

    /// The bits the standard defines: OV, BL, SB, NT, IV.
    fn of(octet: u8) -> Quality {
        Quality(octet & 0xF1)
    }

    pub(crate) fn has(self, bit: u8) -> bool {
        self.0 & bit != 0
    }

    /// The bits set, by their names (`IV NT`).
    pub(crate) fn names(self) -> Vec<&'static str> {
        [
            (Self::IV, "IV"),
            (Self::NT, "NT"),
            (Self::SB, "SB"),
            (Self::BL, "BL"),
            (Self::OV, "OV"),
        ]
        .into_iter()
        .filter(|(b, _)| self.has(*b))
        .map(|(_, n)| n)
        .collect()
    }
}

/// An information object's element.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Element {
    Single {
        on: bool,
        quality: Quality,
    },
    /// 0 indeterminate, 1 off, 2 on, 3 indeterminate.
    Double {
        state: u8,
        quality: Quality,
    },
    Step {
        value: i8,
        transient: bool,
        quality: Quality,
    },
    Bits {
        bits: u32,
        quality: Quality,
    },
    Normalized {
        value: i16,
        quality: Quality,
    },
    Scaled {
        value: i16,
        quality: Quality,
    },
    Float {
        value: f32,
        quality: Quality,
    },
    Counter {
        value: i32,
        sequence: u8,
        carry: bool,
        adjusted: bool,
        invalid: bool,
    },
    SingleCommand {
        on: bool,
        qu: u8,
        select: bool,
    },
    DoubleCommand {
        state: u8,
        qu: u8,
        select: bool,
    },
    /// RCS: 1 a step lower, 2 a step higher.
    StepCommand {
        step: u8,
        qu: u8,
        select: bool,
    },
    SetNormalized {
        value: i16,
        select: bool,
        ql: u8,
    },
    SetScaled {
        value: i16,
        select: bool,
        ql: u8,
    },
    SetFloat {
        value: f32,
        select: bool,
        ql: u8,
    },
    BitsCommand(u32),
    /// COI.
    EndOfInit(u8),
    /// QOI: 20 the station, 21-36 a group.
    Interrogation(u8),
    /// QCC.
    CounterInterrogation(u8),
    Read,
    ClockSync(Cp56),
    /// QRP.
    ResetProcess(u8),
    /// TSC.
    Test(u16),
}

fn word(b: &[u8]) -> i16 {
    i16::from_le_bytes([b[0], b[1]])
}

fn long(b: &[u8]) -> [u8; 4] {
    [b[0], b[1], b[2], b[3]]
}

/// A command qualifier's octet: the command's bits, QU in bits 2-6, S/E in bit 7.
fn command(bits: u8, qu: u8, select: bool) -> u8 {
    bits | ((qu & 0x1F) << 2) | if select { 0x80 } else { 0 }
}

fn qos(ql: u8, select: bool) -> u8 {
    (ql & 0x7F) | if select { 0x80 } else { 0 }
}

impl Element {
    /// An element of `kind` from its octets (exactly `kind.size()` of them).
    pub(crate) fn decode(kind: Kind, b: &[u8]) -> Result<Element, String> {
        Ok(match kind {
            Kind::Single => Element::Single {
                on: b[0] & 1 != 0,
                quality: Quality::of(b[0] & 0xF0),
            },
            Kind::Double => Element::Double {
                state: b[0] & 3,
                quality: Quality::of(b[0] & 0xF0),
            },
            Kind::Step => {
                // VTI: a 7-bit two's complement value, bit 7 the transient state.
                let value = (((b[0] & 0x7F) << 1) as i8) >> 1;
                Element::Step {
                    value,
                    transient: b[0] & 0x80 != 0,
                    quality: Quality::of(b[1]),
                }
            }
            Kind::Bits => Element::Bits {
                bits: u32::from_le_bytes(long(b)),
                quality: Quality::of(b[4]),
            },
            Kind::Normalized => Element::Normalized {
                value: word(b),
                quality: Quality::of(b[2]),
            },
            Kind::NormalizedBare => Element::Normalized {
                value: word(b),
                quality: Quality(0),
            },
            Kind::Scaled => Element::Scaled {
                value: word(b),
                quality: Quality::of(b[2]),
            },
            Kind::Float => Element::Float {
                value: f32::from_le_bytes(long(b)),
                quality: Quality::of(b[4]),
            },
            Kind::Counter => Element::Counter {
                value: i32::from_le_bytes(long(b)),
                sequence: b[4] & 0x1F,
                carry: b[4] & 0x20 != 0,
                adjusted: b[4] & 0x40 != 0,
                invalid: b[4] & 0x80 != 0,
            },
            _ => Element::control(kind, b)?,
        })
    }

    /// A command's or a system element's from its octets.
    fn control(kind: Kind, b: &[u8]) -> Result<Element, String> {
        let select = |o: u8| o & 0x80 != 0;
        let qu = |o: u8| (o >> 2) & 0x1F;
        Ok(match kind {
            Kind::SingleCommand => Element::SingleCommand {
                on: b[0] & 1 != 0,
                qu: qu(b[0]),
                select: select(b[0]),
            },
            Kind::DoubleCommand => Element::DoubleCommand {
                state: b[0] & 3,
                qu: qu(b[0]),
                select: select(b[0]),
            },
            Kind::StepCommand => Element::StepCommand {
                step: b[0] & 3,
                qu: qu(b[0]),
                select: select(b[0]),
            },
            Kind::SetNormalized => Element::SetNormalized {
                value: word(b),
                select: select(b[2]),
                ql: b[2] & 0x7F,
            },
            Kind::SetScaled => Element::SetScaled {
                value: word(b),
                select: select(b[2]),
                ql: b[2] & 0x7F,
            },
            Kind::SetFloat => Element::SetFloat {
                value: f32::from_le_bytes(long(b)),
                select: select(b[4]),
                ql: b[4] & 0x7F,
            },
            Kind::BitsCommand => Element::BitsCommand(u32::from_le_bytes(long(b))),
            Kind::EndOfInit => Element::EndOfInit(b[0]),
            Kind::Interrogation => Element::Interrogation(b[0]),
            Kind::CounterInterrogation => Element::CounterInterrogation(b[0]),
            Kind::Read => Element::Read,
            Kind::ClockSync => {
                Element::ClockSync(Cp56::decode(&b.try_into().map_err(|_| "a short clock")?)?)
            }
            Kind::ResetProcess => Element::ResetProcess(b[0]),
            Kind::Test => Element::Test(u16::from_le_bytes([b[0], b[1]])),
            _ => return Err(format!("{kind:?} is a value, not a command")),
        })
    }

    /// Appends its octets as an element of `type_id`'s kind (a bare normalized value
    /// without its quality).
    pub(crate) fn encode(&self, type_id: TypeId, out: &mut Vec<u8>) {
        let bare = type_id.kind() == Some(Kind::NormalizedBare);
        match *self {
            Element::Single { on, quality } => out.push(u8::from(on) | (quality.0 & 0xF0)),
            Element::Double { state, quality } => out.push((state & 3) | (quality.0 & 0xF0)),
            Element::Step {
                value,
                transient,
                quality,
            } => {
                out.push((value as u8 & 0x7F) | if transient { 0x80 } else { 0 });
                out.push(quality.0);
            }
            Element::Bits { bits, quality } => {
                out.extend_from_slice(&bits.to_le_bytes());
                out.push(quality.0);
            }
            Element::Normalized { value, quality } | Element::Scaled { value, quality } => {
                out.extend_from_slice(&value.to_le_bytes());
                if !bare {
                    out.push(quality.0);
                }
            }
            Element::Float { value, quality } => {
                out.extend_from_slice(&value.to_le_bytes());
                out.push(quality.0);
            }
            Element::Counter {
                value,
                sequence,
                carry,
                adjusted,
                invalid,
            } => {
                out.extend_from_slice(&value.to_le_bytes());
                out.push(
                    (sequence & 0x1F)
                        | if carry { 0x20 } else { 0 }
                        | if adjusted { 0x40 } else { 0 }
                        | if invalid { 0x80 } else { 0 },
                );
            }
            Element::SingleCommand { on, qu, select } => {
                out.push(command(u8::from(on), qu, select))
            }
            Element::DoubleCommand { state, qu, select } => {
                out.push(command(state & 3, qu, select))
            }
            Element::StepCommand { step, qu, select } => out.push(command(step & 3, qu, select)),
            Element::SetNormalized { value, select, ql }
            | Element::SetScaled { value, select, ql } => {
                out.extend_from_slice(&value.to_le_bytes());
                out.push(qos(ql, select));
            }
            Element::SetFloat { value, select, ql } => {
                out.extend_from_slice(&value.to_le_bytes());
                out.push(qos(ql, select));
            }
            Element::BitsCommand(bits) => out.extend_from_slice(&bits.to_le_bytes()),
            Element::EndOfInit(o)
            | Element::Interrogation(o)
            | Element::CounterInterrogation(o)
            | Element::ResetProcess(o) => out.push(o),
            Element::Read => {}
            Element::ClockSync(t) => out.extend_from_slice(&t.encode()),
            Element::Test(tsc) => out.extend_from_slice(&tsc.to_le_bytes()),
        }
    }

    /// The element's quality descriptor, where it has one.
    pub(crate) fn quality(&self) -> Option<Quality> {
        match *self {
            Element::Single { quality, .. }
            | Element::Double { quality, .. }
            | Element::Step { quality, .. }
            | Element::Bits { quality, .. }
            | Element::Normalized { quality, .. }
            | Element::Scaled { quality, .. }
            | Element::Float { quality, .. } => Some(quality),
            Element::Counter { invalid, .. } => {
                Some(Quality(if invalid { Quality::IV } else { 0 }))
            }
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn both_ways(type_id: u8, element: Element, octets: &[u8]) {
        let t = TypeId(type_id);
        let mut out = Vec::new();
        element.encode(t, &mut out);
        assert_eq!(out, octets, "{} {element:?}", t.name());
        let kind = t.kind().expect("a known type");
        assert_eq!(kind.size(), octets.len(), "{}", t.name());
        assert_eq!(Element::decode(kind, octets), Ok(element), "{}", t.name());
    }

    #[test]
    fn every_element_is_its_octets() {
        let q = |bits| Quality(bits);
        both_ways(
            1,
            Element::Single {
                on: true,
                quality: q(Quality::IV | Quality::NT),
            },
            &[0xC1],
        );
        both_ways(
            3,
            Element::Double {
                state: 2,
                quality: q(Quality::BL),
            },
            &[0x12],
        );
        both_ways(
            5,
            Element::Step {
                value: -3,
                transient: true,
                quality: q(Quality::OV),
            },
            &[0xFD, 0x01],
        );
        both_ways(
            7,
            Element::Bits {
                bits: 0x0102_0304,
                quality: q(0),
            },
            &[4, 3, 2, 1, 0],
        );
        both_ways(
            9,
            Element::Normalized {
                value: -16384,
                quality: q(Quality::SB),
            },
            &[0x00, 0xC0, 0x20],
        );
        both_ways(
            21,
            Element::Normalized {
                value: 16384,
                quality: q(0),
            },
            &[0x00, 0x40],
        );
        both_ways(
            11,
            Element::Scaled {
                value: 1234,
                quality: q(0),
            },
            &[0xD2, 0x04, 0],
        );
        both_ways(
            13,
            Element::Float {
                value: 1.5,
                quality: q(Quality::IV),
            },
            &[0, 0, 0xC0, 0x3F, 0x80],
        );
        both_ways(
            15,
            Element::Counter {
                value: -2,
                sequence: 5,
                carry: true,
                adjusted: false,
                invalid: true,
            },
            &[0xFE, 0xFF, 0xFF, 0xFF, 0xA5],
        );
        both_ways(
            45,
            Element::SingleCommand {
                on: true,
                qu: 0,
                select: true,
            },
            &[0x81],
        );
        both_ways(
            46,
            Element::DoubleCommand {
                state: 1,
                qu: 1,
                select: false,
            },
            &[0x05],
        );
        both_ways(
            47,
            Element::StepCommand {
                step: 2,
                qu: 0,
                select: false,
            },
            &[0x02],
        );
        both_ways(
            49,
            Element::SetScaled {
                value: -5,
                select: false,
                ql: 0,
            },
            &[0xFB, 0xFF, 0],
        );
        both_ways(
            50,
            Element::SetFloat {
                value: -1.0,
                select: true,
                ql: 0,
            },
            &[0, 0, 0x80, 0xBF, 0x80],
        );
        both_ways(51, Element::BitsCommand(0xA5), &[0xA5, 0, 0, 0]);
        both_ways(100, Element::Interrogation(20), &[20]);
        both_ways(101, Element::CounterInterrogation(5), &[5]);
        both_ways(102, Element::Read, &[]);
        both_ways(107, Element::Test(0x1234), &[0x34, 0x12]);
        assert_eq!(Quality(0xC1).names(), ["IV", "NT", "OV"]);
    }
}
