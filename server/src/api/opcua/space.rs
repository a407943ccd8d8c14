//! The address space's shape and its values: node ids, IEC types as OPC UA built-in types,
//! qualities as status codes, and the nodes of a device (its fields, with their unit and
//! description, and its diagnostics) and of a link.
//!
//! ```text
//! Objects/iogate                  s=/iogate
//!   Devices                       s=/iogate/Devices
//!     <device>                    s=Devices/<device>     (object)
//!       <field>                   s=<device>.<field>     (variable)
//!         EngineeringUnits        s=<device>.<field>/EngineeringUnits (property)
//!         EURange                 s=<device>.<field>/EURange (property, numeric fields)
//!       Diagnostics               s=Diagnostics/<device> (object)
//!         connected ...           s=Diagnostics/<device>/<name>
//!   Links                         s=/iogate/Links
//!     <link>                      s=/Links/<link>
//!       connected, error_code     s=/Links/<link>/<name>
//! ```
//!
//! Device and link names hold `[A-Za-z0-9_.-]` (a dot, but never a `/`), field names
//! `[A-Za-z0-9_]`: an id without `/` is a field's, split at its last dot; every other id
//! starts with a word no device-and-field id can (`Devices/`, `Diagnostics/`, `/`), so no
//! id made here can be another's, whatever the names (a device `plant.Level` beside a
//! device `plant` with a field `Level` included). BrowseNames are in the gateway's
//! namespace (`2:plant`), but for the standard properties'. TIME is a `Duration` (a Double
//! of milliseconds, OPC UA's own type for spans of time).

use std::time::SystemTime;

use opcua::server::address_space::{
    AccessLevel, AddressSpace, NodeType, ObjectBuilder, VariableBuilder,
};
use opcua::types::{
    DataTypeId, DataValue, DateTime, EUInformation, ExtensionObject, LocalizedText, NodeId,
    ObjectTypeId, QualifiedName, Range, StatusCode, UAString, VariableTypeId, Variant,
};

use crate::cache::{Device, Diagnostics, FieldError, Link, LinkDiagnostics, Sample};
use crate::codec::{IecType, Value};
pub(crate) use crate::opcua_variant::{data_type, value_of, variant};
use crate::profile::{Direction, Field};
use crate::service::{FieldView, Service};
use iogate_types::Quality;

pub(crate) const ROOT: &str = "/iogate";
pub(crate) const DEVICES: &str = "/iogate/Devices";
pub(crate) const LINKS: &str = "/iogate/Links";

/// The device diagnostics' variable names.
pub(crate) const DEVICE_DIAGNOSTICS: [&str; 4] =
    ["connected", "error_code", "io_cycles", "last_response_ms"];
/// The link diagnostics' variable names.
pub(crate) const LINK_DIAGNOSTICS: [&str; 2] = ["connected", "error_code"];

/// The ids of the gateway's namespace `ns`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Ids {
    pub(crate) ns: u16,
}

impl Ids {
    pub(crate) fn folder(self, id: &str) -> NodeId {
        NodeId::new(self.ns, id)
    }
    pub(crate) fn device(self, device: &str) -> NodeId {
        NodeId::new(self.ns, format!("Devices/{device}"))
    }
    pub(crate) fn field(self, device: &str, field: &str) -> NodeId {
        NodeId::new(self.ns, format!("{device}.{field}"))
    }
    fn units(self, device: &str, field: &str) -> NodeId {
        NodeId::new(self.ns, format!("{device}.{field}/EngineeringUnits"))
    }
    fn range(self, device: &str, field: &str) -> NodeId {
        NodeId::new(self.ns, format!("{device}.{field}/EURange"))
    }
    pub(crate) fn device_diagnostics(self, device: &str) -> NodeId {
        NodeId::new(self.ns, format!("Diagnostics/{device}"))
    }
    pub(crate) fn device_diagnostic(self, device: &str, name: &str) -> NodeId {
        NodeId::new(self.ns, format!("Diagnostics/{device}/{name}"))
    }
    pub(crate) fn link(self, link: &str) -> NodeId {
        NodeId::new(self.ns, format!("/Links/{link}"))
    }
    pub(crate) fn link_diagnostic(self, link: &str, name: &str) -> NodeId {
        NodeId::new(self.ns, format!("/Links/{link}/{name}"))
    }

