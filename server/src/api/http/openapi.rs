//! The OpenAPI document as served: utoipa's, generated from the handlers and types, made
//! to describe exactly what the API takes and gives where the Rust types cannot say it (a
//! field's value is any JSON scalar, names and located addresses have a grammar, numbers
//! have ranges, a transaction's keys depend on its function) and with the bearer tokens
//! that guard it when this gateway has tokens configured.

use std::sync::OnceLock;

use serde_json::{Value, json};
use utoipa::OpenApi;

use crate::service::doors::Described;

/// Names of links, devices and standing transactions (as declarations check them).
pub(crate) const NAME_PATTERN: &str = "^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$";

/// IEC 61131-3 located addresses the map takes: `%IX0.0`-`%IX1023.7`, `%QW2`, `%MD10`...
pub(crate) const LOCATED_PATTERN: &str =
    "^%[IQMiqm]([Xx]0*([0-9]{1,3}|10[01][0-9]|102[0-3])\\.[0-7]|[BWDLbwdl][0-9]{1,9})$";

/// A field's value as JSON: BOOL a boolean, integers and reals numbers, STRING a string
/// (TIME milliseconds; writes also take `"T#1s500ms"`).
fn scalar(description: &str, nullable: bool) -> Value {
    let mut types = vec!["boolean", "integer", "number", "string"];
    if nullable {
        types.push("null");
    }
    json!({"type": types, "description": description})
}

/// The document for a gateway with (`secured`) or without bearer tokens; each is made
/// once.
pub(crate) fn document(secured: bool, described: &Described) -> &'static Value {
    static DOCUMENTS: [OnceLock<Value>; 2] = [OnceLock::new(), OnceLock::new()];
    DOCUMENTS[usize::from(secured)].get_or_init(|| {
        let mut doc = serde_json::to_value(crate::api::ApiDoc::openapi()).unwrap_or(Value::Null);
        refine(&mut doc, secured);
        front_ends(&mut doc, described);
        doc
    })
}

/// What the front-ends add: a reload report's kinds (the core's, each front-end's section
/// key before `reload`), the servers that listen, and each front-end's `/readyz` detail.
fn front_ends(doc: &mut Value, described: &Described) {
    if let Some(Value::Array(kinds)) = doc.pointer_mut("/components/schemas/Kind/enum") {
        let at = kinds.len().saturating_sub(1);
        for (i, key) in described.section_keys.iter().enumerate() {
            kinds.insert(at + i, (*key).into());
        }
    }
    let schemas = "/components/schemas";
    merge(
        doc,
        schemas,
        json!({"Server": {"description": "A server of the gateway that listens on a TCP port.",
                          "enum": described.listeners, "type": "string"}}),
    );
    set(
        doc,
        &format!("{schemas}/Listener/properties/server"),
        json!({"$ref": "#/components/schemas/Server"}),
    );
    if let Some(Value::Object(health)) = doc.pointer_mut(&format!("{schemas}/Health")) {
        health.remove("additionalProperties");
    }
    for h in &described.health {
        merge(doc, schemas, json!({ h.schema_name: h.schema }));
        let reference = format!("#/components/schemas/{}", h.schema_name);
        merge(
            doc,
            &format!("{schemas}/Health/properties"),
            json!({ h.name: {"oneOf": [{"$ref": reference, "description": h.description},
                                       {"type": "null"}]} }),
        );
    }
}

fn set(doc: &mut Value, pointer: &str, value: Value) {
    if let Some(slot) = doc.pointer_mut(pointer) {
        *slot = value;
    }
}

/// Merges `extra`'s keys into the object at `pointer`.
fn merge(doc: &mut Value, pointer: &str, extra: Value) {
    if let (Some(Value::Object(target)), Value::Object(extra)) = (doc.pointer_mut(pointer), extra) {
        target.extend(extra);
    }
}

fn refine(doc: &mut Value, secured: bool) {
    values(doc);
    declarations(doc);
    transactions(doc);
    path_parameters(doc);
    // A reload's 400: an invalid configuration, or a malformed query.
    set(
        doc,
        "/paths/~1api~1v1~1config~1reload/post/responses/400/content/application~1json/schema",
        json!({"anyOf": [{"$ref": "#/components/schemas/InvalidConfig"},
                         {"$ref": "#/components/schemas/ErrorBody"}]}),
    );
    security(doc, secured);
}

