//! A raw transaction's parameters as a client gives them, checked with the configuration
//! messages of the Modbus read block (source document 004), word for word, every one that
//! applies at once; write values packed per the write block (source document 002).

use std::time::Duration;

use super::codec::value_bytes;
pub(crate) use super::spec::*;
use crate::codec::ByteOrder;
pub(crate) use crate::config::transactions::TransactionSpec;
use crate::link::frame::{Function, Request};

const DEFAULT_TIMEOUT_MS: i64 = 1000;

impl TransactionSpec {
    /// The checked transaction, or every configuration message that applies.
    pub(crate) fn check(&self) -> Result<Checked, Vec<ParamError>> {
        let mut errors: Vec<ParamError> = Vec::new();
        let function = function_of(self.function);
        if function.is_none() {
            errors.push(ParamError::Function);
        }
        let keys = self.keys(&mut errors);
        let plan = match function {
            Some(f @ (Function::ReadCoils | Function::ReadDiscreteInputs)) => {
                bit_read(f, &keys, &mut errors)
            }
            Some(f @ (Function::ReadHoldingRegisters | Function::ReadInputRegisters)) => {
                register_read(f, &keys, &mut errors)
            }
            Some(f) => {
                write_request(self, f, keys.address, keys.order, &mut errors).and_then(|request| {
                    Some(Plan::Write(WritePlan {
                        slave: keys.slave?,
                        request,
                    }))
                })
            }
            None => None,
        };
        match (plan, keys.timeout) {
            (Some(plan), Some(timeout)) if errors.is_empty() => Ok(Checked { plan, timeout }),
            _ => Err(errors),
        }
    }

    /// The keys every function reads, each checked whenever it is given (a value no
    /// function could take is a mistake whether the function uses it or not).
    fn keys(&self, errors: &mut Vec<ParamError>) -> Keys {
        let slave = self
            .slave
            .and_then(|s| u8::try_from(s).ok())
            .filter(|&s| s >= 1);
        let slave = reported(slave, errors, ParamError::Device);
        let address = self.address.and_then(|a| u16::try_from(a).ok());
        let address = reported(address, errors, ParamError::Register);
        let timeout = Some(self.timeout_ms.unwrap_or(DEFAULT_TIMEOUT_MS))
            .filter(|t| (10..=60_000).contains(t))
            .and_then(|t| u64::try_from(t).ok())
            .map(Duration::from_millis);
        let timeout = reported(timeout, errors, ParamError::Timeout);
        let order = self.byte_order.as_deref().map(parse_byte_order);
        // A read sends no values: any given would be kept and shown with its answers.
        let reads = matches!(self.function, Some(1..=4));
        if reads && self.values.is_some() {
            errors.push(ParamError::Values);
        }
        let value_type = self.value_type.as_deref().map(ValueType::parse);
        if matches!(value_type, Some(None)) {
            errors.push(ParamError::ValueType);
        }
        let register_write = matches!(self.function, Some(6 | 16));
        if !register_write
            && self
                .write_type
                .as_deref()
                .is_some_and(|t| WriteType::parse(t).is_none())
        {
            errors.push(ParamError::WriteType);
        }
        if matches!(self.function, Some(5 | 15)) && matches!(order, Some(None)) {
            errors.push(ParamError::Endianess);
        }
        let divisor = u32::try_from(self.divisor.unwrap_or(1))
            .ok()
            .filter(|&d| d >= 1);
        let divisor = reported(divisor, errors, ParamError::Divisor);
        let precision = u8::try_from(self.precision.unwrap_or(3))
            .ok()
            .filter(|&p| p <= 3);
        let precision = reported(precision, errors, ParamError::Precision);
        let bits = self
            .bit_count
            .map(|b| u8::try_from(b).ok().filter(|b| (1..=32).contains(b)));
        if matches!(bits, Some(None)) {
            errors.push(ParamError::BitCount);
        }
        Keys {
            slave,
            address,
            timeout,
            order,
            value_type,
            divisor,
            precision,
            bits,
        }
    }
}

/// The keys of a transaction as read: `None` when absent or refused (reported), the inner
/// `None` of a key given but refused.
struct Keys {
    slave: Option<u8>,
    address: Option<u16>,
    timeout: Option<Duration>,
    order: Option<Option<ByteOrder>>,
    value_type: Option<Option<ValueType>>,
    divisor: Option<u32>,
    precision: Option<u8>,
    bits: Option<Option<u8>>,
}

/// The function of its code.
fn function_of(code: Option<i64>) -> Option<Function> {
    Some(match code? {
        1 => Function::ReadCoils,
        2 => Function::ReadDiscreteInputs,
        3 => Function::ReadHoldingRegisters,
        4 => Function::ReadInputRegisters,
        5 => Function::WriteSingleCoil,
        6 => Function::WriteSingleRegister,
        15 => Function::WriteMultipleCoils,
        16 => Function::WriteMultipleRegisters,
        _ => return None,
    })
}