    /// A name in the gateway's namespace, for BrowseNames.
    pub(crate) fn name(self, name: &str) -> QualifiedName {
        QualifiedName::new(self.ns, name)
    }

    /// What a variable whose value lives in the gateway (not in the address space) shows.
    pub(crate) fn live_of(self, id: &NodeId) -> Option<Live> {
        if id.namespace != self.ns {
            return None;
        }
        let opcua::types::Identifier::String(s) = &id.identifier else {
            return None;
        };
        let text = s.as_ref();
        let pair = |rest: &str| {
            rest.split_once('/')
                .filter(|(_, name)| !name.contains('/'))
                .map(|(a, b)| (a.to_owned(), b.to_owned()))
        };
        if let Some(rest) = text.strip_prefix("Diagnostics/") {
            return pair(rest).map(|(d, n)| Live::DeviceDiagnostic(d, n));
        }
        if let Some(rest) = text.strip_prefix("/Links/") {
            return pair(rest).map(|(l, n)| Live::LinkDiagnostic(l, n));
        }
        if text.contains('/') {
            return None;
        }
        let (device, field) = text.rsplit_once('.')?;
        Some(Live::Field(device.to_owned(), field.to_owned()))
    }

    /// The device and field a field variable's id names (`<device>.<field>`: field names
    /// hold no dot).
    pub(crate) fn field_of(self, id: &NodeId) -> Option<(String, String)> {
        match self.live_of(id)? {
            Live::Field(device, field) => Some((device, field)),
            _ => None,
        }
    }
}

/// A variable whose value is read from the gateway when asked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum Live {
    Field(String, String),
    DeviceDiagnostic(String, String),
    LinkDiagnostic(String, String),
}

/// The status code of a field's quality as of now, as the service tells it.
pub(crate) fn status(view: &FieldView<'_>) -> StatusCode {
    status_of(view.quality, view.error.as_ref())
}

fn status_of(quality: Quality, error: Option<&FieldError>) -> StatusCode {
    match quality {
        Quality::Good => StatusCode::Good,
        Quality::Stale => StatusCode::UncertainLastUsableValue,
        Quality::NeverRead => match error {
            Some(FieldError::Unreachable(_)) => StatusCode::BadNoCommunication,
            Some(FieldError::NoResponse(_)) => StatusCode::BadCommunicationError,
            _ => StatusCode::BadWaitingForInitialData,
        },
        Quality::Bad => match error {
            Some(FieldError::Unreachable(_)) => StatusCode::BadNoCommunication,
            Some(FieldError::Decode(_)) => StatusCode::BadDecodingError,
            Some(FieldError::Exception(_)) => StatusCode::BadDeviceFailure,
            _ => StatusCode::BadCommunicationError,
        },
    }
}

fn date_time(at: SystemTime) -> DateTime {
    DateTime::from(opcua::types::DateTimeUtc::from(at))
}

/// A field's view as a data value: the value (the last good one while stale; none with a
/// Bad status, as OPC UA Part 4, 7.7.1 asks), the status from the quality, the source
/// timestamp when the device was read.
pub(crate) fn data_value(view: &FieldView<'_>, now: DateTime) -> DataValue {
    rendered(
        view.field.ty,
        view.value.as_ref(),
        status(view),
        view.timestamp,
        now,
    )
}

/// [`data_value`] of field `idx`'s `sample`, its quality as of `instant`: what a change
/// needs of the field's view, without the rest (desired value, latest write).
pub(crate) fn sample_value(
    device: &Device,
    idx: usize,
    sample: &Sample,
    instant: tokio::time::Instant,
    now: DateTime,
) -> DataValue {
    let status = status_of(device.quality(sample, instant), sample.error.as_deref());
    rendered(
        device.field(idx).ty,
        sample.value.as_ref(),
        status,
        sample.updated.map(|(_, wall)| wall),
        now,
    )
}

fn rendered(
    ty: IecType,
    value: Option<&Value>,
    status: StatusCode,
    timestamp: Option<SystemTime>,
    now: DateTime,
) -> DataValue {
    let value = match value {
        Some(v) if !status.is_bad() => variant(ty, v),
        _ => Variant::Empty,
    };
    DataValue {
        value: Some(value),
        status: Some(status),
        source_timestamp: timestamp.map(date_time),
        source_picoseconds: None,
        server_timestamp: Some(now),
        server_picoseconds: None,
    }
}

