//! The address spaces of source document 001: which Modbus table and address each IEC
//! located address has, per platform.
//!
//! The document's tables end some ranges one past their last address (`%MW0-%MW1023` at
//! 1024-2048, while `%MD0` starts at 2048; on esp32 `%MW0-%MW20` at 33-52, 20 registers for
//! 21 words). iogate takes each range's start as given and gives each kind the locations
//! that fit before the next kind starts: linux `%MW0-%MW1023` = 1024-2047, `%MD0-%MD1023` =
//! 2048-4095, `%ML0-%ML1023` = 4096-8191; esp32 `%MW0-%MW19` = 33-52, `%MD0-%MD19` = 53-92,
//! `%ML0-%ML19` = 93-172; atmega coils `%QX0.0-%QX3.7` = 0-31 (the table's "0 - 32" would
//! need a 33rd bit in four bytes).

use iogate_types::{Area, Location, Size};

use crate::config::modbus_server::AddressSpace;

/// The four Modbus tables.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Table {
    Coils,
    DiscreteInputs,
    InputRegisters,
    HoldingRegisters,
}

impl Table {
    pub(crate) fn name(self) -> &'static str {
        match self {
            Table::Coils => "coil",
            Table::DiscreteInputs => "discrete input",
            Table::InputRegisters => "input register",
            Table::HoldingRegisters => "holding register",
        }
    }
}

/// Where a location sits: a table, its first address and how many bits or registers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Slot {
    pub(crate) table: Table,
    pub(crate) address: u16,
    pub(crate) width: u16,
}

/// Why a location has no Modbus address in an address space.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub(crate) enum SlotError {
    #[error("{at} has no Modbus address in the {space} address space")]
    NoAddress { at: Location, space: &'static str },
    #[error("{at} is past the end of the {space} address space (the last is {last})")]
    PastEnd {
        at: Location,
        space: &'static str,
        last: Location,
    },
}

/// One memory kind (%MW, %MD, %ML) of a space: first holding register and how many.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Memory {
    start: u16,
    count: u32,
}

/// A platform's address map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Space {
    pub(crate) kind: AddressSpace,
    /// Bytes of `%QX` (coils) and `%IX` (discrete inputs).
    coil_bytes: u32,
    input_bytes: u32,
    /// Words of `%IW` (input registers from 0) and `%QW` (holding registers from 0).
    input_words: u32,
    output_words: u32,
    /// `%MW`, `%MD`, `%ML` in the holding registers.
    memory: Option<[Memory; 3]>,
}

impl Space {
    pub(crate) fn of(kind: AddressSpace) -> Space {
        let m = |start, count| Memory { start, count };
        match kind {
            AddressSpace::Linux => Space {
                kind,
                coil_bytes: 200,
                input_bytes: 200,
                input_words: 1024,
                output_words: 1024,
                memory: Some([m(1024, 1024), m(2048, 1024), m(4096, 1024)]),
            },
            AddressSpace::Esp32 => Space {
                kind,
                coil_bytes: 7,
                input_bytes: 7,
                input_words: 33,
                output_words: 33,
                memory: Some([m(33, 20), m(53, 20), m(93, 20)]),
            },
            AddressSpace::Atmega => Space {
                kind,
                coil_bytes: 4,
                input_bytes: 1,
                input_words: 6,
                output_words: 33,
                memory: None,
            },
        }
    }

    /// The table and address of `at`, or why it has none in this space.
    pub(crate) fn slot(&self, at: &Location) -> Result<Slot, SlotError> {
        let none = || SlotError::NoAddress {
            at: *at,
            space: self.kind.name(),
        };
        let within = |index: u32, count: u32| {
            if index < count {
                Ok(())
            } else {
                Err(SlotError::PastEnd {
                    at: *at,
                    space: self.kind.name(),
                    last: Location::new(at.area, at.size, count - 1, at.bit.map(|_| 7)),
                })
            }
        };
        let bit = |bytes: u32, table| {
            within(at.index, bytes)?;
            let address = at.bit_number().ok_or_else(none)? as u16;
            Ok(Slot {
                table,
                address,
                width: 1,
            })
        };
        let memory = |kind: usize, words: u16| {
            let m = self.memory.ok_or_else(none)?[kind];
            within(at.index, m.count)?;
            Ok(Slot {
                table: Table::HoldingRegisters,
                address: m.start + at.index as u16 * words,
                width: words,
            })
        };
        match (at.area, at.size) {
            (Area::Input, Size::Bit) => bit(self.input_bytes, Table::DiscreteInputs),
            (Area::Output, Size::Bit) => bit(self.coil_bytes, Table::Coils),
            (Area::Input, Size::Word) => {
                within(at.index, self.input_words)?;
                Ok(Slot {
                    table: Table::InputRegisters,
                    address: at.index as u16,
                    width: 1,
                })
            }
            (Area::Output, Size::Word) => {
                within(at.index, self.output_words)?;
                Ok(Slot {
                    table: Table::HoldingRegisters,
                    address: at.index as u16,
                    width: 1,
                })
            }
            (Area::Memory, Size::Word) => memory(0, 1),
            (Area::Memory, Size::Double) => memory(1, 2),
            (Area::Memory, Size::Long) => memory(2, 4),
            _ => Err(none()),
        }
    }

    /// How many bits or registers a table has in this space (addresses 0 to this minus 1).
    pub(crate) fn table_len(&self, table: Table) -> u32 {
        match table {
            Table::Coils => self.coil_bytes * 8,
            Table::DiscreteInputs => self.input_bytes * 8,
            Table::InputRegisters => self.input_words,
            Table::HoldingRegisters => match self.memory {
                Some([_, _, long]) => u32::from(long.start) + long.count * 4,
                None => self.output_words,
            },
        }
    }

