//! wb-mqtt-serial device templates (JSON): `device.channels` made into fields; setup
//! registers, parameters, sub-devices and channels of unsupported kinds or formats reported.

use super::{Draft, Imported, entries, get, identifier, num, scalar};
use crate::codec::{ByteOrder, IecType, Switch};
use crate::profile::{Direction, RegisterKind};
use crate::yaml::{Kind, Node};

/// Channel keys that only shape wb-mqtt-serial's web interface or polling: nothing to map.
const DISPLAY_KEYS: &[&str] = &[
    "name",
    "reg_type",
    "address",
    "format",
    "word_order",
    "byte_order",
    "scale",
    "offset",
    "units",
    "readonly",
    "type",
    "string_data_size",
    "enabled",
    "group",
    "title",
    "description",
    "order",
    "min",
    "max",
    "enum",
    "enum_titles",
    "hidden",
    "read_period_ms",
    "read_rate_limit_ms",
    "sporadic",
    "id",
    "on_value",
    "off_value",
];

pub(super) fn read(root: &Node) -> Result<Draft, String> {
    let device = get(root, "device").ok_or("no `device` object: not a wb-mqtt-serial template")?;
    let protocol = get(device, "protocol").and_then(scalar);
    if let Some(p) = protocol.as_deref()
        && p != "modbus"
        && p != "modbus-io"
    {
        return Err(format!(
            "protocol `{p}` is not Modbus (iogate speaks Modbus RTU and TCP)"
        ));
    }
    let type_name = get(root, "device_type")
        .and_then(scalar)
        .or_else(|| get(device, "name").and_then(scalar))
        .ok_or("no `device_type`")?;
    let mut draft = Draft {
        name: identifier(&type_name),
        description: get(root, "title")
            .and_then(scalar)
            .map(|title| translated(device, &title))
            .or_else(|| Some(type_name.clone())),
        deprecated: matches!(
            get(root, "deprecated").map(|n| &n.kind),
            Some(Kind::Bool(true))
        ),
        ..Draft::default()
    };
    for (key, value) in entries(device) {
        let why = match key.name.as_str() {
            "setup" => {
                Some("setup registers written on connect: iogate writes only what clients ask")
            }
            "parameters" => {
                Some("configuration parameters (registers set once, with conditions): not a field")
            }
            "subdevices" => Some("sub-devices chosen by parameters: not imported"),
            _ => None,
        };
        if let Some(why) = why {
            let count = match &value.kind {
                Kind::Seq(items) => items.len(),
                Kind::Map(items) => items.len(),
                _ => 1,
            };
            draft.skip(key.line, format!("`{}` ({count}): {why}", key.name));
        }
    }
    let channels = match get(device, "channels").map(|c| &c.kind) {
        Some(Kind::Seq(items)) => items.as_slice(),
        _ => &[],
    };
    for channel in channels {
        channel_field(&mut draft, channel);
    }
    Ok(draft)
}

/// One channel: a field, or why not.
fn channel_field(draft: &mut Draft, channel: &Node) {
    let line = channel.line;
    let name = get(channel, "name").and_then(scalar).unwrap_or_default();
    if get(channel, "consists_of").is_some() {
        draft.skip(
            line,
            format!("channel `{name}`: made of other registers (consists_of)"),
        );
        return;
    }
    note_unmapped(draft, &name, channel);
    match imported(channel) {
        Ok(field) => draft.add(field, &name),
        Err(why) => draft.skip(line, format!("channel `{name}`: {why}")),
    }
}

/// Notes every key of a channel the import does not map, with what it loses.
fn note_unmapped(draft: &mut Draft, name: &str, channel: &Node) {
    for (key, _) in entries(channel) {
        if !DISPLAY_KEYS.contains(&key.name.as_str()) {
            let what = match key.name.as_str() {
                "condition" => {
                    "shown only when parameters say (condition); imported unconditionally"
                }
                "error_value" => "an error value: iogate takes it as a value",
                "round_to" => "rounding: iogate keeps the full value",
                "write_address" => "written at another address: iogate writes where it reads",
                "unsupported_value" => {
                    "a value meaning \"unsupported\": iogate takes it as a value"
                }
                _ => "not mapped",
            };
            draft.skip(
                key.line,
                format!("channel `{name}`: `{}`: {what}", key.name),
            );
        }
    }
}

