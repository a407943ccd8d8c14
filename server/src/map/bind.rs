//! Fields (and device diagnostics) bound to located addresses: the `map` entries of the
//! config checked against the devices' profiles, and with `auto: true` every other field
//! bound to the next free location of its kind. Checked by `iogate check`, printed by
//! `iogate map`, served by the Modbus TCP server.

use std::collections::{HashMap, HashSet};

use iogate_types::{Area, Location, Size};

use super::space::{Slot, Space};
use super::value::Repr;
use crate::codec::IecType;
use crate::config::Config;
use crate::config::modbus_server::ModbusServerConfig;
use crate::profile::{Catalog, Profile, RegisterKind};
use crate::yaml::{Problems, Report};

/// A device diagnostic a location can show.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Diag {
    Connected,
    ErrorCode,
    IoCycles,
    LastResponseMs,
}

impl Diag {
    pub(crate) const ALL: [Diag; 4] = [
        Diag::Connected,
        Diag::ErrorCode,
        Diag::IoCycles,
        Diag::LastResponseMs,
    ];

    /// The name and type of the function block's diagnostic output.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Diag::Connected => "connected",
            Diag::ErrorCode => "error_code",
            Diag::IoCycles => "io_cycles",
            Diag::LastResponseMs => "last_response_ms",
        }
    }

    pub(crate) fn ty(self) -> IecType {
        match self {
            Diag::Connected => IecType::Bool,
            Diag::ErrorCode => IecType::Int,
            Diag::IoCycles => IecType::Udint,
            Diag::LastResponseMs => IecType::Real,
        }
    }
}

/// What a location shows: a field (by index in its profile) or a diagnostic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    Field(usize),
    Diagnostic(Diag),
}

/// One binding.
#[derive(Debug, Clone, PartialEq)]
pub struct Binding {
    pub(crate) at: Location,
    pub(crate) slot: Slot,
    pub(crate) device: String,
    pub(crate) target: Target,
    /// The field's (or diagnostic's) name.
    pub(crate) name: String,
    pub(crate) ty: IecType,
    pub(crate) repr: Repr,
    /// Whether masters may write it: an output or inout field outside `%I`.
    pub(crate) writable: bool,
    /// Bound by `auto` rather than by a `map` entry.
    pub(crate) auto: bool,
}

/// Every binding of the server's map, in location order.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    pub(crate) space: Space,
    pub(crate) bindings: Vec<Binding>,
    /// Fields `auto` could not bind (no location of their kind left, or a STRING).
    pub(crate) unbound: Vec<String>,
    /// Bindings that work but may not show every value (a TIME at `%MD`): `check` and
    /// `serve` print them, they stop nothing.
    pub(crate) warnings: Vec<crate::yaml::Problem>,
}

/// Why a field or diagnostic does not fit a location.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum FitError {
    #[error("a {ty} does not fit {at} ({}; see the map table of docs/modbus-server.md)", holds(at.size))]
    Type { ty: IecType, at: Location },
    #[error(
        "{at} is an output location that masters write: bind an output or inout field (or use %I or %M)"
    )]
    ReadOnly { at: Location },
}

/// What a size of location holds, for a [`FitError::Type`].
fn holds(size: Size) -> &'static str {
    match size {
        Size::Bit => "bit locations hold BOOL",
        Size::Word => "word locations hold 8/16-bit types, or a REAL on one register",
        Size::Double => "double-word locations hold DINT, UDINT, DWORD, REAL or TIME",
        Size::Long => "long-word locations hold LINT, ULINT, LWORD, LREAL or TIME",
        Size::Byte => "byte locations have no Modbus address",
    }
}

/// How a field or diagnostic fits a location, or why it does not.
fn fit(
    at: &Location,
    ty: IecType,
    one_register: bool,
    writable_field: bool,
    diagnostic: bool,
) -> Result<(Repr, bool), FitError> {
    let repr = Repr::of(ty, at.size, one_register).ok_or(FitError::Type { ty, at: *at })?;
    if at.area == Area::Output && (diagnostic || !writable_field) {
        return Err(FitError::ReadOnly { at: *at });
    }
    let writable = at.area != Area::Input && !diagnostic && writable_field;
    Ok((repr, writable))
}

