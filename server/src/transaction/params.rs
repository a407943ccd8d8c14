//! A raw transaction's parameters as a client gives them, checked with the configuration
//! messages of the Modbus read block (source document 004), word for word, every one that
//! applies at once; and the write block's (source document 002) types and byte orders.

use std::time::Duration;

use serde::Deserialize;

use crate::codec::ByteOrder;
use crate::link::frame::{Function, Request};

/// The value types of the read block.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ValueType {
    Signed16,
    Signed32,
    Unsigned16,
    Unsigned32,
    Float,
}

impl ValueType {
    pub fn parse(name: &str) -> Option<ValueType> {
        Some(match name {
            "SIGNED_NUMBER16" => ValueType::Signed16,
            "SIGNED_NUMBER32" => ValueType::Signed32,
            "UNSIGNED_NUMBER16" => ValueType::Unsigned16,
            "UNSIGNED_NUMBER32" => ValueType::Unsigned32,
            "FLOAT" => ValueType::Float,
            _ => return None,
        })
    }

    pub fn registers(self) -> u16 {
        match self {
            ValueType::Signed16 | ValueType::Unsigned16 => 1,
            _ => 2,
        }
    }
}

/// The write block's types.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WriteType {
    Uint8,
    Int8,
    Uint16,
    Int16,
    Int32,
    Float,
}

impl WriteType {
    pub fn parse(name: &str) -> Option<WriteType> {
        Some(match name {
            "uint8" => WriteType::Uint8,
            "int8" => WriteType::Int8,
            "uint16" => WriteType::Uint16,
            "int16" => WriteType::Int16,
            "int32" => WriteType::Int32,
            "float" | "int32/float" => WriteType::Float,
            _ => return None,
        })
    }

    /// Bytes of one value; uint8 and int8 still take a register each (documented).
    pub fn bytes(self) -> usize {
        match self {
            WriteType::Uint8 | WriteType::Int8 | WriteType::Uint16 | WriteType::Int16 => 2,
            WriteType::Int32 | WriteType::Float => 4,
        }
    }
}

/// Byte orders by the names of both blocks: `LittleEndian`, `BigEndian`, `SwapBytes`,
/// `SwapWords` (read block) and `Little-endian`, `Big-endian`, `Big-endian (2 bytes)`
/// (write block: the last swaps the bytes of each register).
pub fn parse_byte_order(name: &str) -> Option<ByteOrder> {
    Some(match name {
        "BigEndian" | "Big-endian" => ByteOrder::BigEndian,
        "LittleEndian" | "Little-endian" => ByteOrder::LittleEndian,
        "SwapBytes" | "Big-endian (2 bytes)" => ByteOrder::SwapBytes,
        "SwapWords" => ByteOrder::SwapWords,
        _ => return None,
    })
}

/// A transaction as JSON (and gRPC) give it: the keys of the interface.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TransactionSpec {
    /// 1-4 read, 5, 6, 15, 16 write.
    pub function: Option<i64>,
    /// deviceAddress / network number, 1-255.
    pub slave: Option<i64>,
    /// registerAddress / data address, 0-65535.
    pub address: Option<i64>,
    /// FC01/02: bits to read, 1-32.
    pub bit_count: Option<i64>,
    /// FC03/04: SIGNED_NUMBER16, SIGNED_NUMBER32, UNSIGNED_NUMBER16, UNSIGNED_NUMBER32, FLOAT.
    pub value_type: Option<String>,
    /// Reads: 1-4294967295 (default 1); the value is divided by it, not rounded.
    pub divisor: Option<i64>,
    /// Reads: 0-3 digits kept after the point, truncating (default 3).
    pub precision: Option<i64>,
    /// LittleEndian, BigEndian, SwapBytes, SwapWords, Little-endian, Big-endian, Big-endian (2 bytes).
    pub byte_order: Option<String>,
    /// responseTimeout, 10-60000 ms (default 1000).
    pub timeout_ms: Option<i64>,
    /// Writes: uint8, int8, uint16, int16, int32, float.
    #[serde(rename = "type")]
    pub write_type: Option<String>,
    /// Writes: the values (numbers; for coils, numbers or booleans).
    #[schema(value_type = Vec<Object>)]
    pub values: Option<Vec<serde_json::Value>>,
}

/// A checked read.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadPlan {
    pub function: Function,
    pub slave: u8,
    pub address: u16,
    /// FC01/02.
    pub bits: Option<u8>,
    /// FC03/04.
    pub value_type: Option<ValueType>,
    pub divisor: u32,
    pub precision: u8,
    pub order: ByteOrder,
}

/// A checked write: the request as it goes on the wire.
#[derive(Debug, Clone, PartialEq)]
pub struct WritePlan {
    pub slave: u8,
    pub request: Request,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Plan {
    Read(ReadPlan),
    Write(WritePlan),
}

/// A checked transaction.
#[derive(Debug, Clone, PartialEq)]
pub struct Checked {
    pub plan: Plan,
    pub timeout: Duration,
}

impl Checked {
    pub fn slave(&self) -> u8 {
        match &self.plan {
            Plan::Read(r) => r.slave,
            Plan::Write(w) => w.slave,
        }
    }

