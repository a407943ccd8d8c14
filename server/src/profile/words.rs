//! The words each field protocol besides Modbus uses in configuration: its profiles'
//! `protocol`, its fields' point key and how a point is checked, its links' settings key.
//! Each driver says its own (`Driver::WORDS`, in its folder); configuration is read below
//! the drivers, so they are made known to it once, before anything is read
//! (`crate::drivers::register`, which calls [`know`]).

use std::sync::OnceLock;

use crate::codec::IecType;

/// The words configuration uses for a field protocol besides Modbus: its profiles'
/// `protocol`, its fields' point key, its links' settings key and the key in them that
/// says where the link goes.
#[derive(Debug)]
pub struct Words {
    pub(crate) protocol: &'static str,
    /// The key a field names its point by (`node`), and another it may use instead.
    pub(crate) point_key: &'static str,
    pub(crate) point_alternative: Option<&'static str>,
    pub(crate) link_key: &'static str,
    pub(crate) link_at: &'static str,
    /// Checks a point as written under `key` (one of the two point keys) for a field of a
    /// type (and a STRING's length): why not, if not.
    pub(crate) check_point: CheckPoint,
    /// A point as written, as one key whatever way it is written (`C3` and `Z3`, German
    /// for it, are one counter): two fields with one key name the same point.
    pub(crate) point_identity: fn(&super::Point) -> String,
    /// A STRING field's most characters when the profile does not say (`length`).
    pub(crate) default_length: u16,
    /// A point as a profile writes it, for messages.
    pub(crate) example: &'static str,
    /// Whether its fields may be scaled (`scale`, `offset`, `raw_type`: the value the
    /// device stores is raw, as for Modbus).
    pub(crate) scaled: bool,
    /// Further keys a field may carry beside its point (BACnet's `property`), each with its
    /// check; kept in [`super::Point::extra`].
    pub(crate) field_keys: &'static [FieldKey],
    /// Keys a device of the protocol carries in the configuration beside the common ones
    /// (BACnet's `device_instance`), kept for its driver (`DeviceConfig::at`), which reads
    /// them.
    pub(crate) device_keys: &'static [&'static str],
}

/// A key a field of a protocol may carry beside its point, and its check for the field's
/// type: why not, if not.
#[derive(Debug)]
pub struct FieldKey {
    pub(crate) key: &'static str,
    pub(crate) check: fn(text: &str, ty: Option<IecType>) -> Result<(), String>,
}

/// Checks a point as written under a key, for a field's type and length.
pub(crate) type CheckPoint =
    fn(key: &str, text: &str, ty: Option<IecType>, length: Option<u16>) -> Result<(), String>;

/// A protocol is its word.
impl PartialEq for Words {
    fn eq(&self, other: &Words) -> bool {
        self.protocol == other.protocol
    }
}

impl Eq for Words {}

impl std::hash::Hash for Words {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.protocol.hash(state);
    }
}

/// The words of the drivers besides Modbus, as the drivers made them known.
static KNOWN: OnceLock<&'static [&'static Words]> = OnceLock::new();

/// Makes the drivers' words known to configuration (once: a second call does nothing).
pub(crate) fn know(words: &'static [&'static Words]) {
    let _ = KNOWN.set(words);
}

/// The words of the drivers besides Modbus (none before [`know`]: a profile of theirs is
/// then an unknown protocol, said so).
pub(crate) fn drivers() -> &'static [&'static Words] {
    KNOWN.get().copied().unwrap_or(&[])
}
