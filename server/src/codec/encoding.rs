use super::{ByteOrder, CodecError, IecType, Value, int_range};

/// How a value is stored on the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Raw {
    /// A coil or discrete input.
    Bit,
    /// One bit (0-15) of a register.
    RegisterBit(u8),
    /// A whole register read as a flag: non-zero is TRUE; written as 1 or 0.
    RegisterFlag,
    /// A two's complement or unsigned integer of 8, 16, 32 or 64 bits (8 bits take a
    /// whole register: the low byte of the 16-bit value in its byte order).
    Int { bits: u8, signed: bool },
    /// IEEE-754 single precision in two registers.
    F32,
    /// IEEE-754 double precision in four registers.
    F64,
    /// Characters, two per register, NUL-padded.
    Str { words: u16 },
}

impl Raw {
    /// The registers the raw value takes (coils and discrete inputs: none).
    pub(crate) fn words(self) -> usize {
        match self {
            Raw::Bit => 0,
            Raw::RegisterBit(_) | Raw::RegisterFlag => 1,
            Raw::Int { bits, .. } => usize::from(bits).div_ceil(16),
            Raw::F32 => 2,
            Raw::F64 => 4,
            Raw::Str { words } => usize::from(words),
        }
    }
}

/// The two raw values a BOOL is stored as where they are not 1 and 0 (or, for a whole
/// register, non-zero and zero): an inverted coil (`on: 0, off: 1`), or a register whose
/// device means "on" by 0xA5 and "off" by 0x5A. Writes store exactly one of the two; a
/// read of any other value is an error, never a guess.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Switch {
    pub(crate) on: u16,
    pub(crate) off: u16,
}

/// A field's value type together with its raw storage, byte order and scaling:
/// `value = raw * scale + offset`, and on write `raw = round((value - offset) / scale)`,
/// rejected when it does not fit the raw type (never wrapped).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Encoding {
    pub(crate) ty: IecType,
    pub(crate) raw: Raw,
    pub(crate) order: ByteOrder,
    pub(crate) scale: f64,
    pub(crate) offset: f64,
    /// For a BOOL: the raw values of TRUE and FALSE, where not the plain ones.
    pub(crate) switch: Option<Switch>,
}

impl Encoding {
    /// An unscaled encoding in big-endian order.
    #[cfg(test)]
    pub(crate) fn plain(ty: IecType, raw: Raw) -> Self {
        Encoding {
            ty,
            raw,
            order: ByteOrder::BigEndian,
            scale: 1.0,
            offset: 0.0,
            switch: None,
        }
    }

    pub(crate) fn words(&self) -> usize {
        self.raw.words()
    }

    fn is_scaled(&self) -> bool {
        self.scale != 1.0 || self.offset != 0.0
    }

    /// The value of a coil or discrete input (or of a register's bit) that reads `wire`.
    pub(crate) fn decode_bit(&self, wire: bool) -> Value {
        Value::Bool(match self.switch {
            Some(s) => wire == (s.on == 1),
            None => wire,
        })
    }

    /// The bit a coil (or a register's bit) is set to for the value `on`: inverted where
    /// the field's switch says so.
    pub(crate) fn wire_bit(&self, on: bool) -> bool {
        match self.switch {
            Some(s) => (if on { s.on } else { s.off }) == 1,
            None => on,
        }
    }

    /// The raw register of a BOOL stored in a whole register.
    fn flag_register(&self, on: bool) -> u16 {
        match self.switch {
            Some(s) if on => s.on,
            Some(s) => s.off,
            None => u16::from(on),
        }
    }

    /// The BOOL a whole register holds: with a switch, only its two values mean anything.
    fn decode_flag(&self, raw: u16) -> Result<Value, CodecError> {
        match self.switch {
            None => Ok(Value::Bool(raw != 0)),
            Some(s) if raw == s.on => Ok(Value::Bool(true)),
            Some(s) if raw == s.off => Ok(Value::Bool(false)),
            Some(s) => Err(CodecError::NotASwitchValue {
                raw,
                on: s.on,
                off: s.off,
            }),
        }
    }