    /// The location that starts at a holding register or bit address, for showing memory:
    /// `%QX`, `%QW`, `%MW`, `%MD` or `%ML` (a wider memory kind only at its first register).
    pub(crate) fn location_at(&self, table: Table, address: u16) -> Option<Location> {
        let a = u32::from(address);
        match table {
            Table::Coils => (a < self.table_len(table))
                .then(|| Location::new(Area::Output, Size::Bit, a / 8, Some((a % 8) as u8))),
            Table::HoldingRegisters => {
                if a < self.output_words {
                    return Some(Location::new(Area::Output, Size::Word, a, None));
                }
                let kinds = [(Size::Word, 1), (Size::Double, 2), (Size::Long, 4)];
                self.memory?
                    .iter()
                    .zip(kinds)
                    .find_map(|(m, (size, words))| {
                        let start = u32::from(m.start);
                        let offset = a.checked_sub(start)?;
                        (offset < m.count * words && offset % words == 0)
                            .then(|| Location::new(Area::Memory, size, offset / words, None))
                    })
            }
            _ => None,
        }
    }

    /// Every location of a kind in address order, for sequential (`auto`) binding.
    pub(crate) fn locations(&self, area: Area, size: Size) -> impl Iterator<Item = Location> + '_ {
        let count = match (area, size) {
            (Area::Input, Size::Bit) => self.input_bytes * 8,
            (Area::Output, Size::Bit) => self.coil_bytes * 8,
            (Area::Input, Size::Word) => self.input_words,
            (Area::Output, Size::Word) => self.output_words,
            (Area::Memory, Size::Word) => self.memory.map_or(0, |m| m[0].count),
            (Area::Memory, Size::Double) => self.memory.map_or(0, |m| m[1].count),
            (Area::Memory, Size::Long) => self.memory.map_or(0, |m| m[2].count),
            _ => 0,
        };
        (0..count).map(move |n| match size {
            Size::Bit => Location::new(area, size, n / 8, Some((n % 8) as u8)),
            _ => Location::new(area, size, n, None),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn slot(space: AddressSpace, at: &str) -> Result<Slot, SlotError> {
        Space::of(space).slot(&Location::parse(at).expect(at))
    }

    #[test]
    fn the_linux_map_follows_the_document() {
        let s = |at| slot(AddressSpace::Linux, at).expect(at);
        assert_eq!(s("%QX2.6").address, 22, "coil 22 is %QX2.6");
        assert_eq!(s("%QX99.7").address, 799);
        assert_eq!(s("%QX100.0").address, 800);
        assert_eq!(s("%QX199.7").address, 1599);
        assert_eq!(s("%IX100.0").table, Table::DiscreteInputs);
        assert_eq!(
            (s("%IW1023").table, s("%IW1023").address),
            (Table::InputRegisters, 1023)
        );
        assert_eq!(
            (s("%QW0").table, s("%QW0").address),
            (Table::HoldingRegisters, 0)
        );
        assert_eq!(s("%MW0").address, 1024);
        assert_eq!(s("%MW1023").address, 2047);
        assert_eq!((s("%MD0").address, s("%MD0").width), (2048, 2));
        assert_eq!(s("%MD1023").address, 4094);
        assert_eq!((s("%ML0").address, s("%ML0").width), (4096, 4));
        assert_eq!(s("%ML1023").address, 8188);
        for past in ["%QX200.0", "%IW1024", "%MW1024", "%MD1024"] {
            let e = slot(AddressSpace::Linux, past).expect_err(past);
            assert!(matches!(e, SlotError::PastEnd { .. }), "{e}");
        }
        for none in ["%IB0", "%ID0", "%QD0", "%MX0.0", "%IL0"] {
            let e = slot(AddressSpace::Linux, none).expect_err(none);
            assert_eq!(
                e.to_string(),
                format!("{none} has no Modbus address in the linux address space")
            );
        }
    }

    #[test]
    fn the_small_platforms_have_their_smaller_tables() {
        assert_eq!(
            slot(AddressSpace::Esp32, "%QX6.7").map(|s| s.address),
            Ok(55)
        );
        assert!(slot(AddressSpace::Esp32, "%QX7.0").is_err());
        assert_eq!(
            slot(AddressSpace::Esp32, "%IW32").map(|s| s.address),
            Ok(32)
        );
        assert_eq!(slot(AddressSpace::Esp32, "%MW0").map(|s| s.address), Ok(33));
        assert_eq!(slot(AddressSpace::Esp32, "%MD0").map(|s| s.address), Ok(53));
        assert_eq!(
            slot(AddressSpace::Esp32, "%ML19").map(|s| s.address),
            Ok(169)
        );
        assert!(slot(AddressSpace::Esp32, "%ML20").is_err());
        assert_eq!(
            slot(AddressSpace::Atmega, "%QX3.7").map(|s| s.address),
            Ok(31)
        );
        assert!(slot(AddressSpace::Atmega, "%IX1.0").is_err());
        assert_eq!(slot(AddressSpace::Atmega, "%IW5").map(|s| s.address), Ok(5));
        assert!(slot(AddressSpace::Atmega, "%MW0").is_err());
    }

    #[test]
    fn memory_addresses_name_their_locations() {
        let linux = Space::of(AddressSpace::Linux);
        assert_eq!(
            linux
                .location_at(Table::HoldingRegisters, 2050)
                .map(|l| l.to_string()),
            Some("%MD1".to_owned())
        );
        assert_eq!(linux.location_at(Table::HoldingRegisters, 2051), None);
        assert_eq!(
            linux.location_at(Table::Coils, 22).map(|l| l.to_string()),
            Some("%QX2.6".to_owned())
        );
    }
}
