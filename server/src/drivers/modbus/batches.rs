//! A device's fields as read batches: the fields of one register kind at consecutive
//! addresses (or within `max_gap`) in one request, within the Modbus limits and
//! `max_batch`; a batch the device refuses splits in two; an answer decodes field by field.

use std::collections::BTreeMap;

use crate::cache::FieldError;
use crate::codec::Value;
use crate::link::frame::{MAX_READ_BITS, Request, Response};
use crate::profile::{Field, Profile, RegisterKind};

/// Fields of one register kind read in one transaction.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct ReadBatch {
    pub(crate) kind: RegisterKind,
    pub(crate) address: u16,
    pub(crate) count: u16,
    /// Indexes of the profile's fields the batch covers.
    pub(crate) fields: Vec<usize>,
}

/// The read request of `count` of `kind` from `address`.
pub(crate) fn read_request(kind: RegisterKind, address: u16, count: u16) -> Request {
    match kind {
        RegisterKind::Coil => Request::ReadCoils { address, count },
        RegisterKind::DiscreteInput => Request::ReadDiscreteInputs { address, count },
        RegisterKind::InputRegister => Request::ReadInputRegisters { address, count },
        RegisterKind::HoldingRegister | RegisterKind::Virtual | RegisterKind::Point => {
            Request::ReadHoldingRegisters { address, count }
        }
    }
}

impl ReadBatch {
    pub(crate) fn request(&self) -> Request {
        read_request(self.kind, self.address, self.count)
    }

    /// The batch as two halves, by field, when it has more than one field.
    pub(crate) fn split(&self, profile: &Profile) -> Option<(ReadBatch, ReadBatch)> {
        if self.fields.len() < 2 {
            return None;
        }
        let (a, b) = self.fields.split_at(self.fields.len() / 2);
        Some((
            batch_of(self.kind, a, profile),
            batch_of(self.kind, b, profile),
        ))
    }

    /// Each field's value, or why it could not be decoded, from the batch's response.
    pub(crate) fn decode(
        &self,
        profile: &Profile,
        response: &Response,
    ) -> Vec<(usize, Result<Value, FieldError>)> {
        self.fields
            .iter()
            .map(|&i| {
                let field = &profile.fields[i];
                let offset = usize::from(field.register.address - self.address);
                let value = match response {
                    Response::Bits(bits) => bits
                        .get(offset)
                        .map(|&b| field.encoding.decode_bit(b))
                        .ok_or(FieldError::Missing("bit")),
                    Response::Registers(regs) => regs
                        .get(offset..offset + field.encoding.words())
                        .ok_or(FieldError::Missing("registers"))
                        .and_then(|words| field.encoding.decode(words).map_err(FieldError::Decode)),
                    Response::Written => Err(FieldError::Missing("value")),
                };
                (i, value)
            })
            .collect()
    }
}

fn batch_of(kind: RegisterKind, fields: &[usize], profile: &Profile) -> ReadBatch {
    let start = fields
        .iter()
        .map(|&i| u32::from(profile.fields[i].register.address))
        .min()
        .unwrap_or(0);
    let end = fields
        .iter()
        .map(|&i| end_of(&profile.fields[i]))
        .max()
        .unwrap_or(start);
    ReadBatch {
        kind,
        address: start as u16,
        count: (end - start) as u16,
        fields: fields.to_vec(),
    }
}

/// One past the field's last register or bit.
fn end_of(field: &Field) -> u32 {
    u32::from(field.register.address) + field.span()
}