fn good(value: Variant, now: DateTime) -> DataValue {
    DataValue {
        value: Some(value),
        status: Some(StatusCode::Good),
        source_timestamp: Some(now),
        source_picoseconds: None,
        server_timestamp: Some(now),
        server_picoseconds: None,
    }
}

/// A device's diagnostics as data values, by variable name.
pub(crate) fn device_diagnostics(d: &Diagnostics, now: DateTime) -> [(&'static str, DataValue); 4] {
    [
        ("connected", good(Variant::Boolean(d.connected), now)),
        ("error_code", good(Variant::Int16(d.error_code.code()), now)),
        ("io_cycles", good(Variant::UInt64(d.io_cycles), now)),
        (
            "last_response_ms",
            good(Variant::Double(d.last_response_ms), now),
        ),
    ]
}

/// A link's diagnostics as data values, by variable name.
pub(crate) fn link_diagnostics(
    d: &LinkDiagnostics,
    now: DateTime,
) -> [(&'static str, DataValue); 2] {
    [
        ("connected", good(Variant::Boolean(d.connected), now)),
        ("error_code", good(Variant::Int16(d.error_code.code()), now)),
    ]
}

fn access(direction: Direction) -> AccessLevel {
    match direction {
        Direction::Input => AccessLevel::CURRENT_READ,
        Direction::Output | Direction::Inout => {
            AccessLevel::CURRENT_READ | AccessLevel::CURRENT_WRITE
        }
    }
}

fn units(unit: &str) -> ExtensionObject {
    ExtensionObject::from_message(EUInformation {
        namespace_uri: UAString::from("http://www.opcfoundation.org/UA/units/un/cefact"),
        unit_id: -1,
        display_name: LocalizedText::new("", unit),
        description: LocalizedText::new("", unit),
    })
}

fn diagnostic_type(name: &str) -> DataTypeId {
    match name {
        "connected" => DataTypeId::Boolean,
        "io_cycles" => DataTypeId::UInt64,
        "last_response_ms" => DataTypeId::Double,
        _ => DataTypeId::Int16,
    }
}

/// A read-only scalar variable of `data_type` (a diagnostic or a property) named `name`.
fn read_only(id: &NodeId, name: QualifiedName, data_type: DataTypeId) -> VariableBuilder {
    let display = name.name.as_ref().to_owned();
    VariableBuilder::new(id, name, display.as_str())
        .data_type(data_type)
        .access_level(AccessLevel::CURRENT_READ)
        .user_access_level(AccessLevel::CURRENT_READ)
        .value_rank(-1)
}

/// Sets the value, status and timestamps of a variable just inserted.
fn set_initial(space: &mut AddressSpace, id: &NodeId, value: DataValue) {
    if let Some(NodeType::Variable(v)) = space.find_mut(id) {
        v.set_data_value(value);
    }
}

/// Adds a device: its object, a variable per field and its diagnostics.
pub(crate) fn add_device(
    space: &mut AddressSpace,
    service: &Service,
    ids: Ids,
    device: &Device,
    now: DateTime,
) {
    let name = device.name();
    let object = ids.device(name);
    let description = device
        .profile
        .description
        .clone()
        .unwrap_or_else(|| format!("profile {}", device.profile.name));
    ObjectBuilder::new(&object, ids.name(name), name)
        .description(description)
        .has_type_definition(ObjectTypeId::BaseObjectType)
        .organized_by(ids.folder(DEVICES))
        .insert(space);
    for (idx, field) in device.profile.fields.iter().enumerate() {
        add_field(space, ids, device, field);
        set_initial(
            space,
            &ids.field(device.name(), &field.name),
            data_value(&service.field_view_now(device, idx), now),
        );
    }
    let diag = ids.device_diagnostics(name);
    ObjectBuilder::new(&diag, ids.name("Diagnostics"), "Diagnostics")
        .description(
            "connected, error_code (0 OK, 1 no link, 2 no slave, 10 communication error), io_cycles, last_response_ms",
        )
        .has_type_definition(ObjectTypeId::BaseObjectType)
        .component_of(object.clone())
        .insert(space);
    for (var, value) in device_diagnostics(&device.diagnostics(), now) {
        let id = ids.device_diagnostic(name, var);
        read_only(&id, ids.name(var), diagnostic_type(var))
            .has_type_definition(VariableTypeId::BaseDataVariableType)
            .component_of(diag.clone())
            .insert(space);
        set_initial(space, &id, value);
    }
}

fn add_field(space: &mut AddressSpace, ids: Ids, device: &Device, field: &Field) {
    let id = ids.field(device.name(), &field.name);
    let level = access(field.direction);
    let builder = VariableBuilder::new(&id, ids.name(&field.name), field.name.as_str())
        .data_type(data_type(field.ty))
        .access_level(level)
        .user_access_level(level)
        .value_rank(-1)
        .minimum_sampling_interval(0.0)
        .has_type_definition(VariableTypeId::BaseDataVariableType)
        .component_of(ids.device(device.name()));
    let description = match (&field.description, field.register.unit.as_deref()) {
        (Some(d), _) => d.clone(),
        (None, Some(unit)) => format!("{} {}, {unit}", field.ty, field.direction.name()),
        (None, None) => format!("{} {}", field.ty, field.direction.name()),
    };
    builder.description(description).insert(space);
    let properties = [
        eu_range(field).map(|(low, high)| {
            (
                ids.range(device.name(), &field.name),
                "EURange",
                DataTypeId::Range,
                ExtensionObject::from_message(Range { low, high }),
            )
        }),
        field.register.unit.as_deref().map(|unit| {
            (
                ids.units(device.name(), &field.name),
                "EngineeringUnits",
                DataTypeId::EUInformation,
                units(unit),
            )
        }),
    ];
    for (property, name, data_type, value) in properties.into_iter().flatten() {
        // The standard properties keep their standard BrowseNames (namespace 0).
        read_only(&property, QualifiedName::from(name), data_type)
            .value(value)
            .has_type_definition(VariableTypeId::PropertyType)
            .property_of(id.clone())
            .insert(space);
    }
}

/// The range a numeric field's values take, for percent deadbands: an integer type's own
/// range, or for a REAL stored as an integer register the register's range scaled.
fn eu_range(field: &Field) -> Option<(f64, f64)> {
    if field.ty == IecType::Time {
        return None;
    }
    if let Some((min, max)) = field.ty.int_range() {
        return Some((min as f64, max as f64));
    }
    let raw = field.register.raw_type?;
    let (min, max) = raw.int_range()?;
    let (a, b) = (
        min as f64 * field.register.scale + field.register.offset,
        max as f64 * field.register.scale + field.register.offset,
    );
    Some((a.min(b), a.max(b)))
}

/// Removes a device's nodes (its fields, units, diagnostics and object).
pub(crate) fn remove_device(space: &mut AddressSpace, ids: Ids, name: &str, fields: &[String]) {
    for field in fields {
        space.delete(&ids.range(name, field), true);
        space.delete(&ids.units(name, field), true);
        space.delete(&ids.field(name, field), true);
    }
    for var in DEVICE_DIAGNOSTICS {
        space.delete(&ids.device_diagnostic(name, var), true);
    }
    space.delete(&ids.device_diagnostics(name), true);
    space.delete(&ids.device(name), true);
}

/// Adds a link: its object and diagnostics.
pub(crate) fn add_link(space: &mut AddressSpace, ids: Ids, link: &Link, now: DateTime) {
    let name = link.name();
    let object = ids.link(name);
    ObjectBuilder::new(&object, ids.name(name), name)
        .description(link.config().transport.to_string())
        .has_type_definition(ObjectTypeId::BaseObjectType)
        .organized_by(ids.folder(LINKS))
        .insert(space);
    for (var, value) in link_diagnostics(&link.diagnostics(), now) {
        let id = ids.link_diagnostic(name, var);
        read_only(&id, ids.name(var), diagnostic_type(var))
            .has_type_definition(VariableTypeId::BaseDataVariableType)
            .component_of(object.clone())
            .insert(space);
        set_initial(space, &id, value);
    }
}

/// Removes a link's nodes.
pub(crate) fn remove_link(space: &mut AddressSpace, ids: Ids, name: &str) {
    for var in LINK_DIAGNOSTICS {
        space.delete(&ids.link_diagnostic(name, var), true);
    }
    space.delete(&ids.link(name), true);
}
