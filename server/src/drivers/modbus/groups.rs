//! Writes as Modbus transactions: adjacent coils in one FC15, adjacent registers in one
//! FC16, single ones with FC05/FC06, BOOLs packed into a holding register by read-modify-write.

use std::collections::BTreeMap;

use crate::cache::WriteError;
use crate::codec::{CodecError, Raw, Value};
use crate::drivers::WriteItem;
use crate::link::frame::{MAX_WRITE_BITS, MAX_WRITE_REGISTERS, Request};
use crate::profile::{Profile, RegisterKind};

/// One write transaction and the items it carries.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum WriteOp {
    /// FC05/FC06/FC15/FC16.
    Direct { request: Request, items: Vec<usize> },
    /// BOOL fields packed into one holding register: read it (FC03), set the bits, write it
    /// back (FC06), so the other bits keep their values.
    Bits {
        address: u16,
        bits: Vec<(u8, bool)>,
        items: Vec<usize>,
    },
}

impl WriteOp {
    /// Indexes into the item list this op carries.
    pub(crate) fn items(&self) -> &[usize] {
        match self {
            WriteOp::Direct { items, .. } | WriteOp::Bits { items, .. } => items,
        }
    }

    /// The op with its item indexes looked up in `map` (for ops planned from a subset).
    pub(crate) fn remap(mut self, map: &[usize]) -> WriteOp {
        let items = match &mut self {
            WriteOp::Direct { items, .. } | WriteOp::Bits { items, .. } => items,
        };
        for i in items.iter_mut() {
            *i = map[*i];
        }
        self
    }

    /// Whether the op uses FC15 or FC16.
    pub(crate) fn is_multiple(&self) -> bool {
        matches!(
            self,
            WriteOp::Direct {
                request: Request::WriteMultipleCoils { .. }
                    | Request::WriteMultipleRegisters { .. },
                ..
            }
        )
    }
}

/// Groups writes into as few transactions as the Modbus functions allow: adjacent coils in
/// one FC15, adjacent registers in one FC16, a single coil or register with FC05/FC06. With
/// `single`, for devices without FC15/FC16, every coil and one-register value goes alone
/// (values of several registers still need FC16). Items that cannot be encoded are returned
/// with the reason.
pub(crate) fn write_ops(
    profile: &Profile,
    items: &[WriteItem],
    single: bool,
) -> (Vec<WriteOp>, Vec<(usize, WriteError)>) {
    let group_limit = |limit: u16| if single { 1 } else { usize::from(limit) };
    let mut coils: Vec<(u16, bool, usize)> = Vec::new();
    let mut registers: Vec<(u16, Vec<u16>, usize)> = Vec::new();
    // Per register: the bits to set and the items they come from.
    type BitWrites = (Vec<(u8, bool)>, Vec<usize>);
    let mut bits: BTreeMap<u16, BitWrites> = BTreeMap::new();
    let mut refused = Vec::new();
    for (n, item) in items.iter().enumerate() {
        let field = &profile.fields[item.field];
        let address = field.register.address;
        let value = match item.value() {
            Ok(value) => value,
            Err(why) => {
                refused.push((n, WriteError::Encode(CodecError::Protocol(why))));
                continue;
            }
        };
        match (field.register.kind, field.encoding.raw, value) {
            // The bit on the wire: an inverted switch writes 0 for TRUE.
            (RegisterKind::Coil, _, Value::Bool(b)) => {
                coils.push((address, field.encoding.wire_bit(*b), n));
            }
            (RegisterKind::HoldingRegister, Raw::RegisterBit(bit), Value::Bool(b)) => {
                let entry = bits.entry(address).or_default();
                entry.0.push((bit, field.encoding.wire_bit(*b)));
                entry.1.push(n);
            }
            (RegisterKind::HoldingRegister, _, value) => match field.encoding.encode(value) {
                Ok(words) => registers.push((address, words, n)),
                Err(e) => refused.push((n, WriteError::Encode(e))),
            },
            (kind, _, _) => refused.push((n, WriteError::ReadOnly(kind))),
        }
    }
    let mut ops = coil_ops(coils, group_limit(MAX_WRITE_BITS));
    ops.extend(register_ops(registers, group_limit(MAX_WRITE_REGISTERS)));
    for (address, (bits, items)) in bits {
        ops.push(WriteOp::Bits {
            address,
            bits,
            items,
        });
    }
    (ops, refused)
}