/// A read of coils or discrete inputs: a bit count, and a byte order past 8 bits.
fn bit_read(f: Function, keys: &Keys, errors: &mut Vec<ParamError>) -> Option<Plan> {
    // Out of range was reported above; missing is reported here.
    let bits = keys.bits.unwrap_or_else(|| {
        errors.push(ParamError::BitCount);
        None
    });
    let order = match (bits, keys.order) {
        (Some(b), None) if b > 8 => {
            errors.push(ParamError::Endianess);
            None
        }
        (_, Some(None)) => {
            errors.push(ParamError::Endianess);
            None
        }
        (_, Some(Some(o))) => Some(o),
        (_, None) => Some(ByteOrder::LittleEndian),
    };
    Some(Plan::Read(ReadPlan {
        function: f,
        slave: keys.slave?,
        address: keys.address?,
        bits: Some(bits?),
        value_type: None,
        divisor: keys.divisor?,
        precision: keys.precision?,
        order: order?,
    }))
}

/// A read of registers: a value type and a byte order.
fn register_read(f: Function, keys: &Keys, errors: &mut Vec<ParamError>) -> Option<Plan> {
    // An unknown type was reported above; a missing one is reported here.
    let value_type = keys.value_type.unwrap_or_else(|| {
        errors.push(ParamError::ValueType);
        None
    });
    let order = reported(keys.order.flatten(), errors, ParamError::Endianess);
    Some(Plan::Read(ReadPlan {
        function: f,
        slave: keys.slave?,
        address: keys.address?,
        bits: None,
        value_type: Some(value_type?),
        divisor: keys.divisor?,
        precision: keys.precision?,
        order: order?,
    }))
}

/// The write request of `spec` for function `f`, or its configuration messages.
fn write_request(
    spec: &TransactionSpec,
    f: Function,
    address: Option<u16>,
    order: Option<Option<ByteOrder>>,
    errors: &mut Vec<ParamError>,
) -> Option<Request> {
    let values = match &spec.values {
        Some(v) if !v.is_empty() => Some(v.as_slice()),
        _ => {
            errors.push(ParamError::Values);
            None
        }
    };
    if matches!(f, Function::WriteSingleCoil | Function::WriteMultipleCoils) {
        return coil_write(f, address, values?, errors);
    }
    let ty = spec.write_type.as_deref().and_then(WriteType::parse);
    let ty = reported(ty, errors, ParamError::WriteType);
    let order = match order {
        Some(Some(o)) => Some(o),
        // One byte needs no order; anything else does.
        None if ty.is_some_and(|t| matches!(t, WriteType::Uint8 | WriteType::Int8)) => {
            Some(ByteOrder::BigEndian)
        }
        _ => {
            errors.push(ParamError::Endianess);
            None
        }
    };
    let (ty, order, values) = (ty?, order?, values?);
    let mut bytes = Vec::with_capacity(values.len() * ty.bytes());
    for v in values {
        let Some(b) = value_bytes(ty, v) else {
            errors.push(ParamError::Value {
                value: v.to_string(),
                ty,
            });
            return None;
        };
        let mut b = b;
        order.reorder(&mut b);
        bytes.extend_from_slice(&b);
    }
    let registers = crate::codec::bytes_registers(&bytes);
    let address = address?;
    match f {
        Function::WriteSingleRegister if registers.len() == 1 => {
            Some(Request::WriteSingleRegister {
                address,
                value: registers[0],
            })
        }
        Function::WriteMultipleRegisters if (1..=123).contains(&registers.len()) => {
            Some(Request::WriteMultipleRegisters {
                address,
                values: registers,
            })
        }
        _ => {
            errors.push(ParamError::Function);
            None
        }
    }
}
/// A write of one or more coils: each value a boolean or a number (not 0 is on).
fn coil_write(
    f: Function,
    address: Option<u16>,
    values: &[serde_json::Value],
    errors: &mut Vec<ParamError>,
) -> Option<Request> {
    let bits = values
        .iter()
        .map(|v| match v {
            serde_json::Value::Bool(b) => Some(*b),
            serde_json::Value::Number(n) => n.as_f64().map(|x| x != 0.0),
            _ => None,
        })
        .collect::<Option<Vec<bool>>>();
    let Some(bits) = bits.filter(|b| f == Function::WriteMultipleCoils || b.len() == 1) else {
        errors.push(ParamError::Values);
        return None;
    };
    if bits.len() > 1968 {
        errors.push(ParamError::Values);
        return None;
    }
    let address = address?;
    Some(if f == Function::WriteSingleCoil {
        Request::WriteSingleCoil {
            address,
            value: bits[0],
        }
    } else {
        Request::WriteMultipleCoils {
            address,
            values: bits,
        }
    })
}

/// `found`, or `error` added to the errors when there is nothing.
fn reported<T>(found: Option<T>, errors: &mut Vec<ParamError>, error: ParamError) -> Option<T> {
    if found.is_none() {
        errors.push(error);
    }
    found
}