/// Values: JSON scalars, never objects; a write's body `{"value": X}` or X alone.
fn values(doc: &mut Value) {
    let schemas = "/components/schemas";
    // Values: JSON scalars, never objects.
    for (pointer, description, nullable) in [
        (
            "FieldValue/properties/value",
            "The value as the JSON of its type; null until first read.",
            true,
        ),
        (
            "FieldValue/properties/desired",
            "The newest value requested for this output, when the device holds another.",
            true,
        ),
        (
            "WriteRequest/properties/value",
            "The value as the JSON of the field's type.",
            false,
        ),
        ("Simulated/properties/value", "The value set.", false),
        ("WriteInfo/properties/value", "The value written.", false),
        (
            "StandingValues/properties/values/items",
            "A number (for coils, a number or a boolean).",
            false,
        ),
    ] {
        set(
            doc,
            &format!("{schemas}/{pointer}"),
            scalar(description, nullable),
        );
    }
    set(
        doc,
        &format!("{schemas}/DeviceDetail/allOf/1/properties/fields"),
        json!({"type": "object", "description": "Field name to value object.",
               "additionalProperties": {"$ref": "#/components/schemas/FieldValue"}}),
    );
    // PATCH: field name to value, at least one.
    set(
        doc,
        "/paths/~1api~1v1~1devices~1{device}~1fields/patch/requestBody/content/application~1json/schema",
        json!({"type": "object", "minProperties": 1,
               "additionalProperties": scalar("The value as the JSON of the field's type.", false)}),
    );
    // A write's body: `{"value": X}`, or X alone.
    let write = json!({"oneOf": [{"$ref": "#/components/schemas/WriteRequest"},
                                 scalar("The value alone.", false)]});
    for path in [
        "~1api~1v1~1map~1{at}",
        "~1api~1v1~1devices~1{device}~1fields~1{field}",
        "~1api~1v1~1devices~1{device}~1fields~1{field}~1simulate",
    ] {
        set(
            doc,
            &format!("/paths/{path}/put/requestBody/content/application~1json/schema"),
            write.clone(),
        );
    }
}

/// Declarations: ranges and integers as the checks have them.
fn declarations(doc: &mut Value) {
    let schemas = "/components/schemas";
    use crate::config::rules;
    let ms = |d: std::time::Duration| u64::try_from(d.as_millis()).unwrap_or(u64::MAX);
    let timeouts = crate::declare::TIMEOUTS;
    let refresh = crate::declare::REFRESH_RATES;
    for (pointer, extra) in [
        (
            "DeviceDeclarationBody/properties/slave_id",
            json!({"type": "integer", "minimum": 0, "maximum": rules::SLAVE_IDS.end(),
                   "description": "1-247; 0 (or none): declared without one, error 2 until it has one."}),
        ),
        (
            "DeviceDeclarationBody/properties/refresh_rate_ms",
            json!({"minimum": ms(*refresh.start()), "maximum": ms(*refresh.end())}),
        ),
        (
            "DeviceDeclarationBody/properties/timeout_ms",
            json!({"minimum": ms(*timeouts.start()), "maximum": ms(*timeouts.end())}),
        ),
        (
            "TcpDeclaration/properties/host",
            json!({"minLength": 1, "maxLength": 253}),
        ),
        (
            "TcpDeclaration/properties/port",
            json!({"minimum": rules::TCP_PORTS.start(), "maximum": rules::TCP_PORTS.end()}),
        ),
        (
            "TcpDeclaration/properties/framing",
            json!({"enum": ["mbap", "rtu"]}),
        ),
        (
            "LinkDeclarationBody/properties/guard_time_ms",
            json!({"maximum": ms(rules::MAX_GUARD_TIME)}),
        ),
        (
            "LinkDeclarationBody",
            json!({"oneOf": [
                {"required": ["serial"], "properties": {"serial": {"type": "object"}, "tcp": {"type": "null"}}},
                {"required": ["tcp"], "properties": {"tcp": {"type": "object"}, "serial": {"type": "null"}}}
            ]}),
        ),
        (
            "SerialDeclaration/properties/data_bits",
            json!({"enum": rules::DATA_BITS}),
        ),
        (
            "SerialDeclaration/properties/stop_bits",
            json!({"enum": rules::STOP_BITS}),
        ),
        (
            "SerialDeclaration/properties/parity",
            json!({"enum": ["N", "E", "O"]}),
        ),
        (
            "SerialDeclaration/properties/baud",
            json!({"minimum": rules::BAUD_RATES.start(), "maximum": rules::BAUD_RATES.end()}),
        ),
    ] {
        merge(doc, &format!("{schemas}/{pointer}"), extra);
    }
}