    pub fn request(&self) -> Request {
        match &self.plan {
            Plan::Read(r) => {
                let count = r
                    .bits
                    .map(u16::from)
                    .or(r.value_type.map(ValueType::registers))
                    .unwrap_or(1);
                let address = r.address;
                match r.function {
                    Function::ReadCoils => Request::ReadCoils { address, count },
                    Function::ReadDiscreteInputs => Request::ReadDiscreteInputs { address, count },
                    Function::ReadHoldingRegisters => {
                        Request::ReadHoldingRegisters { address, count }
                    }
                    _ => Request::ReadInputRegisters { address, count },
                }
            }
            Plan::Write(w) => w.request.clone(),
        }
    }
}

pub const INVALID_FUNCTION: &str = "Invalid function code configuration.";
pub const INVALID_DEVICE: &str = "Invalid device address configuration.";
pub const INVALID_REGISTER: &str = "Invalid register address configuration.";
pub const INVALID_BIT_COUNT: &str = "Invalid bit count configuration.";
pub const INVALID_VALUE_TYPE: &str = "Invalid value type configuration.";
pub const INVALID_DIVISOR: &str = "Invalid divisor configuration.";
pub const INVALID_PRECISION: &str = "Invalid precision configuration.";
pub const INVALID_ENDIANESS: &str = "Invalid endianess configuration.";
pub const INVALID_REFRESH: &str = "Invalid refresh interval configuration.";
pub const INVALID_TIMEOUT: &str = "Invalid response timeout configuration.";
pub const MISSING_RS485: &str = "Missing RS485 configuration.";
pub const INVALID_INPUT_EDGE: &str = "Invalid input edge configuration.";
pub const INVALID_WRITE_TYPE: &str = "Invalid type configuration.";
pub const INVALID_VALUES: &str = "Invalid values configuration.";

const DEFAULT_TIMEOUT_MS: i64 = 1000;

impl TransactionSpec {
    /// The checked transaction, or every configuration message that applies.
    pub fn check(&self) -> Result<Checked, Vec<String>> {
        let mut errors: Vec<String> = Vec::new();
        let function = match self.function {
            Some(1) => Some(Function::ReadCoils),
            Some(2) => Some(Function::ReadDiscreteInputs),
            Some(3) => Some(Function::ReadHoldingRegisters),
            Some(4) => Some(Function::ReadInputRegisters),
            Some(5) => Some(Function::WriteSingleCoil),
            Some(6) => Some(Function::WriteSingleRegister),
            Some(15) => Some(Function::WriteMultipleCoils),
            Some(16) => Some(Function::WriteMultipleRegisters),
            _ => {
                errors.push(INVALID_FUNCTION.to_owned());
                None
            }
        };
        let slave = match self.slave {
            Some(s @ 1..=255) => Some(s as u8),
            _ => {
                errors.push(INVALID_DEVICE.to_owned());
                None
            }
        };
        let address = match self.address {
            Some(a @ 0..=65535) => Some(a as u16),
            _ => {
                errors.push(INVALID_REGISTER.to_owned());
                None
            }
        };
        let timeout = match self.timeout_ms.unwrap_or(DEFAULT_TIMEOUT_MS) {
            t @ 10..=60_000 => Some(Duration::from_millis(t as u64)),
            _ => {
                errors.push(INVALID_TIMEOUT.to_owned());
                None
            }
        };
        let order = self.byte_order.as_deref().map(parse_byte_order);
        let plan = match function {
            Some(f @ (Function::ReadCoils | Function::ReadDiscreteInputs)) => {
                let bits = match self.bit_count {
                    Some(b @ 1..=32) => Some(b as u8),
                    _ => {
                        errors.push(INVALID_BIT_COUNT.to_owned());
                        None
                    }
                };
                let order = match (bits, order) {
                    (Some(b), None) if b > 8 => {
                        errors.push(INVALID_ENDIANESS.to_owned());
                        None
                    }
                    (_, Some(None)) => {
                        errors.push(INVALID_ENDIANESS.to_owned());
                        None
                    }
                    (_, Some(Some(o))) => Some(o),
                    (_, None) => Some(ByteOrder::LittleEndian),
                };
                self.read_rest(&mut errors)
                    .and_then(|(divisor, precision)| {
                        Some(Plan::Read(ReadPlan {
                            function: f,
                            slave: slave?,
                            address: address?,
                            bits: Some(bits?),
                            value_type: None,
                            divisor,
                            precision,
                            order: order?,
                        }))
                    })
            }
            Some(f @ (Function::ReadHoldingRegisters | Function::ReadInputRegisters)) => {
                let value_type = match self.value_type.as_deref().map(ValueType::parse) {
                    Some(Some(v)) => Some(v),
                    _ => {
                        errors.push(INVALID_VALUE_TYPE.to_owned());
                        None
                    }
                };
                let order = match order {
                    Some(Some(o)) => Some(o),
                    _ => {
                        errors.push(INVALID_ENDIANESS.to_owned());
                        None
                    }
                };
                self.read_rest(&mut errors)
                    .and_then(|(divisor, precision)| {
                        Some(Plan::Read(ReadPlan {
                            function: f,
                            slave: slave?,
                            address: address?,
                            bits: None,
                            value_type: Some(value_type?),
                            divisor,
                            precision,
                            order: order?,
                        }))
                    })
            }
            Some(f) => super::codec::write_request(self, f, address, order, &mut errors).and_then(
                |request| {
                    Some(Plan::Write(WritePlan {
                        slave: slave?,
                        request,
                    }))
                },
            ),
            None => None,
        };
        match (plan, timeout) {
            (Some(plan), Some(timeout)) if errors.is_empty() => Ok(Checked { plan, timeout }),
            _ => Err(errors),
        }
    }

    /// Divisor and precision of a read.
    fn read_rest(&self, errors: &mut Vec<String>) -> Option<(u32, u8)> {
        let divisor = match self.divisor.unwrap_or(1) {
            d @ 1..=4_294_967_295 => Some(d as u32),
            _ => {
                errors.push(INVALID_DIVISOR.to_owned());
                None
            }
        };
        let precision = match self.precision.unwrap_or(3) {
            p @ 0..=3 => Some(p as u8),
            _ => {
                errors.push(INVALID_PRECISION.to_owned());
                None
            }
        };
        Some((divisor?, precision?))
    }
}
