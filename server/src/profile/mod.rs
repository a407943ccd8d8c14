//! Device profiles: the model, loading with validation, and the generated FB layout.

pub(crate) mod deadband;
pub mod import;
pub(crate) mod keywords;
mod layout;
mod load;
mod scale;
mod words;

pub use words::{FieldKey, Words};
pub(crate) use words::{drivers, know};

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::codec::{ByteOrder, Encoding, IecType, Raw, Switch};
use crate::yaml::Problems;

pub use layout::{LayoutEntry, LayoutSection, fb_layout, st_declaration};
pub use load::{load_dir, load_files, load_str};

/// How many parent directories are searched for a `profiles/` folder.
pub(crate) const PARENT_SEARCH_DEPTH: usize = 6;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Protocol {
    ModbusRtu,
    ModbusTcp,
    Simulated,
    /// A protocol of a driver besides Modbus (`crate::drivers`), by its words.
    Driver(&'static Words),
}

impl Protocol {
    /// Every protocol a profile may say.
    pub(crate) fn all() -> Vec<Protocol> {
        [
            Protocol::ModbusRtu,
            Protocol::ModbusTcp,
            Protocol::Simulated,
        ]
        .into_iter()
        .chain(drivers().iter().copied().map(Protocol::Driver))
        .collect()
    }

    pub(crate) fn name(self) -> &'static str {
        match self {
            Protocol::ModbusRtu => "modbus-rtu",
            Protocol::ModbusTcp => "modbus-tcp",
            Protocol::Simulated => "simulated",
            Protocol::Driver(w) => w.protocol,
        }
    }

    /// Whether a device's newest requested outputs are written again after a reconnect or
    /// its return, when its `rewrite_outputs` does not say: never, unless the protocol's
    /// devices are I/O modules that lose their outputs at power-up and nobody else writes
    /// (Modbus); a PLC's program, HMIs and other masters write its tags too.
    pub(crate) fn rewrites_outputs(self) -> bool {
        self.is_modbus()
    }

    /// Whether a device of this protocol is a Modbus unit (a link and a slave id).
    pub(crate) fn is_modbus(self) -> bool {
        matches!(self, Protocol::ModbusRtu | Protocol::ModbusTcp)
    }

    /// The words of a protocol whose fields name their points (an OPC UA node).
    pub(crate) fn words(self) -> Option<&'static Words> {
        match self {
            Protocol::Driver(w) => Some(w),
            _ => None,
        }
    }

    /// The key of the link settings a device of this protocol needs (none: `serial` or
    /// `tcp`, Modbus).
    pub(crate) fn link_key(self) -> Option<&'static str> {
        self.words().map(|w| w.link_key)
    }
}

pub(crate) use iogate_types::Direction;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum RegisterKind {
    Coil,
    DiscreteInput,
    HoldingRegister,
    InputRegister,
    Virtual,
    /// A point of a protocol that addresses fields by name (an OPC UA node):
    /// [`Field::point`] says which.
    Point,
}

impl RegisterKind {
    /// The kinds a profile's `register.kind` may say.
    pub(crate) const ALL: [RegisterKind; 5] = [
        RegisterKind::Coil,
        RegisterKind::DiscreteInput,
        RegisterKind::HoldingRegister,
        RegisterKind::InputRegister,
        RegisterKind::Virtual,
    ];

    pub(crate) fn name(self) -> &'static str {
        match self {
            RegisterKind::Coil => "coil",
            RegisterKind::DiscreteInput => "discrete_input",
            RegisterKind::HoldingRegister => "holding_register",
            RegisterKind::InputRegister => "input_register",
            RegisterKind::Virtual => "virtual",
            RegisterKind::Point => "point",
        }
    }

    /// Coils and discrete inputs hold single bits.
    pub(crate) fn is_bit(self) -> bool {
        matches!(self, RegisterKind::Coil | RegisterKind::DiscreteInput)
    }

    pub(crate) fn is_read_only(self) -> bool {
        matches!(
            self,
            RegisterKind::DiscreteInput | RegisterKind::InputRegister
        )
    }
}

