//! A field of a protocol whose devices store raw values (`scale`, `offset`, `raw_type`:
//! S7, IEC 104) both ways: its value from the raw one the device stores, and the raw one
//! a value is stored as. Modbus registers do the same in their `Encoding`.

use super::{Field, RegisterKind};
use crate::codec::{IecType, Value};

impl Field {
    /// `value` as the device holds it once written, as a read will show it: through its
    /// registers (Modbus) or the raw value it stores (S7, IEC 104) and back (5.55 at a
    /// scale of 0.1 is 5.6); the value itself where nothing changes it.
    pub(crate) fn held(&self, value: &Value) -> Value {
        let back = match self.register.kind {
            RegisterKind::HoldingRegister | RegisterKind::InputRegister => self
                .encoding
                .encode(value)
                .ok()
                .and_then(|regs| self.encoding.decode(&regs).ok()),
            RegisterKind::Point => self
                .to_raw(value)
                .ok()
                .and_then(|raw| self.value_of_raw(raw).ok()),
            _ => None,
        };
        back.unwrap_or_else(|| value.clone())
    }

    /// The type the device stores the value as (`raw_type`, else the field's own).
    pub(crate) fn stored_type(&self) -> IecType {
        self.register.raw_type.unwrap_or(self.ty)
    }

    /// Whether the device stores the value as it is (no scale, offset or other raw type).
    pub(crate) fn is_plain(&self) -> bool {
        let r = &self.register;
        r.raw_type.is_none_or(|t| t == self.ty) && r.scale == 1.0 && r.offset == 0.0
    }

    /// The field's value from the value the device stores: `raw * scale + offset`.
    pub(crate) fn value_of_raw(&self, raw: Value) -> Result<Value, String> {
        if self.is_plain() {
            return Ok(raw);
        }
        let r = &self.register;
        let x = raw
            .as_f64()
            .ok_or_else(|| format!("{raw} is not a number"))?
            * r.scale
            + r.offset;
        let value = if self.ty.is_real() {
            Value::from_real(self.ty, x)
        } else if x.is_finite() {
            Value::from_int(self.ty, x.round() as i128)
        } else {
            return Err(format!("{x} is not a {}", self.ty));
        };
        value.map_err(|e| e.to_string())
    }

    /// The value the device stores for the field's `value`: `(value - offset) / scale`,
    /// rounded for an integer, refused when it does not fit the type stored.
    pub(crate) fn to_raw(&self, value: &Value) -> Result<Value, String> {
        if self.is_plain() {
            return Ok(value.clone());
        }
        let r = &self.register;
        let stored = self.stored_type();
        let v = value
            .as_f64()
            .ok_or_else(|| format!("{value} is not a number"))?;
        let x = (v - r.offset) / r.scale;
        if !x.is_finite() {
            return Err(format!("{v} scaled is not a number"));
        }
        let raw = if stored.is_real() {
            Value::from_real(stored, x)
        } else {
            Value::from_int(stored, x.round() as i128)
        };
        raw.map_err(|e| format!("{v} is {x} raw: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use crate::codec::Value;

    fn field(yaml: &str) -> super::Field {
        let p = crate::profile::load_str("p.yaml", &format!("name: P\nfields:\n{yaml}"))
            .expect("profile");
        p.fields[0].clone()
    }

    #[test]
    fn a_value_is_held_as_its_registers_store_it() {
        let scaled = field(
            "  - { name: SP, type: REAL, direction: output, register: { address: 0, kind: holding_register, scale: 0.1, raw_type: INT } }\n",
        );
        assert_eq!(scaled.held(&Value::Real(5.55)), Value::Real(5.6));
        assert_eq!(scaled.held(&Value::Real(-1.04)), Value::Real(-1.0));
        let plain = field(
            "  - { name: N, type: INT, direction: output, register: { address: 0, kind: holding_register } }\n",
        );
        assert_eq!(plain.held(&Value::Int(-7)), Value::Int(-7));
        let text = field(
            "  - { name: T, type: STRING, direction: output, register: { address: 0, kind: holding_register, word_count: 2 } }\n",
        );
        assert_eq!(
            text.held(&Value::String("abcd".into())),
            Value::String("abcd".into())
        );
        let coil = field(
            "  - { name: Q, type: BOOL, direction: output, register: { address: 0, kind: coil } }\n",
        );
        assert_eq!(coil.held(&Value::Bool(true)), Value::Bool(true));
    }
}
