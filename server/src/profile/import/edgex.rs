//! EdgeX device profiles (YAML, device-modbus): `deviceResources` made into fields; device
//! commands and resources of unsupported tables or value types reported.

use super::{Draft, Imported, entries, get, identifier, num, scalar};
use crate::codec::{ByteOrder, IecType};
use crate::profile::{Direction, RegisterKind};
use crate::yaml::{Kind, Node};

/// Keys of a resource's `properties` that shape nothing on the wire.
const QUIET_PROPERTIES: &[&str] = &[
    "valueType",
    "readWrite",
    "scale",
    "offset",
    "units",
    "minimum",
    "maximum",
    "defaultValue",
    "mediaType",
];

pub(super) fn read(root: &Node) -> Result<Draft, String> {
    let name = get(root, "name")
        .and_then(scalar)
        .ok_or("no `name`: not an EdgeX device profile")?;
    let resources = match get(root, "deviceResources").map(|r| &r.kind) {
        Some(Kind::Seq(items)) => items.as_slice(),
        _ => return Err("no `deviceResources`: not an EdgeX device profile".to_owned()),
    };
    let mut draft = Draft {
        name: identifier(&name),
        vendor: get(root, "manufacturer").and_then(scalar),
        description: get(root, "description").and_then(scalar).map(|d| {
            match get(root, "model").and_then(scalar) {
                Some(model) => format!("{model}: {d}"),
                None => d,
            }
        }),
        ..Draft::default()
    };
    for (key, value) in entries(root) {
        if key.name == "deviceCommands"
            && let Kind::Seq(commands) = &value.kind
        {
            for command in commands {
                let cmd = get(command, "name").and_then(scalar).unwrap_or_default();
                draft.skip(
                    command.line,
                    format!(
                        "device command `{cmd}`: a group of resources (each resource is a field)"
                    ),
                );
            }
        }
    }
    for resource in resources {
        resource_field(&mut draft, resource);
    }
    Ok(draft)
}

fn resource_field(draft: &mut Draft, resource: &Node) {
    let line = resource.line;
    let name = get(resource, "name").and_then(scalar).unwrap_or_default();
    match imported(draft, resource, &name) {
        Ok(field) => draft.add(field, &name),
        Err(why) => draft.skip(line, format!("resource `{name}`: {why}")),
    }
}

/// The field a resource becomes, or why it becomes none; what it says that is not mapped
/// is noted in `draft` on the way.
fn imported(draft: &mut Draft, resource: &Node, name: &str) -> Result<Imported, String> {
    let line = resource.line;
    let (Some(attributes), Some(properties)) =
        (get(resource, "attributes"), get(resource, "properties"))
    else {
        return Err("no attributes or properties".into());
    };
    let (kind, table) = table_kind(attributes)?;
    let (address, bit) = starting_address(attributes)?;
    note_unmapped(draft, name, attributes, properties);
    let value_type = get(properties, "valueType")
        .and_then(scalar)
        .unwrap_or_default();
    let ty = iec_type(&value_type)
        .ok_or_else(|| format!("valueType `{value_type}` has no iogate type"))?;
    let read_write = get(properties, "readWrite")
        .and_then(scalar)
        .unwrap_or_else(|| "R".to_owned());
    let writes = read_write.contains('W');
    let direction = if writes && !kind.is_read_only() {
        Direction::Output
    } else {
        if writes {
            draft.skip(line, format!("resource `{name}`: readWrite {read_write} on a read-only table: imported as an input"));
        }
        Direction::Input
    };
    let mut field = Imported {
        name: String::new(),
        ty,
        direction,
        kind,
        address,
        bit: bit.filter(|_| ty == IecType::Bool && !kind.is_bit()),
        word_count: None,
        raw_type: None,
        switch: None,
        scale: get(properties, "scale").and_then(num).unwrap_or(1.0),
        offset: get(properties, "offset").and_then(num).unwrap_or(0.0),
        order: byte_order(attributes),
        unit: get(properties, "units").and_then(scalar),
        description: get(resource, "description").and_then(scalar),
        line,
    };
    if field.scale == 0.0 {
        return Err("scale 0".into());
    }
    if ty == IecType::Bool {
        // A bit has no byte order, scale or offset.
        field.order = ByteOrder::BigEndian;
        field.scale = 1.0;
        field.offset = 0.0;
        return Ok(field);
    }
    if kind.is_bit() {
        return Err(format!(
            "{value_type} on {table}: a coil or discrete input is one bit"
        ));
    }
    encoded(&mut field, attributes, &value_type)?;
    Ok(field)
}