/// Where a field lives on the device and how its value is stored there.
#[derive(Debug, Clone, PartialEq)]
pub struct Register {
    pub(crate) address: u16,
    pub(crate) kind: RegisterKind,
    pub(crate) bit: Option<u8>,
    pub(crate) scale: f64,
    pub(crate) offset: f64,
    pub(crate) unit: Option<String>,
    pub(crate) byte_order: ByteOrder,
    pub(crate) word_count: u16,
    /// Whether `word_count` was written in the profile (else it is the default, 1).
    pub(crate) word_count_set: bool,
    /// For REAL/LREAL fields stored as integers: the integer type of the register value.
    pub(crate) raw_type: Option<IecType>,
    /// For a BOOL: `on_value`/`off_value`, the raw values meaning TRUE and FALSE where they
    /// are not the plain ones (an inverted coil, a register switched by 0xA5/0x5A).
    pub(crate) switch: Option<Switch>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub(crate) name: String,
    pub(crate) ty: IecType,
    pub(crate) direction: Direction,
    pub(crate) register: Register,
    pub(crate) description: Option<String>,
    /// How much the value must change before MQTT reports it (else the section's).
    pub(crate) deadband: Option<deadband::Deadband>,
    pub(crate) encoding: Encoding,
    /// Where the field is on a device of a protocol that addresses fields by name (an OPC
    /// UA node id, as the profile writes it); `None` for a Modbus or simulated field.
    pub(crate) point: Option<Point>,
    /// The line of the profile file the field starts on.
    pub(crate) line: u64,
}

/// A field's point on a device whose protocol addresses fields by name.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// As the profile writes it (`ns=3;s=Line1.Speed`, or a browse path).
    pub(crate) address: String,
    /// The key it is written under (`node`, `browse_path`).
    pub(crate) key: &'static str,
    /// Whether `address` is a browse path from the Objects folder rather than an id.
    pub(crate) browse_path: bool,
    /// How often the device samples it, where the profile says (else its refresh rate).
    pub(crate) sampling: Option<std::time::Duration>,
    /// A STRING's maximum length in characters, where the profile says.
    pub(crate) length: Option<u16>,
    /// The protocol's further keys the field carries (`Words::field_keys`), as written.
    pub(crate) extra: Vec<(&'static str, String)>,
}

impl Point {
    /// The text of a further key the field carries, if it does.
    pub(crate) fn get(&self, key: &str) -> Option<&str> {
        self.extra
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, v)| v.as_str())
    }
}

