//! The words each field protocol besides Modbus uses in configuration: its profiles'
//! `protocol`, its fields' point key and how a point is checked, its links' settings key.

use super::{eip_tag, point, s7_form};
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
    pub(crate) point_identity: fn(&str) -> String,
    /// A STRING field's most characters when the profile does not say (`length`).
    pub(crate) default_length: u16,
    /// A point as a profile writes it, for messages.
    pub(crate) example: &'static str,
    /// Whether its fields may be scaled (`scale`, `offset`, `raw_type`: the value the
    /// device stores is raw, as for Modbus).
    pub(crate) scaled: bool,
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

/// The protocols of the drivers besides Modbus (the drivers themselves are listed in
/// `drivers::with_driver`).
pub(crate) const DRIVERS: &[Words] = &[
    Words {
        protocol: "opcua",
        point_key: "node",
        point_alternative: Some("browse_path"),
        link_key: "opcua",
        link_at: "url",
        check_point: point::check_opcua,
        point_identity: str::to_owned,
        default_length: 64,
        example: "ns=3;s=Line1.Speed",
        scaled: false,
    },
    Words {
        protocol: "s7",
        point_key: "address",
        point_alternative: None,
        link_key: "s7",
        link_at: "host",
        check_point: s7_form::check,
        point_identity: s7_form::point_identity,
        default_length: 64,
        example: "DB10.DBD6",
        scaled: true,
    },
    Words {
        protocol: "ab-eip",
        point_key: "tag",
        point_alternative: None,
        link_key: "eip",
        link_at: "host",
        check_point: eip_tag::check,
        // Logix tag names are not case-sensitive.
        point_identity: str::to_ascii_lowercase,
        // A Logix STRING holds 82 characters.
        default_length: 82,
        example: "Program:Main.Speed",
        scaled: false,
    },
];