/// `primaryTable`: the register kind, and the table as written (upper case).
fn table_kind(attributes: &Node) -> Result<(RegisterKind, String), String> {
    let table = get(attributes, "primaryTable")
        .and_then(scalar)
        .unwrap_or_default()
        .to_ascii_uppercase();
    let kind = match table.as_str() {
        "COILS" => RegisterKind::Coil,
        "DISCRETES_INPUT" | "DISCRETE_INPUTS" => RegisterKind::DiscreteInput,
        "HOLDING_REGISTERS" => RegisterKind::HoldingRegister,
        "INPUT_REGISTERS" => RegisterKind::InputRegister,
        other => return Err(format!("primaryTable `{other}` is not a Modbus table")),
    };
    Ok((kind, table))
}

/// `startingAddress: 10.10` is register 10, bit 10 (EdgeX reads it with two decimals).
fn starting_address(attributes: &Node) -> Result<(u16, Option<u8>), String> {
    let start = get(attributes, "startingAddress").ok_or("no startingAddress")?;
    let (address, bit) = match &start.kind {
        Kind::Float(f) => {
            let text = format!("{f:.2}");
            let (reg, bit) = text.split_once('.').unwrap_or((&text, "0"));
            (reg.parse::<f64>().ok(), bit.parse::<u8>().ok())
        }
        Kind::Str(s) if s.contains('.') => {
            let (reg, bit) = s.split_once('.').unwrap_or((s, "0"));
            (
                reg.trim().parse::<f64>().ok(),
                bit.trim().parse::<u8>().ok(),
            )
        }
        _ => (num(start), None),
    };
    let address = address
        .filter(|a| a.fract() == 0.0 && (0.0..=65535.0).contains(a))
        .ok_or("startingAddress is not 0-65535")?;
    if bit.is_some_and(|b| b > 15) {
        return Err("bit above 15".into());
    }
    Ok((address as u16, bit))
}

/// Notes every attribute and property the import does not map.
fn note_unmapped(draft: &mut Draft, name: &str, attributes: &Node, properties: &Node) {
    const MAPPED: [&str; 6] = [
        "primaryTable",
        "startingAddress",
        "rawType",
        "isByteSwap",
        "isWordSwap",
        "stringRegisterSize",
    ];
    for (key, _) in entries(attributes) {
        if !MAPPED.contains(&key.name.as_str()) {
            draft.skip(
                key.line,
                format!("resource `{name}`: attribute `{}` not mapped", key.name),
            );
        }
    }
    for (key, _) in entries(properties) {
        if !QUIET_PROPERTIES.contains(&key.name.as_str()) {
            draft.skip(
                key.line,
                format!("resource `{name}`: property `{}` not mapped", key.name),
            );
        }
    }
}

/// The iogate type of an EdgeX `valueType`.
fn iec_type(value_type: &str) -> Option<IecType> {
    Some(match value_type.to_ascii_lowercase().as_str() {
        "bool" => IecType::Bool,
        "int16" => IecType::Int,
        "uint16" => IecType::Uint,
        "int32" => IecType::Dint,
        "uint32" => IecType::Udint,
        "int64" => IecType::Lint,
        "uint64" => IecType::Ulint,
        "float32" => IecType::Real,
        "float64" => IecType::Lreal,
        "string" => IecType::String,
        _ => return None,
    })
}