impl Field {
    /// The registers (or coils) the field takes, from its address. A virtual field is one
    /// value at its address.
    pub(crate) fn span(&self) -> u32 {
        if self.register.kind.is_bit()
            || matches!(
                self.register.kind,
                RegisterKind::Virtual | RegisterKind::Point
            )
        {
            1
        } else {
            u32::from(self.register.word_count)
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct Profile {
    pub name: String,
    pub(crate) vendor: Option<String>,
    pub(crate) protocol: Protocol,
    pub(crate) description: Option<String>,
    pub(crate) fields: Vec<Field>,
    /// What the device says it is (FC 43 objects by key: `vendor`, `product_code`, ...),
    /// where the profile states it; a scan suggests the profile only for a device that
    /// says the same.
    pub(crate) identification: BTreeMap<String, String>,
    /// The reads a scan tries to tell the device by (else one read of each register kind's
    /// first field).
    pub(crate) probe: Vec<ProbeRead>,
    /// The file the profile was loaded from.
    pub(crate) source: String,
}

/// The FC 43 objects a profile's `identification:` may state, by key.
pub(crate) const IDENTIFICATION_KEYS: &[&str] = &[
    "vendor",
    "product_code",
    "product_name",
    "model_name",
    "revision",
];

/// One read a scan sends to tell a device by: it must answer with data (and, where given,
/// these register values).
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeRead {
    pub(crate) kind: RegisterKind,
    pub(crate) address: u16,
    pub(crate) count: u16,
    pub(crate) values: Option<Vec<u16>>,
}

impl Profile {
    /// A warning for every field wider than 16 bits that relies on the default `word_count`
    /// of 1 and so reads one register (where a friendlier default would have read the full
    /// width): 32/64-bit integers and TIME, and REAL/LREAL that are neither scaled nor given
    /// a `raw_type` (a scaled REAL on one register is the documented 16-bit idiom).
    pub(crate) fn width_warnings(&self) -> Vec<crate::yaml::Problem> {
        self.fields
            .iter()
            .filter(|f| {
                let r = &f.register;
                let wide = crate::codec::full_words(f.ty) > 1;
                let idiom = f.ty.is_real() && (r.scale != 1.0 || r.offset != 0.0);
                let stored = r.kind != RegisterKind::Virtual;
                stored && wide && !r.word_count_set && r.raw_type.is_none() && !idiom
            })
            .map(|f| {
                let full = crate::codec::full_words(f.ty);
                let add = if f.ty == IecType::Time {
                    "to read 32- or 64-bit milliseconds, add `word_count: 2` or `4`".to_owned()
                } else {
                    format!("to read the full {}-bit value, add `word_count: {full}`", 16 * full)
                };
                let read = match f.ty {
                    t if t.is_real() => "as a 16-bit integer",
                    IecType::Time => "as 16-bit milliseconds",
                    t if t.int_bits().is_some_and(|(_, signed)| signed) => {
                        "as a 16-bit value, sign-extended"
                    }
                    _ => "as a 16-bit value",
                };
                crate::yaml::Problem {
                    file: self.source.clone(),
                    line: f.line,
                    context: format!("field {}", f.name),
                    message: format!(
                        "{} with no `word_count` reads one register {read} (the default is 1); {add} to its register",
                        f.ty
                    ),
                }
            })
            .collect()
    }

    /// A field by name; IEC identifiers ignore case.
    pub(crate) fn field_index(&self, name: &str) -> Option<usize> {
        self.fields
            .iter()
            .position(|f| f.name.eq_ignore_ascii_case(name))
    }
}

/// The raw storage of a field, derived from its type and register options. Validation has
/// already made sure the combination is possible.
pub(crate) fn raw_of(ty: IecType, register: &Register) -> Raw {
    if ty == IecType::Bool {
        return match (register.kind.is_bit(), register.bit) {
            (true, _) => Raw::Bit,
            (false, Some(bit)) => Raw::RegisterBit(bit),
            (false, None) => Raw::RegisterFlag,
        };
    }
    if ty == IecType::String {
        return Raw::Str {
            words: register.word_count,
        };
    }
    if let Some(raw) = register.raw_type.and_then(IecType::int_bits) {
        return Raw::Int {
            bits: raw.0,
            signed: raw.1,
        };
    }
    match (ty, register.word_count) {
        (IecType::Real | IecType::Lreal, 1) => Raw::Int {
            bits: 16,
            signed: true,
        },
        (IecType::Real | IecType::Lreal, 2) => Raw::F32,
        (IecType::Real | IecType::Lreal, _) => Raw::F64,
        (t, words) => {
            // One register holds at most 16 bits: a wider type on fewer registers reads
            // them widened (sign-extended when signed) and writes only what fits.
            let (bits, signed) = t.int_bits().unwrap_or((16, false));
            Raw::Int {
                bits: bits.min(16 * words.min(4) as u8),
                signed,
            }
        }
    }
}

/// Every loaded profile, by name.
#[derive(Debug, Clone, Default)]
pub struct Catalog {
    profiles: BTreeMap<String, Arc<Profile>>,
    /// Names of profiles whose files have problems (reported when they were loaded).
    unreadable: Vec<String>,
}

impl Catalog {
    pub fn new(profiles: impl IntoIterator<Item = Profile>) -> Self {
        Catalog {
            profiles: profiles
                .into_iter()
                .map(|p| (p.name.clone(), Arc::new(p)))
                .collect(),
            unreadable: Vec::new(),
        }
    }

    /// No profiles, with `names` taken as unreadable: the directory itself is missing (that
    /// is reported once), so a device's profile is not reported unknown on top of it.
    pub(crate) fn missing(names: impl IntoIterator<Item = String>) -> Self {
        Catalog {
            profiles: BTreeMap::new(),
            unreadable: names.into_iter().collect(),
        }
    }

    /// Whether `name` is a profile whose file could not be loaded: its problems are
    /// reported already, so a device that uses it is not checked against it.
    pub(crate) fn is_unreadable(&self, name: &str) -> bool {
        self.unreadable.iter().any(|n| n == name)
    }

    pub fn get(&self, name: &str) -> Option<&Arc<Profile>> {
        self.profiles.get(name)
    }

    pub fn iter(&self) -> impl Iterator<Item = &Arc<Profile>> {
        self.profiles.values()
    }

    pub fn len(&self) -> usize {
        self.profiles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.profiles.is_empty()
    }
}

/// The `profiles/` directory: `configured` if given, else `./profiles` in `start` or one of
/// up to [`PARENT_SEARCH_DEPTH`] parent directories.
pub(crate) fn find_dir(configured: Option<&Path>, start: &Path) -> Option<PathBuf> {
    if let Some(dir) = configured {
        return Some(dir.to_path_buf());
    }
    // A relative start (`.` for `./iogate.yaml`, `sub` for `sub/iogate.yaml`) has no parents
    // of its own: resolve it first, following links, so that `..` means the real parent.
    let start = start
        .canonicalize()
        .or_else(|_| std::path::absolute(start))
        .unwrap_or_else(|_| start.to_path_buf());
    start
        .ancestors()
        .take(PARENT_SEARCH_DEPTH + 1)
        .map(|dir| dir.join("profiles"))
        .find(|dir| dir.is_dir())
}

/// The profiles of `dir` that load, knowing the names of those that do not, and every
/// problem: for checking everything else at once.
pub(crate) fn load_catalog_partial(dir: &Path) -> (Catalog, Problems) {
    let (profiles, unreadable, problems) = load::load_dir_partial(dir);
    let mut catalog = Catalog::new(profiles);
    catalog.unreadable = unreadable;
    (catalog, problems)
}

/// A profile from field lines, for tests.
#[cfg(test)]
pub(crate) fn test_profile(fields: &str) -> Profile {
    load_str("p.yaml", &format!("name: P\nfields:\n{fields}")).expect("profile")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profiles_dir_is_found_in_a_parent() {
        let root = std::env::temp_dir().join(format!("iogate-find-{}", std::process::id()));
        let deep = root.join("a/b/c");
        std::fs::create_dir_all(&deep).expect("mkdir");
        std::fs::create_dir_all(root.join("profiles")).expect("mkdir");
        assert_eq!(find_dir(None, &deep), Some(root.join("profiles")));
        let configured = Path::new("/somewhere/else");
        assert_eq!(
            find_dir(Some(configured), &deep),
            Some(configured.to_path_buf())
        );
        std::fs::remove_dir_all(&root).expect("cleanup");
    }

    #[test]
    fn search_stops_after_six_parents() {
        let root = std::env::temp_dir().join(format!("iogate-depth-{}", std::process::id()));
        let deep = root.join("1/2/3/4/5/6/7");
        std::fs::create_dir_all(&deep).expect("mkdir");
        std::fs::create_dir_all(root.join("profiles")).expect("mkdir");
        // root is 7 levels above `deep`: one too many.
        assert_ne!(find_dir(None, &deep), Some(root.join("profiles")));
        assert_eq!(
            find_dir(None, &root.join("1/2/3/4/5/6")),
            Some(root.join("profiles"))
        );
        std::fs::remove_dir_all(&root).expect("cleanup");
    }
}