/// The read batches of a device: the fields of each register kind in address order, merged
/// while they are consecutive (or at most `max_gap` apart) and fit the Modbus limit and
/// `max_batch` registers. Virtual fields and points of other protocols are not on a Modbus
/// bus.
pub(crate) fn read_batches(profile: &Profile, max_batch: u16, max_gap: u16) -> Vec<ReadBatch> {
    let mut by_kind: BTreeMap<RegisterKind, Vec<usize>> = BTreeMap::new();
    for (i, f) in profile.fields.iter().enumerate() {
        if !matches!(f.register.kind, RegisterKind::Virtual | RegisterKind::Point) {
            by_kind.entry(f.register.kind).or_default().push(i);
        }
    }
    let mut batches = Vec::new();
    for (kind, mut fields) in by_kind {
        fields.sort_by_key(|&i| (profile.fields[i].register.address, i));
        let limit = u32::from(if kind.is_bit() {
            MAX_READ_BITS
        } else {
            max_batch
        });
        let mut current: Vec<usize> = Vec::new();
        let (mut start, mut end) = (0u32, 0u32);
        for i in fields {
            let f = &profile.fields[i];
            let (a, e) = (u32::from(f.register.address), end_of(f));
            let fits =
                !current.is_empty() && a <= end + u32::from(max_gap) && e.max(end) - start <= limit;
            if fits {
                end = end.max(e);
            } else {
                if !current.is_empty() {
                    batches.push(batch_of(kind, &current, profile));
                    current.clear();
                }
                start = a;
                end = e;
            }
            current.push(i);
        }
        if !current.is_empty() {
            batches.push(batch_of(kind, &current, profile));
        }
    }
    batches
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::test_profile as profile;

    #[test]
    fn consecutive_fields_of_one_kind_share_a_transaction() {
        let p = profile(
            "  - { name: A, type: INT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: B, type: REAL, direction: input, register: { address: 1, kind: input_register, word_count: 2 } }\n  - { name: C, type: INT, direction: input, register: { address: 5, kind: input_register } }\n  - { name: D, type: BOOL, direction: input, register: { address: 0, kind: discrete_input } }\n  - { name: E, type: BOOL, direction: input, register: { address: 1, kind: discrete_input } }\n",
        );
        let batches = read_batches(&p, 125, 0);
        let shape: Vec<_> = batches
            .iter()
            .map(|b| (b.kind, b.address, b.count, b.fields.clone()))
            .collect();
        assert_eq!(
            shape,
            vec![
                (RegisterKind::DiscreteInput, 0, 2, vec![3, 4]),
                (RegisterKind::InputRegister, 0, 3, vec![0, 1]),
                (RegisterKind::InputRegister, 5, 1, vec![2]),
            ]
        );
        // A gap of two registers is bridged with max_gap 2.
        let bridged = read_batches(&p, 125, 2);
        assert_eq!(bridged.len(), 2);
        assert_eq!((bridged[1].address, bridged[1].count), (0, 6));
    }

    #[test]
    fn batches_respect_max_batch_and_bits_share_registers() {
        let mut fields = String::new();
        for i in 0..10 {
            fields.push_str(&format!("  - {{ name: R{i}, type: INT, direction: input, register: {{ address: {i}, kind: holding_register }} }}\n"));
        }
        fields.push_str("  - { name: B0, type: BOOL, direction: input, register: { address: 20, kind: holding_register, bit: 0 } }\n  - { name: B1, type: BOOL, direction: input, register: { address: 20, kind: holding_register, bit: 5 } }\n");
        let p = profile(&fields);
        let batches = read_batches(&p, 4, 0);
        let counts: Vec<_> = batches.iter().map(|b| (b.address, b.count)).collect();
        assert_eq!(counts, vec![(0, 4), (4, 4), (8, 2), (20, 1)]);
        assert_eq!(batches[3].fields.len(), 2);
    }

    #[test]
    fn splitting_halves_the_fields() {
        let p = profile(
            "  - { name: A, type: INT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: B, type: INT, direction: input, register: { address: 1, kind: input_register } }\n  - { name: C, type: INT, direction: input, register: { address: 2, kind: input_register } }\n",
        );
        let batch = &read_batches(&p, 125, 0)[0];
        let (a, b) = batch.split(&p).expect("splits");
        assert_eq!((a.address, a.count, a.fields.clone()), (0, 1, vec![0]));
        assert_eq!((b.address, b.count, b.fields.clone()), (1, 2, vec![1, 2]));
        assert!(a.split(&p).is_none());
    }
}
