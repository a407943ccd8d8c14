//! The function-block layout a runtime generates for a profile (seed 000, "Generated FB
//! layout"): link binding, Modbus parameters, diagnostics, then the profile's fields.

use super::{Profile, Protocol};
use crate::codec::IecType;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LayoutSection {
    VarInput,
    Var,
}

impl LayoutSection {
    pub fn name(self) -> &'static str {
        match self {
            LayoutSection::VarInput => "VAR_INPUT",
            LayoutSection::Var => "VAR",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LayoutEntry {
    pub name: String,
    pub ty: IecType,
    pub section: LayoutSection,
    /// `link`, `parameter`, `diagnostic` or `field`.
    pub role: &'static str,
    pub description: String,
}

fn entry(
    name: &str,
    ty: IecType,
    section: LayoutSection,
    role: &'static str,
    description: &str,
) -> LayoutEntry {
    LayoutEntry {
        name: name.to_owned(),
        ty,
        section,
        role,
        description: description.to_owned(),
    }
}

/// The FB members of `profile`, in order. Simulated profiles have no link and no slave id.
pub fn fb_layout(profile: &Profile) -> Vec<LayoutEntry> {
    use LayoutSection::{Var, VarInput};
    let mut out = Vec::with_capacity(profile.fields.len() + 7);
    if profile.protocol != Protocol::Simulated {
        out.push(entry(
            "link",
            IecType::String,
            VarInput,
            "link",
            "serial port path from a SerialLink instance (e.g. serial.port)",
        ));
        out.push(entry(
            "slave_id",
            IecType::Int,
            VarInput,
            "parameter",
            "Modbus slave address (1-247)",
        ));
    }
    out.push(entry(
        "refresh_rate",
        IecType::Time,
        VarInput,
        "parameter",
        "how often to poll the device (e.g. T#50ms)",
    ));
    out.push(entry(
        "connected",
        IecType::Bool,
        Var,
        "diagnostic",
        "TRUE if the device is responding",
    ));
    out.push(entry(
        "error_code",
        IecType::Int,
        Var,
        "diagnostic",
        "0 = OK, 1 = no link, 2 = no slave, 10 = communication error",
    ));
    out.push(entry(
        "io_cycles",
        IecType::Udint,
        Var,
        "diagnostic",
        "number of successful I/O cycles",
    ));
    out.push(entry(
        "last_response_ms",
        IecType::Real,
        Var,
        "diagnostic",
        "last round-trip time in milliseconds",
    ));
    for f in &profile.fields {
        let description = f.description.clone().unwrap_or_else(|| {
            format!(
                "{} {} {}{}",
                f.direction.name(),
                f.register.kind.name(),
                f.register.address,
                f.register
                    .unit
                    .as_deref()
                    .map(|u| format!(" [{u}]"))
                    .unwrap_or_default()
            )
        });
        out.push(LayoutEntry {
            name: f.name.clone(),
            ty: f.ty,
            section: Var,
            role: "field",
            description,
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::load_str;

    #[test]
    fn modbus_layout_follows_the_seed_order() {
        let p = load_str(
            "w.yaml",
            "name: W\nfields:\n  - { name: AI1, type: INT, direction: input, register: { address: 0, kind: input_register } }\n",
        )
        .expect("loads");
        let names: Vec<_> = fb_layout(&p).into_iter().map(|e| e.name).collect();
        assert_eq!(
            names,
            [
                "link",
                "slave_id",
                "refresh_rate",
                "connected",
                "error_code",
                "io_cycles",
                "last_response_ms",
                "AI1"
            ]
        );
    }

    #[test]
    fn simulated_layout_has_no_link() {
        let p = load_str(
            "s.yaml",
            "name: S\nprotocol: simulated\nfields:\n  - { name: DI_0, type: BOOL, direction: input, register: { address: 0, kind: virtual } }\n",
        )
        .expect("loads");
        let layout = fb_layout(&p);
        assert_eq!(layout[0].name, "refresh_rate");
        assert_eq!(layout[0].section, LayoutSection::VarInput);
        assert_eq!(layout.last().map(|e| e.name.as_str()), Some("DI_0"));
    }
}
