//! The ASDU types this gateway speaks: each type identification's name, the kind of its
//! elements and its time tag; the elements themselves (values with their quality
//! descriptors, commands with their qualifiers), as octets both ways.

use super::time::Cp56;

/// A type identification.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) struct TypeId(pub(crate) u8);

/// The kind of an information object's element.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kind {
    Single,
    Double,
    Step,
    Bits,
    Normalized,
    /// M_ME_ND_1: a normalized value with no quality descriptor.
    NormalizedBare,
    Scaled,
    Float,
    Counter,
    SingleCommand,
    DoubleCommand,
    StepCommand,
    SetNormalized,
    SetScaled,
    SetFloat,
    BitsCommand,
    EndOfInit,
    Interrogation,
    CounterInterrogation,
    Read,
    ClockSync,
    ResetProcess,
    Test,
}

/// The time tag an object of a type carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Tag {
    None,
    /// CP24Time2a.
    Short,
    /// CP56Time2a.
    Full,
}

impl Tag {
    pub(crate) fn len(self) -> usize {
        match self {
            Tag::None => 0,
            Tag::Short => 3,
            Tag::Full => 7,
        }
    }
}

/// Type identifications by name (IEC 60870-5-101 and -104).
#[allow(non_upper_case_globals, dead_code)]
pub(crate) mod id {
    pub(crate) const M_SP_NA_1: u8 = 1;
    pub(crate) const M_DP_NA_1: u8 = 3;
    pub(crate) const M_ST_NA_1: u8 = 5;
    pub(crate) const M_BO_NA_1: u8 = 7;
    pub(crate) const M_ME_NA_1: u8 = 9;
    pub(crate) const M_ME_NB_1: u8 = 11;
    pub(crate) const M_ME_NC_1: u8 = 13;
    pub(crate) const M_IT_NA_1: u8 = 15;
    pub(crate) const M_SP_TB_1: u8 = 30;
    pub(crate) const M_DP_TB_1: u8 = 31;
    pub(crate) const M_ST_TB_1: u8 = 32;
    pub(crate) const M_BO_TB_1: u8 = 33;
    pub(crate) const M_ME_TD_1: u8 = 34;
    pub(crate) const M_ME_TE_1: u8 = 35;
    pub(crate) const M_ME_TF_1: u8 = 36;
    pub(crate) const M_IT_TB_1: u8 = 37;
    pub(crate) const C_SC_NA_1: u8 = 45;
    pub(crate) const C_DC_NA_1: u8 = 46;
    pub(crate) const C_RC_NA_1: u8 = 47;
    pub(crate) const C_SE_NA_1: u8 = 48;
    pub(crate) const C_SE_NB_1: u8 = 49;
    pub(crate) const C_SE_NC_1: u8 = 50;
    pub(crate) const C_BO_NA_1: u8 = 51;
    pub(crate) const M_EI_NA_1: u8 = 70;
    pub(crate) const C_IC_NA_1: u8 = 100;
    pub(crate) const C_CI_NA_1: u8 = 101;
    pub(crate) const C_RD_NA_1: u8 = 102;
    pub(crate) const C_CS_NA_1: u8 = 103;
    pub(crate) const C_RP_NA_1: u8 = 105;
    pub(crate) const C_TS_TA_1: u8 = 107;
}