/// Path parameters: names and located addresses have a grammar.
fn path_parameters(doc: &mut Value) {
    if let Some(Value::Object(paths)) = doc.get_mut("paths") {
        for operation in paths.values_mut().filter_map(Value::as_object_mut) {
            for op in operation.values_mut() {
                let Some(Value::Array(parameters)) = op.get_mut("parameters") else {
                    continue;
                };
                for p in parameters.iter_mut() {
                    let pattern = match p["name"].as_str() {
                        Some("device" | "link" | "name") if p["in"] == "path" => NAME_PATTERN,
                        Some("at") => LOCATED_PATTERN,
                        _ => continue,
                    };
                    merge(p, "/schema", json!({"pattern": pattern}));
                }
            }
        }
    }
}

/// A transaction's keys by function: reads of bits (FC01/02, `bit_count`), of registers
/// (FC03/04, `value_type`), writes (FC05/06/15/16, `type` and `values`); a read carries no
/// `values`.
fn transactions(doc: &mut Value) {
    let base = "/components/schemas/TransactionSpec";
    for (key, range) in [
        (
            "slave",
            json!({"type": "integer", "minimum": 1, "maximum": 255}),
        ),
        (
            "address",
            json!({"type": "integer", "minimum": 0, "maximum": 65535}),
        ),
        ("bit_count", json!({"minimum": 1, "maximum": 32})),
        (
            "divisor",
            json!({"minimum": 1, "maximum": 4_294_967_295_u64}),
        ),
        ("precision", json!({"minimum": 0, "maximum": 3})),
        ("timeout_ms", json!({"minimum": 10, "maximum": 60000})),
        (
            "value_type",
            json!({"enum": ["SIGNED_NUMBER16", "SIGNED_NUMBER32", "UNSIGNED_NUMBER16", "UNSIGNED_NUMBER32", "FLOAT", null]}),
        ),
        (
            "byte_order",
            json!({"enum": ["LittleEndian", "BigEndian", "SwapBytes", "SwapWords", "Little-endian", "Big-endian", "Big-endian (2 bytes)", null]}),
        ),
        (
            "type",
            json!({"enum": ["uint8", "int8", "uint16", "int16", "int32", "float", "int32/float", null]}),
        ),
    ] {
        merge(doc, &format!("{base}/properties/{key}"), range);
    }
    set(
        doc,
        &format!("{base}/properties/values"),
        json!({"type": ["array", "null"], "minItems": 1, "maxItems": 1968,
               "items": {"type": ["number", "boolean"]},
               "description": "Writes: the values (numbers; for coils, numbers or booleans); null or absent for reads."}),
    );
    set(
        doc,
        &format!("{base}/properties/function"),
        json!({"type": "integer", "enum": [1, 2, 3, 4, 5, 6, 15, 16],
               "description": "1-4 read, 5, 6, 15, 16 write."}),
    );
    if let Some(Value::Object(spec)) = doc.pointer_mut(base) {
        spec.insert("required".into(), json!(["function", "slave", "address"]));
        spec.insert("anyOf".into(), Value::Array(by_function()));
    }
    // A standing transaction: the one-shot's keys and its own, in one object (an `allOf`
    // of a closed and an open object takes no body at all).
    let standing = "/components/schemas/StandingDeclaration";
    let spec = doc.pointer(base).cloned().unwrap_or(Value::Null);
    let own = doc.pointer(&format!("{standing}/allOf/1")).cloned();
    if let (Value::Object(mut spec), Some(Value::Object(own))) = (spec, own) {
        if let (Some(Value::Object(props)), Some(Value::Object(extra))) =
            (spec.get_mut("properties"), own.get("properties"))
        {
            props.extend(extra.clone());
            if let Some(link) = props.get_mut("link") {
                merge(link, "", json!({"pattern": NAME_PATTERN}));
            }
            for period in ["refresh_interval_ms", "polling_period_ms"] {
                if let Some(p) = props.get_mut(period) {
                    merge(p, "", json!({"maximum": 3_600_000}));
                }
            }
        }
        spec.insert(
            "required".into(),
            json!(["function", "slave", "address", "link"]),
        );
        spec.insert(
            "description".into(),
            json!("The body of `PUT /api/v1/transactions/{name}`: the one-shot's keys plus `link` and a period."),
        );
        set(doc, standing, Value::Object(spec));
    }
}

