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
                errors.push(ParamError::Function);
                None
            }
        };
        let slave = self
            .slave
            .and_then(|s| u8::try_from(s).ok())
            .filter(|&s| s >= 1);
        let slave = reported(slave, &mut errors, ParamError::Device);
        let address = self.address.and_then(|a| u16::try_from(a).ok());
        let address = reported(address, &mut errors, ParamError::Register);
        let timeout = Some(self.timeout_ms.unwrap_or(DEFAULT_TIMEOUT_MS))
            .filter(|t| (10..=60_000).contains(t))
            .and_then(|t| u64::try_from(t).ok())
            .map(Duration::from_millis);
        let timeout = reported(timeout, &mut errors, ParamError::Timeout);
        let order = self.byte_order.as_deref().map(parse_byte_order);
        // A read sends no values: any given would be kept and shown with its answers.
        let reads = matches!(self.function, Some(1..=4));
        if reads && self.values.is_some() {
            errors.push(ParamError::Values);
        }
        // A key the function does not use is still a mistake when its value is no value
        // of that key (the functions that use it report it themselves).
        let registers_read = matches!(self.function, Some(3 | 4));
        let register_write = matches!(self.function, Some(6 | 16));
        if !registers_read
            && self
                .value_type
                .as_deref()
                .is_some_and(|v| ValueType::parse(v).is_none())
        {
            errors.push(ParamError::ValueType);
        }
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
        if !reads {
            if self
                .divisor
                .is_some_and(|d| !(1..=4_294_967_295).contains(&d))
            {
                errors.push(ParamError::Divisor);
            }
            if self.precision.is_some_and(|p| !(0..=3).contains(&p)) {
                errors.push(ParamError::Precision);
            }
        }
        if !matches!(self.function, Some(1 | 2))
            && self.bit_count.is_some_and(|b| !(1..=32).contains(&b))
        {
            errors.push(ParamError::BitCount);
        }
        let plan = match function {
            Some(f @ (Function::ReadCoils | Function::ReadDiscreteInputs)) => {
                let bits = match self.bit_count {
                    Some(b @ 1..=32) => Some(b as u8),
                    _ => {
                        errors.push(ParamError::BitCount);
                        None
                    }
                };
                let order = match (bits, order) {
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
                let value_type = self.value_type.as_deref().and_then(ValueType::parse);
                let value_type = reported(value_type, &mut errors, ParamError::ValueType);
                let order = reported(order.flatten(), &mut errors, ParamError::Endianess);
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
            Some(f) => write_request(self, f, address, order, &mut errors).and_then(|request| {
                Some(Plan::Write(WritePlan {
                    slave: slave?,
                    request,
                }))
            }),
            None => None,
        };
        match (plan, timeout) {
            (Some(plan), Some(timeout)) if errors.is_empty() => Ok(Checked { plan, timeout }),
            _ => Err(errors),
        }
    }

    /// Divisor and precision of a read.
    fn read_rest(&self, errors: &mut Vec<ParamError>) -> Option<(u32, u8)> {
        let divisor = match self.divisor.unwrap_or(1) {
            d @ 1..=4_294_967_295 => Some(d as u32),
            _ => {
                errors.push(ParamError::Divisor);
                None
            }
        };
        let precision = match self.precision.unwrap_or(3) {
            p @ 0..=3 => Some(p as u8),
            _ => {
                errors.push(ParamError::Precision);
                None
            }
        };
        Some((divisor?, precision?))
    }
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
        let bits: Option<Vec<bool>> = values.map(|vs| {
            vs.iter()
                .map(|v| match v {
                    serde_json::Value::Bool(b) => Some(*b),
                    serde_json::Value::Number(n) => n.as_f64().map(|x| x != 0.0),
                    _ => None,
                })
                .collect::<Option<Vec<bool>>>()
        })?;
        let Some(bits) = bits.filter(|b| f == Function::WriteMultipleCoils || b.len() == 1) else {
            errors.push(ParamError::Values);
            return None;
        };
        if bits.len() > 1968 {
            errors.push(ParamError::Values);
            return None;
        }
        let address = address?;
        return Some(if f == Function::WriteSingleCoil {
            Request::WriteSingleCoil {
                address,
                value: bits[0],
            }
        } else {
            Request::WriteMultipleCoils {
                address,
                values: bits,
            }
        });
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
/// `found`, or `error` added to the errors when there is nothing.
fn reported<T>(found: Option<T>, errors: &mut Vec<ParamError>, error: ParamError) -> Option<T> {
    if found.is_none() {
        errors.push(error);
    }
    found
}