/// The field a channel becomes, or why it becomes none.
fn imported(channel: &Node) -> Result<Imported, String> {
    let kind = register_kind(channel)?;
    let (address, bit) = channel_address(channel)?;
    let readonly = matches!(
        get(channel, "readonly").map(|n| &n.kind),
        Some(Kind::Bool(true))
    );
    let direction = if kind.is_read_only() || readonly {
        Direction::Input
    } else {
        Direction::Output
    };
    let mut field = Imported {
        name: String::new(),
        ty: IecType::Bool,
        direction,
        kind,
        address,
        bit,
        word_count: None,
        raw_type: None,
        scale: get(channel, "scale").and_then(num).unwrap_or(1.0),
        offset: get(channel, "offset").and_then(num).unwrap_or(0.0),
        order: ByteOrder::BigEndian,
        unit: get(channel, "units").and_then(scalar).or_else(|| {
            get(channel, "type")
                .and_then(scalar)
                .and_then(|t| unit_of(&t))
        }),
        description: None,
        switch: None,
        line: channel.line,
    };
    let switch = switch_values(channel)?;
    if field.scale == 0.0 {
        return Err("scale 0".into());
    }
    if kind.is_bit() || bit.is_some() {
        field.scale = 1.0;
        field.offset = 0.0;
        match switch {
            Some((on, off)) if on > 1 || off > 1 => {
                return Err(format!(
                    "on_value {on} / off_value {off} on a bit (0 or 1): not a switch iogate can write faithfully"
                ));
            }
            Some((on, off)) if (on, off) != (1, 0) => field.switch = Some(Switch { on, off }),
            _ => {}
        }
        return Ok(field);
    }
    let format = get(channel, "format")
        .and_then(scalar)
        .unwrap_or_else(|| "u16".to_owned());
    if let Some((on, off)) = switch {
        // A switch in a register: a BOOL that holds exactly its two values.
        let one_register = matches!(format.as_str(), "u16" | "s16" | "u8" | "s8");
        if !one_register || field.scale != 1.0 || field.offset != 0.0 {
            return Err(format!(
                "on_value {on} / off_value {off} on a {format} register{}: an iogate switch is one unscaled register",
                if one_register {
                    " with scale or offset"
                } else {
                    ""
                }
            ));
        }
        field.switch = Some(Switch { on, off });
        return Ok(field);
    }
    typed(&mut field, channel, &format)?;
    Ok(field)
}

/// `reg_type`: the register kind.
fn register_kind(channel: &Node) -> Result<RegisterKind, String> {
    let reg_type = get(channel, "reg_type")
        .and_then(scalar)
        .unwrap_or_default();
    Ok(match reg_type.as_str() {
        "coil" => RegisterKind::Coil,
        "discrete" => RegisterKind::DiscreteInput,
        "holding" | "holding_single" | "holding_multi" => RegisterKind::HoldingRegister,
        "input" | "press_counter" => RegisterKind::InputRegister,
        other => return Err(format!("register type `{other}` is not a Modbus table")),
    })
}

/// `address`, with `reg:shift:width` reading bits of a register.
fn channel_address(channel: &Node) -> Result<(u16, Option<u8>), String> {
    let address_node = get(channel, "address").ok_or("no address")?;
    let address_text = scalar(address_node).unwrap_or_default();
    let (address, bit) = match address_text.split(':').collect::<Vec<_>>().as_slice() {
        [reg, shift, width] => {
            let reg = super::num_text(reg);
            match (reg, shift.parse::<u8>(), width.parse::<u8>()) {
                (Some(r), Ok(s), Ok(1)) if s < 16 => (Some(r), Some(s)),
                _ => {
                    return Err(format!("bits `{address_text}` wider than one: not a field"));
                }
            }
        }
        _ => (num(address_node), None),
    };
    let address = address
        .filter(|a| a.fract() == 0.0 && (0.0..=65535.0).contains(a))
        .ok_or_else(|| format!("address `{address_text}` is not 0-65535"))?;
    Ok((address as u16, bit))
}

/// A register field's type, words and byte order from its `format`.
fn typed(field: &mut Imported, channel: &Node, format: &str) -> Result<(), String> {
    let (ty, words) = match format {
        "u16" => (IecType::Uint, 1),
        "s16" => (IecType::Int, 1),
        "u8" => (IecType::Usint, 1),
        "s8" => (IecType::Sint, 1),
        "u32" => (IecType::Udint, 2),
        "s32" => (IecType::Dint, 2),
        "u64" => (IecType::Ulint, 4),
        "s64" => (IecType::Lint, 4),
        "float" => (IecType::Real, 2),
        "double" => (IecType::Lreal, 4),
        "string8" => {
            let size = get(channel, "string_data_size")
                .and_then(num)
                .filter(|s| (1.0..=125.0).contains(s))
                .ok_or("string8 without a string_data_size of 1-125")?;
            (IecType::String, size as u16)
        }
        other => {
            return Err(format!(
                "format `{other}` has no iogate type (BCD, 24-bit, one character a register)"
            ));
        }
    };
    let word_little =
        get(channel, "word_order").and_then(scalar).as_deref() == Some("little_endian");
    let byte_little =
        get(channel, "byte_order").and_then(scalar).as_deref() == Some("little_endian");
    field.order = match (word_little && words > 1, byte_little) {
        (false, false) => ByteOrder::BigEndian,
        (true, false) => ByteOrder::SwapWords,
        (false, true) => ByteOrder::SwapBytes,
        (true, true) => ByteOrder::LittleEndian,
    };
    if ty == IecType::String {
        field.ty = ty;
        field.word_count = Some(words);
        field.scale = 1.0;
        field.offset = 0.0;
    } else if (field.scale != 1.0 || field.offset != 0.0) && !ty.is_real() {
        // A scaled integer is a REAL (LREAL past 16 bits) read from that integer.
        field.ty = super::scaled_type(ty);
        field.raw_type = Some(ty);
    } else {
        field.ty = ty;
        field.word_count = (words > 1).then_some(words);
    }
    Ok(())
}