/// The byte order of `isByteSwap` and `isWordSwap` (EdgeX takes each as a boolean or its
/// text).
fn byte_order(attributes: &Node) -> ByteOrder {
    let is_true = |key: &str| match get(attributes, key).map(|n| &n.kind) {
        Some(Kind::Bool(b)) => *b,
        Some(Kind::Str(s)) => s.trim().eq_ignore_ascii_case("true"),
        _ => false,
    };
    match (is_true("isByteSwap"), is_true("isWordSwap")) {
        (false, false) => ByteOrder::BigEndian,
        (true, false) => ByteOrder::SwapBytes,
        (false, true) => ByteOrder::SwapWords,
        (true, true) => ByteOrder::LittleEndian,
    }
}

/// A register field's words: a string's size, a scaled integer read raw, or its type's.
fn encoded(field: &mut Imported, attributes: &Node, value_type: &str) -> Result<(), String> {
    let raw = get(attributes, "rawType")
        .and_then(scalar)
        .map(|r| r.to_ascii_lowercase());
    let ty = field.ty;
    match (ty, raw.as_deref()) {
        (IecType::String, _) => {
            let size = get(attributes, "stringRegisterSize")
                .and_then(num)
                .filter(|s| (1.0..=123.0).contains(s))
                .ok_or("String without a stringRegisterSize of 1-123")?;
            field.word_count = Some(size as u16);
            field.scale = 1.0;
            field.offset = 0.0;
        }
        (IecType::Real | IecType::Lreal, Some(raw @ ("int16" | "uint16" | "int32" | "uint32"))) => {
            field.raw_type = Some(match raw {
                "int16" => IecType::Int,
                "uint16" => IecType::Uint,
                "int32" => IecType::Dint,
                _ => IecType::Udint,
            });
        }
        (_, Some(raw)) if raw != value_type.to_ascii_lowercase() => {
            return Err(format!("rawType `{raw}` for {value_type} not mapped"));
        }
        _ => {
            let words = crate::codec::full_words(ty);
            if field.scale != 1.0 || field.offset != 0.0 {
                if ty.is_real() {
                    field.word_count = Some(words);
                } else {
                    field.raw_type = Some(ty);
                    field.ty = super::scaled_type(ty);
                }
            } else {
                field.word_count = (words > 1).then_some(words);
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use crate::profile::import::{Format, import_text};

    #[test]
    fn swaps_bits_and_raw_types_are_mapped_and_the_rest_named_at_its_line() {
        let text = "name: \"Meter-1\"\nmanufacturer: ACME\ndeviceResources:\n  - name: Energy\n    attributes: { primaryTable: HOLDING_REGISTERS, startingAddress: 4, isByteSwap: \"true\", isWordSwap: true }\n    properties: { valueType: Uint32, readWrite: R, units: kWh }\n  - name: Alarm\n    attributes: { primaryTable: INPUT_REGISTERS, startingAddress: 2.03 }\n    properties: { valueType: Bool, readWrite: R }\n  - name: Temp\n    attributes: { primaryTable: INPUT_REGISTERS, startingAddress: 1, rawType: Int16 }\n    properties: { valueType: Float32, readWrite: R, scale: \"0.5\", mask: 3 }\n  - name: Blob\n    attributes: { primaryTable: HOLDING_REGISTERS, startingAddress: 9 }\n    properties: { valueType: Binary, readWrite: R }\n";
        let c = import_text("m.yaml", text, Format::Edgex).expect("imports");
        assert_eq!(c.profile, "Meter_1");
        assert!(c.text.contains("name: Energy, type: UDINT, direction: input, register: { address: 4, kind: holding_register, word_count: 2, byte_order: little-endian, unit: \"kWh\" }"), "{}", c.text);
        assert!(c.text.contains("name: Alarm, type: BOOL, direction: input, register: { address: 2, kind: input_register, bit: 3 }"), "{}", c.text);
        assert!(c.text.contains("name: Temp, type: REAL, direction: input, register: { address: 1, kind: input_register, raw_type: INT, scale: 0.5 }"), "{}", c.text);
        assert!(
            c.unmapped
                .iter()
                .any(|u| u.starts_with("m.yaml:12:") && u.contains("`mask`")),
            "{:#?}",
            c.unmapped
        );
        assert!(
            c.unmapped
                .iter()
                .any(|u| u.starts_with("m.yaml:13:") && u.contains("`Binary`")),
            "{:#?}",
            c.unmapped
        );
    }
}
