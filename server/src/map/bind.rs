//! Fields (and device diagnostics) bound to located addresses: the `map` entries of the
//! config checked against the devices' profiles, and with `auto: true` every other field
//! bound to the next free location of its kind. Checked by `iogate check`, printed by
//! `iogate map`, served by the Modbus TCP server.

use std::collections::HashMap;

use iogate_types::{Area, Location, Size};

mod auto;

use super::space::{Slot, Space};
use super::value::Repr;
use crate::codec::IecType;
use crate::config::Config;
use crate::config::modbus_server::{MapEntry, ModbusServerConfig};
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
    /// Locations `auto` gave a field that a reload removed (or gave another kind): kept
    /// empty, so that no master reading them gets another field's value, until a restart
    /// numbers the map afresh. With the field they held.
    pub(crate) reserved: Vec<(Location, String)>,
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

fn one_register(profile: &Profile, idx: usize) -> bool {
    let r = &profile.fields[idx].register;
    r.kind != RegisterKind::Virtual && r.word_count == 1
}

/// Resolves the server's map against the config's devices and the profiles; every problem
/// with its line.
pub(crate) fn plan(config: &Config, catalog: &Catalog) -> Result<Option<Plan>, Problems> {
    plan_after(config, catalog, None)
}

/// [`plan`] for a reload of a gateway serving `previous`: every field `auto` bound keeps
/// its location (masters polling it read the same field), new fields take the next free
/// ones, and a removed field's location stays empty.
pub(crate) fn plan_after(
    config: &Config,
    catalog: &Catalog,
    previous: Option<&Plan>,
) -> Result<Option<Plan>, Problems> {
    let Some(server) = &config.modbus_server else {
        return Ok(None);
    };
    let mut report = Report::new(&config.source);
    let plan = resolve(server, config, catalog, previous, &mut report);
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
    previous: Option<&Plan>,
    report: &mut Report,
) -> Plan {
    let mut r = Resolver {
        config,
        catalog,
        space: Space::of(server.address_space),
        taken: HashMap::new(),
        bindings: Vec::new(),
        warnings: Vec::new(),
        unbound: Vec::new(),
        reserved: Vec::new(),
    };
    for entry in &server.map {
        let ctx = format!("modbus_server.map: {}", entry.at);
        if let Err(e) = r.entry(entry, &ctx) {
            report.push(entry.line, &ctx, e);
        }
    }
    check_forwards(server, config, report);
    if server.auto {
        r.auto(previous.filter(|p| p.space == r.space));
    }
    let Resolver {
        space,
        mut bindings,
        warnings,
        unbound,
        reserved,
        ..
    } = r;
    bindings.sort_by_key(|b| (b.slot.table, b.slot.address));
    Plan {
        space,
        bindings,
        unbound,
        warnings,
        reserved,
    }
}

/// The bindings made so far, and which binding holds each table address (to refuse
/// overlaps).
struct Resolver<'a> {
    config: &'a Config,
    catalog: &'a Catalog,
    space: Space,
    taken: HashMap<(super::space::Table, u16), Location>,
    bindings: Vec<Binding>,
    warnings: Vec<crate::yaml::Problem>,
    unbound: Vec<String>,
    reserved: Vec<(Location, String)>,
}

impl<'a> Resolver<'a> {
    /// Takes every address of `slot` for `at`, or names the location holding one of them.
    fn claim(&mut self, slot: Slot, at: Location) -> Result<(), Location> {
        claim(&mut self.taken, slot, at)
    }

    fn profile_of(&self, device: &str) -> Option<&'a Profile> {
        let (config, catalog) = (self.config, self.catalog);
        let device = config.devices.iter().find(|d| d.name == device)?;
        catalog.get(&device.profile).map(|p| &**p)
    }

    /// Binds one map entry, or says why not (`Ok` also when its device's problems are
    /// reported elsewhere).
    fn entry(&mut self, entry: &MapEntry, ctx: &str) -> Result<(), String> {
        let slot = self.space.slot(&entry.at).map_err(|e| e.to_string())?;
        let Some(profile) = self.profile_of(&entry.device) else {
            // A device (or its profile) that could not be read has its problems reported.
            // So has a device whose profile is unknown (`check` names the profile).
            let config = self.config;
            let reported = config.unreadable.devices.contains(&entry.device)
                || config.devices.iter().any(|d| d.name == entry.device);
            return match reported {
                true => Ok(()),
                false => Err(format!("unknown device `{}`", entry.device)),
            };
        };
        let (target, name, ty, writable_field, diagnostic) = entry_target(profile, entry)?;
        let one = matches!(target, Target::Field(i) if one_register(profile, i));
        let (repr, writable) = fit(&entry.at, ty, one, writable_field, diagnostic)
            .map_err(|e| format!("{}.{name}: {e}", entry.device))?;
        if ty == IecType::Time && entry.at.size == Size::Double {
            self.warnings.push(crate::yaml::Problem {
                file: self.config.source.clone(),
                line: entry.line,
                context: ctx.to_owned(),
                message: format!(
                    "{}.{name}: TIME is 64-bit milliseconds; {} holds -2147483648 to 2147483647 ms \
                     (about ±24.8 days) and a value outside is answered with exception 0B, not \
                     clamped: bind it at %ML to serve every value",
                    entry.device, entry.at
                ),
            });
        }
        self.claim(slot, entry.at)
            .map_err(|other| format!("overlaps {other}, bound to another field"))?;
        self.bindings.push(Binding {
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
        Ok(())
    }
}

/// Takes every address of `slot` for `at` in `taken`, or names the location holding one
/// of them.
fn claim(
    taken: &mut HashMap<(super::space::Table, u16), Location>,
    slot: Slot,
    at: Location,
) -> Result<(), Location> {
    let addresses = (slot.address..slot.address + slot.width).map(|a| (slot.table, a));
    if let Some(other) = addresses.clone().find_map(|k| taken.get(&k).copied()) {
        return Err(other);
    }
    for k in addresses {
        taken.insert(k, at);
    }
    Ok(())
}

/// What a map entry binds: a field of the profile or a device diagnostic, with its name,
/// type, whether it is written, and whether it is a diagnostic.
fn entry_target(
    profile: &Profile,
    entry: &MapEntry,
) -> Result<(Target, String, IecType, bool, bool), String> {
    if let Some(idx) = profile.field_index(&entry.field) {
        let f = &profile.fields[idx];
        return Ok((
            Target::Field(idx),
            f.name.clone(),
            f.ty,
            f.direction.is_writable(),
            false,
        ));
    }
    match Diag::ALL
        .into_iter()
        .find(|d| d.name().eq_ignore_ascii_case(&entry.field))
    {
        Some(d) => Ok((
            Target::Diagnostic(d),
            d.name().to_owned(),
            d.ty(),
            false,
            true,
        )),
        None => Err(format!(
            "device {} has no field or diagnostic `{}`",
            entry.device, entry.field
        )),
    }
}

/// The forwarded unit ids: a known link each, never the server's own unit id.
fn check_forwards(server: &ModbusServerConfig, config: &Config, report: &mut Report) {
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
}
