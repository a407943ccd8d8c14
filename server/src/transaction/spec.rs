//! The shapes of a checked raw transaction (the read plan, the write request), the value
//! types and byte orders of the read and write blocks, and the read block's configuration
//! messages (source documents 004 and 002).

use std::time::Duration;

use crate::codec::ByteOrder;
use crate::link::frame::{Function, Request};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ValueType {
    Signed16,
    Signed32,
    Unsigned16,
    Unsigned32,
    Float,
}

impl ValueType {
    pub(crate) fn parse(name: &str) -> Option<ValueType> {
        Some(match name {
            "SIGNED_NUMBER16" => ValueType::Signed16,
            "SIGNED_NUMBER32" => ValueType::Signed32,
            "UNSIGNED_NUMBER16" => ValueType::Unsigned16,
            "UNSIGNED_NUMBER32" => ValueType::Unsigned32,
            "FLOAT" => ValueType::Float,
            _ => return None,
        })
    }

    pub(crate) fn registers(self) -> u16 {
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
    /// Always a signed 32-bit integer.
    Int32,
    /// Always IEEE-754 single precision.
    Float,
    /// Source document 002's `int32/float`: a float (a number written with a point or an
    /// exponent) as IEEE-754, an integer as a signed 32-bit integer.
    Int32OrFloat,
}

impl WriteType {
    pub(crate) fn parse(name: &str) -> Option<WriteType> {
        Some(match name {
            "uint8" => WriteType::Uint8,
            "int8" => WriteType::Int8,
            "uint16" => WriteType::Uint16,
            "int16" => WriteType::Int16,
            "int32" => WriteType::Int32,
            "float" => WriteType::Float,
            "int32/float" => WriteType::Int32OrFloat,
            _ => return None,
        })
    }

    /// The name the write block gives it, and the values it takes.
    pub(crate) fn describe(self) -> &'static str {
        match self {
            WriteType::Uint8 => "uint8 takes whole numbers 0 to 255",
            WriteType::Int8 => "int8 takes whole numbers -128 to 127",
            WriteType::Uint16 => "uint16 takes whole numbers 0 to 65535",
            WriteType::Int16 => "int16 takes whole numbers -32768 to 32767",
            WriteType::Int32 => "int32 takes whole numbers -2147483648 to 2147483647",
            WriteType::Float => "float takes finite numbers within ±3.4028235e38",
            WriteType::Int32OrFloat => {
                "int32/float takes integers -2147483648 to 2147483647 (written as int32) and numbers with a point or an exponent within ±3.4028235e38 (written as IEEE-754)"
            }
        }
    }

    /// Bytes of one value; uint8 and int8 still take a register each (documented).
    pub(crate) fn bytes(self) -> usize {
        match self {
            WriteType::Uint8 | WriteType::Int8 | WriteType::Uint16 | WriteType::Int16 => 2,
            WriteType::Int32 | WriteType::Float | WriteType::Int32OrFloat => 4,
        }
    }
}

/// Byte orders by the names of both blocks: `LittleEndian`, `BigEndian`, `SwapBytes`,
/// `SwapWords` (read block) and `Little-endian`, `Big-endian`, `Big-endian (2 bytes)`
/// (write block: the last swaps the bytes of each register).
pub(crate) fn parse_byte_order(name: &str) -> Option<ByteOrder> {
    Some(match name {
        "BigEndian" | "Big-endian" => ByteOrder::BigEndian,
        "LittleEndian" | "Little-endian" => ByteOrder::LittleEndian,
        "SwapBytes" | "Big-endian (2 bytes)" => ByteOrder::SwapBytes,
        "SwapWords" => ByteOrder::SwapWords,
        _ => return None,
    })
}

/// A transaction as JSON (and gRPC) give it: the keys of the interface.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ReadPlan {
    pub(crate) function: Function,
    pub(crate) slave: u8,
    pub(crate) address: u16,
    /// FC01/02.
    pub(crate) bits: Option<u8>,
    /// FC03/04.
    pub(crate) value_type: Option<ValueType>,
    pub(crate) divisor: u32,
    pub(crate) precision: u8,
    pub(crate) order: ByteOrder,
}

/// A checked write: the request as it goes on the wire.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WritePlan {
    pub(crate) slave: u8,
    pub(crate) request: Request,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Plan {
    Read(ReadPlan),
    Write(WritePlan),
}

/// A checked transaction.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Checked {
    pub(crate) plan: Plan,
    pub(crate) timeout: Duration,
}

impl Checked {
    pub(crate) fn slave(&self) -> u8 {
        match &self.plan {
            Plan::Read(r) => r.slave,
            Plan::Write(w) => w.slave,
        }
    }

    pub(crate) fn request(&self) -> Request {
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

/// A raw transaction's parameter that the blocks refuse, as a kind; its message is source
/// document 004's (the write block's type and values in the same form), rendered from the
/// kind.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    /// `functionCode` / Function.
    #[error("Invalid function code configuration.")]
    Function,
    /// `deviceAddress` / Network Number.
    #[error("Invalid device address configuration.")]
    Device,
    /// `registerAddress` / Data Address.
    #[error("Invalid register address configuration.")]
    Register,
    /// `bitCount`.
    #[error("Invalid bit count configuration.")]
    BitCount,
    /// `valueType`.
    #[error("Invalid value type configuration.")]
    ValueType,
    /// `divisor`.
    #[error("Invalid divisor configuration.")]
    Divisor,
    /// `precision`.
    #[error("Invalid precision configuration.")]
    Precision,
    /// `endianess` / Byte Order.
    #[error("Invalid endianess configuration.")]
    Endianess,
    /// `refreshInterval` / Polling Period.
    #[error("Invalid refresh interval configuration.")]
    Refresh,
    /// `responseTimeout` / Timeout.
    #[error("Invalid response timeout configuration.")]
    Timeout,
    /// No link of that name (the block's `server`).
    #[error("Missing RS485 configuration.")]
    MissingRs485,
    /// `input_edge`.
    #[error("Invalid input edge configuration.")]
    InputEdge,
    /// The write block's Type.
    #[error("Invalid type configuration.")]
    WriteType,
    /// The write block's values: none, or too many for the function.
    #[error("Invalid values configuration.")]
    Values,
    /// One value the type does not take.
    #[error("Invalid values configuration. `{value}`: {}", .ty.describe())]
    Value {
        /// The value as given.
        value: String,
        /// The type it was meant for.
        ty: WriteType,
    },
}

/// Every message of `errors`, in order, as one text.
pub(crate) fn messages(errors: &[ParamError]) -> String {
    errors
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(" ")
}