/// Every type: its identification, name, element kind and time tag.
const TYPES: &[(u8, &str, Kind, Tag)] = &[
    (1, "M_SP_NA_1", Kind::Single, Tag::None),
    (2, "M_SP_TA_1", Kind::Single, Tag::Short),
    (3, "M_DP_NA_1", Kind::Double, Tag::None),
    (4, "M_DP_TA_1", Kind::Double, Tag::Short),
    (5, "M_ST_NA_1", Kind::Step, Tag::None),
    (6, "M_ST_TA_1", Kind::Step, Tag::Short),
    (7, "M_BO_NA_1", Kind::Bits, Tag::None),
    (8, "M_BO_TA_1", Kind::Bits, Tag::Short),
    (9, "M_ME_NA_1", Kind::Normalized, Tag::None),
    (10, "M_ME_TA_1", Kind::Normalized, Tag::Short),
    (11, "M_ME_NB_1", Kind::Scaled, Tag::None),
    (12, "M_ME_TB_1", Kind::Scaled, Tag::Short),
    (13, "M_ME_NC_1", Kind::Float, Tag::None),
    (14, "M_ME_TC_1", Kind::Float, Tag::Short),
    (15, "M_IT_NA_1", Kind::Counter, Tag::None),
    (16, "M_IT_TA_1", Kind::Counter, Tag::Short),
    (21, "M_ME_ND_1", Kind::NormalizedBare, Tag::None),
    (30, "M_SP_TB_1", Kind::Single, Tag::Full),
    (31, "M_DP_TB_1", Kind::Double, Tag::Full),
    (32, "M_ST_TB_1", Kind::Step, Tag::Full),
    (33, "M_BO_TB_1", Kind::Bits, Tag::Full),
    (34, "M_ME_TD_1", Kind::Normalized, Tag::Full),
    (35, "M_ME_TE_1", Kind::Scaled, Tag::Full),
    (36, "M_ME_TF_1", Kind::Float, Tag::Full),
    (37, "M_IT_TB_1", Kind::Counter, Tag::Full),
    (45, "C_SC_NA_1", Kind::SingleCommand, Tag::None),
    (46, "C_DC_NA_1", Kind::DoubleCommand, Tag::None),
    (47, "C_RC_NA_1", Kind::StepCommand, Tag::None),
    (48, "C_SE_NA_1", Kind::SetNormalized, Tag::None),
    (49, "C_SE_NB_1", Kind::SetScaled, Tag::None),
    (50, "C_SE_NC_1", Kind::SetFloat, Tag::None),
    (51, "C_BO_NA_1", Kind::BitsCommand, Tag::None),
    (58, "C_SC_TA_1", Kind::SingleCommand, Tag::Full),
    (59, "C_DC_TA_1", Kind::DoubleCommand, Tag::Full),
    (60, "C_RC_TA_1", Kind::StepCommand, Tag::Full),
    (61, "C_SE_TA_1", Kind::SetNormalized, Tag::Full),
    (62, "C_SE_TB_1", Kind::SetScaled, Tag::Full),
    (63, "C_SE_TC_1", Kind::SetFloat, Tag::Full),
    (64, "C_BO_TA_1", Kind::BitsCommand, Tag::Full),
    (70, "M_EI_NA_1", Kind::EndOfInit, Tag::None),
    (100, "C_IC_NA_1", Kind::Interrogation, Tag::None),
    (101, "C_CI_NA_1", Kind::CounterInterrogation, Tag::None),
    (102, "C_RD_NA_1", Kind::Read, Tag::None),
    (103, "C_CS_NA_1", Kind::ClockSync, Tag::None),
    (105, "C_RP_NA_1", Kind::ResetProcess, Tag::None),
    (107, "C_TS_TA_1", Kind::Test, Tag::Full),
];

impl TypeId {
    fn entry(self) -> Option<&'static (u8, &'static str, Kind, Tag)> {
        TYPES.iter().find(|t| t.0 == self.0)
    }

    pub(crate) fn kind(self) -> Option<Kind> {
        self.entry().map(|t| t.2)
    }

    pub(crate) fn tag(self) -> Tag {
        self.entry().map_or(Tag::None, |t| t.3)
    }

    /// Its name (`M_ME_NC_1`), or `type N` for one not known.
    pub(crate) fn name(self) -> &'static str {
        self.entry().map_or("an unknown type", |t| t.1)
    }

    /// The type a name names (`M_ME_NC_1`).
    pub(crate) fn named(name: &str) -> Option<TypeId> {
        TYPES.iter().find(|t| t.1 == name).map(|t| TypeId(t.0))
    }

    /// Every known type's name, for messages.
    pub(crate) fn names() -> impl Iterator<Item = &'static str> {
        TYPES.iter().map(|t| t.1)
    }
}

impl Kind {
    /// The octets of its element (the time tag apart).
    pub(crate) fn size(self) -> usize {
        match self {
            Kind::Single
            | Kind::Double
            | Kind::SingleCommand
            | Kind::DoubleCommand
            | Kind::StepCommand
            | Kind::EndOfInit
            | Kind::Interrogation
            | Kind::CounterInterrogation
            | Kind::ResetProcess => 1,
            Kind::Step | Kind::NormalizedBare | Kind::Test => 2,
            Kind::Normalized | Kind::Scaled | Kind::SetNormalized | Kind::SetScaled => 3,
            Kind::BitsCommand => 4,
            Kind::Bits | Kind::Float | Kind::Counter | Kind::SetFloat => 5,
            Kind::Read => 0,
            Kind::ClockSync => Cp56::LEN,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn types_are_found_by_name_and_number() {
        assert_eq!(TypeId::named("M_ME_NC_1"), Some(TypeId(13)));
        assert_eq!(TypeId(36).name(), "M_ME_TF_1");
        assert_eq!(TypeId(36).tag(), Tag::Full);
        assert_eq!(TypeId(2).tag(), Tag::Short);
        assert_eq!(TypeId(200).kind(), None);
    }
}