/// The kind of location `auto` gives a field, if any. TIME is 64-bit milliseconds (source
/// document 000), so it goes to `%ML`, where every value fits.
fn auto_kind(ty: IecType, one_register: bool, writable: bool) -> Option<(Area, Size)> {
    let io = if writable { Area::Output } else { Area::Input };
    [
        (io, Size::Bit),
        (io, Size::Word),
        (Area::Memory, Size::Double),
        (Area::Memory, Size::Long),
    ]
    .into_iter()
    .filter(|(_, size)| !(ty == IecType::Time && *size == Size::Double))
    .find(|(_, size)| Repr::of(ty, *size, one_register).is_some())
}

fn one_register(profile: &Profile, idx: usize) -> bool {
    let r = &profile.fields[idx].register;
    r.kind != RegisterKind::Virtual && r.word_count == 1
}

/// Resolves the server's map against the config's devices and the profiles; every problem
/// with its line.
pub(crate) fn plan(config: &Config, catalog: &Catalog) -> Result<Option<Plan>, Problems> {
    let Some(server) = &config.modbus_server else {
        return Ok(None);
    };
    let mut report = Report::new(&config.source);
    let plan = resolve(server, config, catalog, &mut report);
    let problems = report.into_problems();
    if problems.is_empty() {
        Ok(Some(plan))
    } else {
        Err(problems)
    }
}