/// A text as the template shows it in English: a key of `device.translations` (its `en`
/// entry, else the first language that has it), else the text itself.
fn translated(device: &Node, text: &str) -> String {
    let Some(translations) = get(device, "translations") else {
        return text.to_owned();
    };
    let in_language = |(_, table): &(crate::yaml::Key, Node)| get(table, text).and_then(scalar);
    let entries = entries(translations);
    entries
        .iter()
        .filter(|(lang, _)| lang.name == "en")
        .chain(entries.iter())
        .find_map(in_language)
        .unwrap_or_else(|| text.to_owned())
}

/// A channel's `on_value`/`off_value` as raw register values (wb-mqtt-serial writes 0 for
/// "off" where `off_value` is not given), or why they cannot be: a value past 16 bits, or
/// one value for both states.
fn switch_values(channel: &Node) -> Result<Option<(u16, u16)>, String> {
    let value = |key: &str| -> Result<Option<u16>, String> {
        let Some(node) = get(channel, key) else {
            return Ok(None);
        };
        let text = scalar(node).unwrap_or_default();
        match num(node) {
            Some(x) if x.fract() == 0.0 && (0.0..=65535.0).contains(&x) => Ok(Some(x as u16)),
            Some(x) if x.fract() == 0.0 && (-32768.0..0.0).contains(&x) => {
                Ok(Some(x as i16 as u16))
            }
            _ => Err(format!("`{key}` {text} is not a 16-bit register value")),
        }
    };
    let (on, off) = (value("on_value")?, value("off_value")?);
    if on.is_none() && off.is_none() {
        return Ok(None);
    }
    let (on, off) = (on.unwrap_or(1), off.unwrap_or(0));
    if on == off {
        return Err(format!(
            "on_value and off_value are both {on}: a write of TRUE or FALSE would say the same"
        ));
    }
    Ok(Some((on, off)))
}

/// The unit a wb-mqtt-serial control type implies (its MQTT conventions), where it has one.
fn unit_of(control: &str) -> Option<String> {
    let unit = match control {
        "voltage" => "V",
        "current" => "A",
        "power" => "W",
        "power_consumption" => "kWh",
        "temperature" => "deg C",
        "rel_humidity" => "%RH",
        "atmospheric_pressure" => "mbar",
        "pressure" => "bar",
        "lux" => "lx",
        "concentration" => "ppm",
        "sound_level" => "dB",
        "wind_speed" => "m/s",
        "water_flow" => "m^3/h",
        "water_consumption" => "m^3",
        "resistance" => "Ohm",
        _ => return None,
    };
    Some(unit.to_owned())
}

#[cfg(test)]
mod tests {
    use crate::profile::import::{Format, import_text};

    #[test]
    fn bits_scaled_integers_strings_and_orders_are_mapped_and_the_rest_named_at_its_line() {
        let text = r#"{
    "device_type": "T-1",
    "device": {
        "name": "T-1",
        "setup": [ { "title": "mode", "address": 5, "value": 1 } ],
        "channels": [
            { "name": "Alarm", "reg_type": "input", "address": "0x10:3:1" },
            { "name": "Temp", "reg_type": "holding", "address": 2, "format": "s16", "scale": 0.1, "readonly": true },
            { "name": "Serial", "reg_type": "input", "address": 20, "format": "string8", "string_data_size": 4 },
            { "name": "Energy", "reg_type": "input", "address": 30, "format": "u32", "word_order": "little_endian", "byte_order": "little_endian" },
            { "name": "Code", "reg_type": "input", "address": 40, "format": "bcd16" },
            { "name": "Relay", "reg_type": "coil", "address": 0, "type": "switch" }
        ]
    }
}"#;
        let c = import_text("t.json", text, Format::Wb).expect("imports");
        for line in [
            "name: Alarm, type: BOOL, direction: input, register: { address: 16, kind: input_register, bit: 3 }",
            "name: Temp, type: REAL, direction: input, register: { address: 2, kind: holding_register, raw_type: INT, scale: 0.1 }",
            "name: Serial, type: STRING, direction: input, register: { address: 20, kind: input_register, word_count: 4 }",
            "name: Energy, type: UDINT, direction: input, register: { address: 30, kind: input_register, word_count: 2, byte_order: little-endian }",
            "name: Relay, type: BOOL, direction: output, register: { address: 0, kind: coil }",
        ] {
            assert!(c.text.contains(line), "{line}\n{}", c.text);
        }
        assert!(
            c.unmapped
                .iter()
                .any(|u| u.starts_with("t.json:5:") && u.contains("`setup`")),
            "{:#?}",
            c.unmapped
        );
        assert!(
            c.unmapped
                .iter()
                .any(|u| u.starts_with("t.json:11:") && u.contains("bcd16")),
            "{:#?}",
            c.unmapped
        );
    }
}
