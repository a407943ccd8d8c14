//! Fields to Modbus transactions: read batches per device, write groups, and the bus-time
//! budget of a link (`iogate plan`).

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

use crate::cache::{FieldError, WriteError};
use crate::codec::{Raw, Value};
use crate::config::{Config, DeviceConfig, LinkConfig, Transport};
use crate::link::frame::{MAX_READ_BITS, MAX_WRITE_BITS, MAX_WRITE_REGISTERS, Request, Response};
use crate::link::timing::LineTiming;
use crate::profile::{Catalog, Field, Profile, RegisterKind};

/// Fields of one register kind read in one transaction.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadBatch {
    pub kind: RegisterKind,
    pub address: u16,
    pub count: u16,
    /// Indexes of the profile's fields the batch covers.
    pub fields: Vec<usize>,
}

impl ReadBatch {
    pub fn request(&self) -> Request {
        let (address, count) = (self.address, self.count);
        match self.kind {
            RegisterKind::Coil => Request::ReadCoils { address, count },
            RegisterKind::DiscreteInput => Request::ReadDiscreteInputs { address, count },
            RegisterKind::InputRegister => Request::ReadInputRegisters { address, count },
            RegisterKind::HoldingRegister | RegisterKind::Virtual => {
                Request::ReadHoldingRegisters { address, count }
            }
        }
    }