fn resolve(
    server: &ModbusServerConfig,
    config: &Config,
    catalog: &Catalog,
    report: &mut Report,
) -> Plan {
    let space = Space::of(server.address_space);
    let profile_of = |device: &str| {
        config
            .devices
            .iter()
            .find(|d| d.name == device)
            .and_then(|d| catalog.get(&d.profile))
    };
    let mut bindings: Vec<Binding> = Vec::new();
    let mut warnings = Vec::new();
    // Which binding holds each table address, to refuse overlaps.
    let mut taken: HashMap<(super::space::Table, u16), Location> = HashMap::new();
    let mut claim = |slot: Slot, at: Location| -> Result<(), Location> {
        let addresses = (slot.address..slot.address + slot.width).map(|a| (slot.table, a));
        if let Some(other) = addresses.clone().find_map(|k| taken.get(&k).copied()) {
            return Err(other);
        }
        for k in addresses {
            taken.insert(k, at);
        }
        Ok(())
    };
    for entry in &server.map {
        let ctx = format!("modbus_server.map: {}", entry.at);
        let slot = match space.slot(&entry.at) {
            Ok(s) => s,
            Err(e) => {
                report.push(entry.line, &ctx, e);
                continue;
            }
        };
        let Some(profile) = profile_of(&entry.device) else {
            // A device (or its profile) that could not be read has its problems reported.
            // So has a device whose profile is unknown (`check` names the profile).
            let reported = config.unreadable.devices.contains(&entry.device)
                || config.devices.iter().any(|d| d.name == entry.device);
            if reported {
                continue;
            }
            report.push(
                entry.line,
                &ctx,
                format!("unknown device `{}`", entry.device),
            );
            continue;
        };
        let (target, name, ty, writable_field, diagnostic) = match profile.field_index(&entry.field)
        {
            Some(idx) => {
                let f = &profile.fields[idx];
                (
                    Target::Field(idx),
                    f.name.clone(),
                    f.ty,
                    f.direction.is_writable(),
                    false,
                )
            }
            None => match Diag::ALL
                .into_iter()
                .find(|d| d.name().eq_ignore_ascii_case(&entry.field))
            {
                Some(d) => (
                    Target::Diagnostic(d),
                    d.name().to_owned(),
                    d.ty(),
                    false,
                    true,
                ),
                None => {
                    report.push(
                        entry.line,
                        &ctx,
                        format!(
                            "device {} has no field or diagnostic `{}`",
                            entry.device, entry.field
                        ),
                    );
                    continue;
                }
            },
        };
        let one = matches!(target, Target::Field(i) if one_register(profile, i));
        let (repr, writable) = match fit(&entry.at, ty, one, writable_field, diagnostic) {
            Ok(f) => f,
            Err(e) => {
                report.push(entry.line, &ctx, format!("{}.{name}: {e}", entry.device));
                continue;
            }
        };
        if ty == IecType::Time && entry.at.size == Size::Double {
            warnings.push(crate::yaml::Problem {
                file: config.source.clone(),
                line: entry.line,
                context: ctx.clone(),
                message: format!(
                    "{}.{name}: TIME is 64-bit milliseconds; {} holds -2147483648 to 2147483647 ms \
                     (about ±24.8 days) and a value outside is answered with exception 0B, not \
                     clamped: bind it at %ML to serve every value",
                    entry.device, entry.at
                ),
            });
        }
        if let Err(other) = claim(slot, entry.at) {
            report.push(
                entry.line,
                &ctx,
                format!("overlaps {other}, bound to another field"),
            );
            continue;
        }
        bindings.push(Binding {
            at: entry.at,
            slot,
            device: entry.device.clone(),
            target,
            name,
            ty,
            repr,
            writable,
            auto: false,
        });
    }
    for f in &server.forward {
        if !config.links.iter().any(|l| l.name == f.link)
            && !config.unreadable.links.contains(&f.link)
        {
            report.push(
                f.line,
                "modbus_server.forward",
                format!("unknown link `{}`", f.link),
            );
        }
        if (f.first..=f.last).contains(&server.unit_id) {
            report.push(
                f.line,
                "modbus_server.forward",
                format!(
                    "unit ids {}-{} include the server's own unit_id {}",
                    f.first, f.last, server.unit_id
                ),
            );
        }
    }
    let mut unbound = Vec::new();
    if server.auto {
        let mapped: HashSet<(String, String)> = bindings
            .iter()
            .map(|b| (b.device.clone(), b.name.to_ascii_lowercase()))
            .collect();
        let mut cursors: HashMap<(Area, Size), u32> = HashMap::new();
        for device in &config.devices {
            let Some(profile) = catalog.get(&device.profile) else {
                continue;
            };
            for (idx, f) in profile.fields.iter().enumerate() {
                if mapped.contains(&(device.name.clone(), f.name.to_ascii_lowercase())) {
                    continue;
                }
                let one = one_register(profile, idx);
                let writable = f.direction.is_writable();
                let Some((area, size)) = auto_kind(f.ty, one, writable) else {
                    unbound.push(format!("{}.{} ({})", device.name, f.name, f.ty));
                    continue;
                };
                let cursor = cursors.entry((area, size)).or_insert(0);
                let free = space
                    .locations(area, size)
                    .skip(*cursor as usize)
                    .enumerate()
                    .find_map(|(k, at)| {
                        let slot = space.slot(&at).ok()?;
                        claim(slot, at).ok().map(|()| (k, at, slot))
                    });
                let Some((k, at, slot)) = free else {
                    unbound.push(format!("{}.{} ({})", device.name, f.name, f.ty));
                    continue;
                };
                *cursor += k as u32 + 1;
                let Ok((repr, writable)) = fit(&at, f.ty, one, writable, false) else {
                    continue;
                };
                bindings.push(Binding {
                    at,
                    slot,
                    device: device.name.clone(),
                    target: Target::Field(idx),
                    name: f.name.clone(),
                    ty: f.ty,
                    repr,
                    writable,
                    auto: true,
                });
            }
        }
    }
    bindings.sort_by_key(|b| (b.slot.table, b.slot.address));
    Plan {
        space,
        bindings,
        unbound,
        warnings,
    }
}