/// What each function needs, as `TransactionSpec::check` checks it: a read takes no values;
/// bits over 8 and registers need a byte order; a write's values fit its type and, as
/// registers, its function (FC06 one, FC16 at most 123).
fn by_function() -> Vec<Value> {
    let none = json!({"type": "null"});
    let mut branches = vec![
        json!({"properties": {"function": {"enum": [1, 2]}, "bit_count": {"type": "integer", "maximum": 8}, "values": none},
               "required": ["bit_count"]}),
        json!({"properties": {"function": {"enum": [1, 2]}, "bit_count": {"type": "integer", "minimum": 9},
                              "byte_order": {"type": "string"}, "values": none},
               "required": ["bit_count", "byte_order"]}),
        json!({"properties": {"function": {"enum": [3, 4]}, "value_type": {"type": "string"},
                              "byte_order": {"type": "string"}, "values": none},
               "required": ["value_type", "byte_order"]}),
        json!({"properties": {"function": {"const": 5},
                              "values": {"type": "array", "minItems": 1, "maxItems": 1}},
               "required": ["values"]}),
        json!({"properties": {"function": {"const": 15},
                              "values": {"type": "array", "minItems": 1, "maxItems": 1968}},
               "required": ["values"]}),
    ];
    for (name, item, registers, ordered) in write_types() {
        let required: Vec<&str> = ["type", "values"]
            .into_iter()
            .chain(ordered.then_some("byte_order"))
            .collect();
        let byte_order = if ordered {
            json!({"type": "string"})
        } else {
            json!({})
        };
        if registers == 1 {
            branches.push(json!({"properties": {"function": {"const": 6}, "type": {"const": name},
                "byte_order": byte_order, "values": {"type": "array", "minItems": 1, "maxItems": 1, "items": item}},
                "required": required}));
        }
        branches.push(json!({"properties": {"function": {"const": 16}, "type": {"const": name},
            "byte_order": byte_order, "values": {"type": "array", "minItems": 1, "maxItems": 123 / registers, "items": item}},
            "required": required}));
    }
    branches
}

/// The register writes' types: the JSON of a value, the registers one takes, and whether
/// it needs a byte order.
fn write_types() -> [(&'static str, Value, u32, bool); 7] {
    // Within f32's range, a little inside so that no rounding of the bound leaves it.
    let f32_max = 3.4e38_f64;
    [
        (
            "uint8",
            json!({"type": "integer", "minimum": 0, "maximum": 255}),
            1,
            false,
        ),
        (
            "int8",
            json!({"type": "integer", "minimum": -128, "maximum": 127}),
            1,
            false,
        ),
        (
            "uint16",
            json!({"type": "integer", "minimum": 0, "maximum": 65535}),
            1,
            true,
        ),
        (
            "int16",
            json!({"type": "integer", "minimum": -32768, "maximum": 32767}),
            1,
            true,
        ),
        (
            "int32",
            json!({"type": "integer", "minimum": i32::MIN, "maximum": i32::MAX}),
            2,
            true,
        ),
        (
            "float",
            json!({"type": "number", "minimum": -f32_max, "maximum": f32_max}),
            2,
            true,
        ),
        (
            "int32/float",
            json!({"type": "number", "minimum": i32::MIN, "maximum": i32::MAX}),
            2,
            true,
        ),
    ]
}

/// Bearer tokens: the scheme always; required by every API operation (not the health and
/// metrics endpoints) when the gateway has tokens, with its 401 and 403.
fn security(doc: &mut Value, secured: bool) {
    merge(
        doc,
        "/components",
        json!({"securitySchemes": {"bearer": {"type": "http", "scheme": "bearer",
            "description": "a token of `security.tokens_file` or `IOGATE_TOKENS`; its role (read, write, admin) decides what it may do"}}}),
    );
    if !secured {
        return;
    }
    let Some(Value::Object(paths)) = doc.get_mut("paths") else {
        return;
    };
    for (path, operations) in paths.iter_mut() {
        if !path.starts_with("/api/v1/") {
            continue;
        }
        let Some(operations) = operations.as_object_mut() else {
            continue;
        };
        for op in operations.values_mut() {
            let Some(op) = op.as_object_mut() else {
                continue;
            };
            op.insert("security".into(), json!([{"bearer": []}]));
            if let Some(Value::Object(responses)) = op.get_mut("responses") {
                let error = json!({"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}});
                responses.entry("401").or_insert_with(|| {
                    json!({"description": "no token, or an unknown one", "content": error.clone()})
                });
                responses.entry("403").or_insert_with(|| {
                    json!({"description": "the token's role is below the operation's", "content": error})
                });
            }
        }
    }
}

#[cfg(test)]
#[path = "openapi_tests.rs"]
mod tests;