    /// The batch as two halves, by field, when it has more than one field.
    pub fn split(&self, profile: &Profile) -> Option<(ReadBatch, ReadBatch)> {
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
    pub fn decode(
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
/// `max_batch` registers. Virtual fields are not on the bus.
pub fn read_batches(profile: &Profile, max_batch: u16, max_gap: u16) -> Vec<ReadBatch> {
    let mut by_kind: BTreeMap<RegisterKind, Vec<usize>> = BTreeMap::new();
    for (i, f) in profile.fields.iter().enumerate() {
        if f.register.kind != RegisterKind::Virtual {
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

/// A value to put on the bus: a client's write (with its generation) or the latest value
/// written again after a reconnect (without).
#[derive(Debug, Clone, PartialEq)]
pub struct WriteItem {
    pub field: usize,
    pub value: Value,
    pub generation: Option<u64>,
}

/// One write transaction and the items it carries.
#[derive(Debug, Clone, PartialEq)]
pub enum WriteOp {
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
    pub fn items(&self) -> &[usize] {
        match self {
            WriteOp::Direct { items, .. } | WriteOp::Bits { items, .. } => items,
        }
    }

    /// The op with its item indexes looked up in `map` (for ops planned from a subset).
    pub fn remap(mut self, map: &[usize]) -> WriteOp {
        let items = match &mut self {
            WriteOp::Direct { items, .. } | WriteOp::Bits { items, .. } => items,
        };
        for i in items.iter_mut() {
            *i = map[*i];
        }
        self
    }

    /// Whether the op uses FC15 or FC16.
    pub fn is_multiple(&self) -> bool {
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
pub fn write_ops(
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
        match (field.register.kind, field.encoding.raw, &item.value) {
            (RegisterKind::Coil, _, Value::Bool(b)) => coils.push((address, *b, n)),
            (RegisterKind::HoldingRegister, Raw::RegisterBit(bit), Value::Bool(b)) => {
                let entry = bits.entry(address).or_default();
                entry.0.push((bit, *b));
                entry.1.push(n);
            }
            (RegisterKind::HoldingRegister, _, value) => match field.encoding.encode(value) {
                Ok(words) => registers.push((address, words, n)),
                Err(e) => refused.push((n, WriteError::Encode(e))),
            },
            (kind, _, _) => refused.push((n, WriteError::ReadOnly(kind))),
        }
    }
    let mut ops = Vec::new();
    coils.sort_by_key(|c| c.0);
    for group in runs(
        &coils,
        |prev, next| next.0 == prev.0.wrapping_add(1),
        group_limit(MAX_WRITE_BITS),
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
    registers.sort_by_key(|r| r.0);
    for group in runs(
        &registers,
        |prev, next| u32::from(next.0) == u32::from(prev.0) + prev.1.len() as u32,
        group_limit(MAX_WRITE_REGISTERS),
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
    for (address, (bits, items)) in bits {
        ops.push(WriteOp::Bits {
            address,
            bits,
            items,
        });
    }
    (ops, refused)
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

/// Bytes of an RTU request and its good response.
pub fn rtu_sizes(request: &Request) -> (usize, usize) {
    let mut pdu = Vec::new();
    request.encode(&mut pdu);
    (pdu.len() + 3, request.response_len() + 3)
}

/// The bus time of one transaction: both frames, each after the silence and guard time.
pub fn transaction_time(request: &Request, timing: &LineTiming, guard: Duration) -> Duration {
    let (req, resp) = rtu_sizes(request);
    timing.transaction_time(req, resp) + guard * 2
}

/// The bus time one poll cycle of a device needs at `timing`.
pub fn cycle_time(batches: &[ReadBatch], timing: &LineTiming, guard: Duration) -> Duration {
    batches
        .iter()
        .map(|b| transaction_time(&b.request(), timing, guard))
        .sum()
}

/// The share of a line's time the devices' refresh rates demand (1.0 = all of it).
pub fn utilisation<'a>(
    devices: impl IntoIterator<Item = (&'a DeviceConfig, &'a [ReadBatch])>,
    timing: &LineTiming,
    guard: Duration,
) -> f64 {
    devices
        .into_iter()
        .map(|(d, batches)| {
            cycle_time(batches, timing, guard).as_secs_f64()
                / d.refresh_rate.as_secs_f64().max(1e-6)
        })
        .sum()
}

/// A link's devices whose profiles are known, each with its read batches.
type Planned<'a> = Vec<(&'a DeviceConfig, &'a Profile, Vec<ReadBatch>)>;

fn devices_of<'a>(config: &'a Config, catalog: &'a Catalog, link: &LinkConfig) -> Planned<'a> {
    config
        .devices
        .iter()
        .filter(|d| d.link.as_deref() == Some(link.name.as_str()))
        .filter_map(|d| {
            let p = catalog.get(&d.profile)?;
            Some((d, p.as_ref(), read_batches(p, d.max_batch, d.max_gap)))
        })
        .collect()
}

/// The share of a serial link's time its devices' refresh rates demand; `None` over TCP.
fn link_utilisation(link: &LinkConfig, devices: &Planned<'_>) -> Option<f64> {
    let Transport::Serial(s) = &link.transport else {
        return None;
    };
    Some(utilisation(
        devices.iter().map(|(d, _, b)| (*d, b.as_slice())),
        &LineTiming::new(s),
        link.guard_time,
    ))
}

/// Links whose devices' refresh rates need more than the line carries, as warnings.
pub fn warnings(config: &Config, catalog: &Catalog) -> Vec<String> {
    config
        .links
        .iter()
        .filter_map(|link| {
            let u = link_utilisation(link, &devices_of(config, catalog, link))?;
            (u > 1.0).then(|| {
                format!(
                    "link {}: the refresh rates need {:.0}% of what the line carries; devices will be polled less often than configured (see `iogate plan`)",
                    link.name,
                    u * 100.0
                )
            })
        })
        .collect()
}

/// The poll plan of every link, as `iogate plan` prints it.
pub fn render(config: &Config, catalog: &Catalog) -> String {
    let mut out = String::new();
    if config.links.is_empty() {
        out.push_str("No links configured: nothing is polled on a bus.\n");
    }
    for link in &config.links {
        let devices = devices_of(config, catalog, link);
        let timing = match &link.transport {
            Transport::Serial(s) => {
                let t = LineTiming::new(s);
                let _ = writeln!(
                    out,
                    "link {}: serial {} {} {}{}{} ({} bits per character, {:.3} ms per character, {:.3} ms inter-frame silence{})",
                    link.name,
                    s.port,
                    s.baud,
                    s.data_bits,
                    s.parity.letter(),
                    s.stop_bits,
                    t.bits_per_char,
                    ms(t.char_time()),
                    ms(t.silence()),
                    if link.guard_time.is_zero() {
                        String::new()
                    } else {
                        format!(" + {:.3} ms guard time", ms(link.guard_time))
                    }
                );
                Some(t)
            }
            Transport::Tcp {
                host,
                port,
                framing,
            } => {
                let _ = writeln!(
                    out,
                    "link {}: tcp {host}:{port} ({}); no wire-time budget",
                    link.name,
                    framing.name()
                );
                None
            }
        };
        for (d, profile, batches) in &devices {
            let _ = writeln!(
                out,
                "  device {} (profile {}, slave {}, every {} ms): {} transaction(s) per cycle",
                d.name,
                profile.name,
                d.slave_id.unwrap_or(0),
                d.refresh_rate.as_millis(),
                batches.len()
            );
            for b in batches {
                let request = b.request();
                let names: Vec<&str> = b
                    .fields
                    .iter()
                    .map(|&i| profile.fields[i].name.as_str())
                    .collect();
                let wire = timing
                    .map(|t| {
                        let time = transaction_time(&request, &t, link.guard_time);
                        format!(" {:>8.3} ms", ms(time))
                    })
                    .unwrap_or_default();
                let _ = writeln!(
                    out,
                    "    {} slave {:>3} address {:>5} count {:>4}{wire}  {}",
                    request.function(),
                    d.slave_id.unwrap_or(0),
                    b.address,
                    b.count,
                    names.join(", ")
                );
            }
            if let Some(t) = timing {
                let _ = writeln!(
                    out,
                    "    cycle: {:.3} ms of bus time",
                    ms(cycle_time(batches, &t, link.guard_time))
                );
            }
        }
        if let Some(u) = link_utilisation(link, &devices) {
            let _ = writeln!(out, "  bus utilisation: {:.1}% of the line", u * 100.0);
            if u > 1.0 {
                let _ = writeln!(
                    out,
                    "  WARNING: the refresh rates need {:.0}% of what the line can carry; devices will be polled less often than configured",
                    u * 100.0
                );
            }
        }
    }
    out
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::load_str;

    fn profile(fields: &str) -> Profile {
        load_str("p.yaml", &format!("name: P\nfields:\n{fields}")).expect("profile")
    }

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

    #[test]
    fn writes_group_into_fc05_fc06_fc15_fc16_and_bit_merges() {
        let p = profile(
            "  - { name: C0, type: BOOL, direction: output, register: { address: 0, kind: coil } }\n  - { name: C1, type: BOOL, direction: output, register: { address: 1, kind: coil } }\n  - { name: C5, type: BOOL, direction: output, register: { address: 5, kind: coil } }\n  - { name: H0, type: INT, direction: output, register: { address: 0, kind: holding_register } }\n  - { name: H1, type: REAL, direction: output, register: { address: 1, kind: holding_register, word_count: 2 } }\n  - { name: H9, type: UINT, direction: output, register: { address: 9, kind: holding_register } }\n  - { name: Run, type: BOOL, direction: output, register: { address: 20, kind: holding_register, bit: 0 } }\n  - { name: Rev, type: BOOL, direction: output, register: { address: 20, kind: holding_register, bit: 1 } }\n",
        );
        let item = |field, value| WriteItem {
            field,
            value,
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

    #[test]
    fn plan_warns_when_the_line_cannot_carry_the_rates() {
        let config = crate::config::parse(
            "c.yaml",
            "links:\n  - { name: slow, serial: { port: /dev/ttyS0, baud: 9600 } }\ndevices:\n  - { name: m, profile: P, link: slow, slave_id: 1, refresh_rate: 20ms }\n",
        )
        .expect("config");
        let p = profile(
            "  - { name: A, type: INT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: B, type: INT, direction: input, register: { address: 10, kind: input_register } }\n",
        );
        let catalog = Catalog::new([p]);
        let text = render(&config, &catalog);
        assert!(
            text.contains("FC04 slave   1 address     0 count    1"),
            "{text}"
        );
        assert!(text.contains("WARNING"), "{text}");
        let warnings = warnings(&config, &catalog);
        assert_eq!(warnings.len(), 1);
        assert!(
            warnings[0].starts_with("link slow: the refresh rates need"),
            "{warnings:?}"
        );
    }
}