    /// The value held in `regs` (exactly [`Encoding::words`] registers).
    pub(crate) fn decode(&self, regs: &[u16]) -> Result<Value, CodecError> {
        if regs.len() != self.words() {
            return Err(CodecError::WrongLength {
                expected: self.words(),
                found: regs.len(),
            });
        }
        match self.raw {
            Raw::Bit => Err(CodecError::WrongLength {
                expected: 0,
                found: regs.len(),
            }),
            Raw::RegisterBit(bit) => Ok(self.decode_bit(regs[0] >> bit & 1 == 1)),
            Raw::RegisterFlag => self.decode_flag(regs[0]),
            Raw::Int { bits, signed } => {
                let bytes = self.value_bytes(regs);
                let raw = int_from_be(&bytes, bits, signed);
                if self.is_scaled() || self.ty.is_real() {
                    self.value_from_f64(raw as f64 * self.scale + self.offset)
                } else {
                    Ok(Value::from_int(self.ty, raw)?)
                }
            }
            Raw::F32 => {
                let bytes = self.value_bytes(regs);
                let raw = f32::from_be_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]);
                self.value_from_f64(f64::from(raw) * self.scale + self.offset)
            }
            Raw::F64 => {
                let bytes = self.value_bytes(regs);
                let mut b = [0u8; 8];
                b.copy_from_slice(&bytes);
                self.value_from_f64(f64::from_be_bytes(b) * self.scale + self.offset)
            }
            Raw::Str { .. } => {
                let bytes = self.value_bytes(regs);
                let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
                Ok(Value::String(
                    String::from_utf8_lossy(&bytes[..end]).into_owned(),
                ))
            }
        }
    }

    /// The registers that hold `value` (for a coil: one register, 1 or 0; for a bit in a
    /// register: the register with only that bit set, see [`Encoding::apply_bit`]).
    pub(crate) fn encode(&self, value: &Value) -> Result<Vec<u16>, CodecError> {
        if !value.is_of(self.ty) {
            return Err(CodecError::WrongType {
                ty: self.ty,
                found: value_kind(value),
            });
        }
        match (self.raw, value) {
            (Raw::Bit, Value::Bool(b)) => Ok(vec![u16::from(self.wire_bit(*b))]),
            (Raw::RegisterFlag, Value::Bool(b)) => Ok(vec![self.flag_register(*b)]),
            (Raw::RegisterBit(bit), Value::Bool(b)) => {
                Ok(vec![u16::from(self.wire_bit(*b)) << bit])
            }
            (Raw::Int { bits, signed }, _) => {
                let raw = match value.as_i128() {
                    Some(n) if !self.is_scaled() => n,
                    _ => {
                        let x = self.unscale(value)?;
                        let (min, max) = int_range(bits, signed);
                        let rounded = x.round();
                        if rounded < min as f64 || rounded > max as f64 {
                            return Err(raw_range(x, min, max));
                        }
                        rounded as i128
                    }
                };
                let (min, max) = int_range(bits, signed);
                if raw < min || raw > max {
                    return Err(raw_range(raw as f64, min, max));
                }
                let width = self.words() * 2;
                let all = raw.to_be_bytes();
                Ok(self.registers(all[16 - width..].to_vec()))
            }
            (Raw::F32, _) => {
                let x = self.unscale(value)?;
                if x.abs() > f64::from(f32::MAX) {
                    return Err(raw_range(x, -f32::MAX, f32::MAX));
                }
                Ok(self.registers((x as f32).to_be_bytes().to_vec()))
            }
            (Raw::F64, _) => {
                let x = self.unscale(value)?;
                Ok(self.registers(x.to_be_bytes().to_vec()))
            }
            (Raw::Str { words }, Value::String(s)) => {
                let max = usize::from(words) * 2;
                if s.len() > max {
                    return Err(CodecError::TooLong { len: s.len(), max });
                }
                let mut bytes = s.as_bytes().to_vec();
                bytes.resize(max, 0);
                Ok(self.registers(bytes))
            }
            _ => Err(CodecError::WrongType {
                ty: self.ty,
                found: value_kind(value),
            }),
        }
    }

    /// `current` with this field's bit set to `on` and every other bit kept.
    #[cfg(test)]
    pub(crate) fn apply_bit(&self, current: u16, on: bool) -> u16 {
        match self.raw {
            Raw::RegisterBit(bit) if self.wire_bit(on) => current | 1 << bit,
            Raw::RegisterBit(bit) => current & !(1 << bit),
            _ => self.flag_register(on),
        }
    }

    fn unscale(&self, value: &Value) -> Result<f64, CodecError> {
        let x = value.as_f64().ok_or(CodecError::WrongType {
            ty: self.ty,
            found: value_kind(value),
        })?;
        let raw = (x - self.offset) / self.scale;
        if raw.is_finite() {
            Ok(raw)
        } else {
            Err(CodecError::NotFinite { ty: self.ty })
        }
    }

    fn value_from_f64(&self, x: f64) -> Result<Value, CodecError> {
        if self.ty.is_real() && !x.is_finite() {
            // The device's own NaN or infinity is what it holds (the doors say it as
            // "NaN", "Infinity", "-Infinity"); a client cannot write one.
            return Ok(match self.ty {
                IecType::Real => Value::Real(x as f32),
                _ => Value::LReal(x),
            });
        }
        if self.ty.is_real() {
            Ok(Value::from_real(self.ty, x)?)
        } else if x.is_finite() {
            Ok(Value::from_int(self.ty, x.round() as i128)?)
        } else {
            Err(CodecError::NotFinite { ty: self.ty })
        }
    }

    /// Register contents as bytes in value order (most significant first).
    fn value_bytes(&self, regs: &[u16]) -> Vec<u8> {
        let mut bytes = super::register_bytes(regs);
        self.order.reorder(&mut bytes);
        bytes
    }

    /// Bytes in value order to registers.
    fn registers(&self, mut bytes: Vec<u8>) -> Vec<u16> {
        self.order.reorder(&mut bytes);
        super::bytes_registers(&bytes)
    }
}

fn raw_range(value: impl ToString, min: impl ToString, max: impl ToString) -> CodecError {
    CodecError::RawOutOfRange {
        value: value.to_string(),
        min: min.to_string(),
        max: max.to_string(),
    }
}

fn value_kind(value: &Value) -> &'static str {
    match value {
        Value::Bool(_) => "a boolean",
        Value::Int(_) | Value::UInt(_) => "an integer",
        Value::Real(_) | Value::LReal(_) => "a real number",
        Value::String(_) => "a string",
        Value::Time(_) => "a duration",
    }
}

/// The integer in the low `bits` of big-endian `bytes`, sign-extended when `signed`.
fn int_from_be(bytes: &[u8], bits: u8, signed: bool) -> i128 {
    let unsigned = bytes.iter().fold(0u128, |acc, &b| acc << 8 | u128::from(b));
    let mask = (1u128 << bits) - 1;
    let value = unsigned & mask;
    if signed && value >> (bits - 1) & 1 == 1 {
        value as i128 - (1i128 << bits)
    } else {
        value as i128
    }
}

#[cfg(test)]
#[path = "encoding_tests.rs"]
mod tests;