/// Adjacent coils in one FC15 (at most `limit`), a single one with FC05.
fn coil_ops(mut coils: Vec<(u16, bool, usize)>, limit: usize) -> Vec<WriteOp> {
    let mut ops = Vec::new();
    coils.sort_by_key(|c| c.0);
    for group in runs(
        &coils,
        |prev, next| next.0 == prev.0.wrapping_add(1),
        limit,
        |_| 1,
    ) {
        let address = group[0].0;
        let items = group.iter().map(|c| c.2).collect();
        let request = if group.len() == 1 {
            Request::WriteSingleCoil {
                address,
                value: group[0].1,
            }
        } else {
            Request::WriteMultipleCoils {
                address,
                values: group.iter().map(|c| c.1).collect(),
            }
        };
        ops.push(WriteOp::Direct { request, items });
    }
    ops
}

/// Adjacent registers in one FC16 (at most `limit` values), a single one with FC06.
fn register_ops(mut registers: Vec<(u16, Vec<u16>, usize)>, limit: usize) -> Vec<WriteOp> {
    let mut ops = Vec::new();
    registers.sort_by_key(|r| r.0);
    for group in runs(
        &registers,
        |prev, next| u32::from(next.0) == u32::from(prev.0) + prev.1.len() as u32,
        limit,
        |r| r.1.len(),
    ) {
        let address = group[0].0;
        let items = group.iter().map(|r| r.2).collect();
        let values: Vec<u16> = group.iter().flat_map(|r| r.1.iter().copied()).collect();
        let request = if values.len() == 1 {
            Request::WriteSingleRegister {
                address,
                value: values[0],
            }
        } else {
            Request::WriteMultipleRegisters { address, values }
        };
        ops.push(WriteOp::Direct { request, items });
    }
    ops
}

/// Splits sorted `items` into runs where each follows its predecessor and the run's size
/// stays within `limit`.
fn runs<T>(
    items: &[T],
    follows: impl Fn(&T, &T) -> bool,
    limit: usize,
    size: impl Fn(&T) -> usize,
) -> Vec<&[T]> {
    let mut out = Vec::new();
    let mut start = 0;
    let mut total = 0;
    for i in 0..items.len() {
        let s = size(&items[i]);
        if i > start && (!follows(&items[i - 1], &items[i]) || total + s > limit) {
            out.push(&items[start..i]);
            start = i;
            total = 0;
        }
        total += s;
    }
    if start < items.len() {
        out.push(&items[start..]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::test_profile as profile;

    #[test]
    fn writes_group_into_fc05_fc06_fc15_fc16_and_bit_merges() {
        let p = profile(
            "  - { name: C0, type: BOOL, direction: output, register: { address: 0, kind: coil } }\n  - { name: C1, type: BOOL, direction: output, register: { address: 1, kind: coil } }\n  - { name: C5, type: BOOL, direction: output, register: { address: 5, kind: coil } }\n  - { name: H0, type: INT, direction: output, register: { address: 0, kind: holding_register } }\n  - { name: H1, type: REAL, direction: output, register: { address: 1, kind: holding_register, word_count: 2 } }\n  - { name: H9, type: UINT, direction: output, register: { address: 9, kind: holding_register } }\n  - { name: Run, type: BOOL, direction: output, register: { address: 20, kind: holding_register, bit: 0 } }\n  - { name: Rev, type: BOOL, direction: output, register: { address: 20, kind: holding_register, bit: 1 } }\n",
        );
        let item = |field, value| WriteItem {
            field,
            value: Some(value),
            generation: None,
        };
        let items = vec![
            item(2, Value::Bool(true)),
            item(0, Value::Bool(true)),
            item(1, Value::Bool(false)),
            item(3, Value::Int(-1)),
            item(4, Value::Real(1.5)),
            item(5, Value::UInt(7)),
            item(6, Value::Bool(true)),
            item(7, Value::Bool(true)),
        ];
        let (ops, refused) = write_ops(&p, &items, false);
        assert!(refused.is_empty());
        let functions: Vec<String> = ops
            .iter()
            .map(|op| match op {
                WriteOp::Direct { request, .. } => {
                    format!(
                        "{}@{}x{}",
                        request.function(),
                        request.address(),
                        request.count()
                    )
                }
                WriteOp::Bits { address, bits, .. } => format!("bits@{address}:{}", bits.len()),
            })
            .collect();
        assert_eq!(
            functions,
            ["FC15@0x2", "FC05@5x1", "FC16@0x3", "FC06@9x1", "bits@20:2"]
        );
        // For a device without FC15/FC16: one item per transaction; a REAL still needs FC16.
        let (single, _) = write_ops(&p, &items, true);
        let shapes: Vec<String> = single
            .iter()
            .filter_map(|op| match op {
                WriteOp::Direct { request, .. } => {
                    Some(format!("{}@{}", request.function(), request.address()))
                }
                WriteOp::Bits { .. } => None,
            })
            .collect();
        assert_eq!(
            shapes,
            ["FC05@0", "FC05@1", "FC05@5", "FC06@0", "FC16@1", "FC06@9"]
        );
    }
}
