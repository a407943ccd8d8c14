//! Profiles as JSON: the list, one profile's fields and registers, its function block.

use super::*;

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct ProfileSummary {
    pub(crate) name: String,
    pub(crate) vendor: Option<String>,
    pub(crate) protocol: String,
    pub(crate) description: Option<String>,
    pub(crate) field_count: usize,
    pub(crate) source: String,
}

pub(crate) fn profile_summary(p: &Profile) -> ProfileSummary {
    ProfileSummary {
        name: p.name.clone(),
        vendor: p.vendor.clone(),
        protocol: p.protocol.name().to_owned(),
        description: p.description.clone(),
        field_count: p.fields.len(),
        source: p.source.clone(),
    }
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct ProfileList {
    pub(crate) profiles: Vec<ProfileSummary>,
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct RegisterInfo {
    pub(crate) address: u16,
    pub(crate) kind: String,
    pub(crate) bit: Option<u8>,
    pub(crate) scale: f64,
    pub(crate) offset: f64,
    pub(crate) unit: Option<String>,
    pub(crate) byte_order: String,
    pub(crate) word_count: u16,
    pub(crate) raw_type: Option<String>,
    /// A BOOL switch's raw value for TRUE, where not the plain one (0 on an inverted coil).
    pub(crate) on_value: Option<u16>,
    /// A BOOL switch's raw value for FALSE, where not the plain one.
    pub(crate) off_value: Option<u16>,
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct FieldInfo {
    pub(crate) name: String,
    #[serde(rename = "type")]
    pub(crate) ty: String,
    pub(crate) direction: String,
    /// Where a Modbus field is (for a field of another protocol: kind `point`, its unit).
    pub(crate) register: RegisterInfo,
    /// The node id of a field of an OPC UA profile, as the profile writes it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) node: Option<String>,
    /// The browse path of a field of an OPC UA profile, where it names one instead.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) browse_path: Option<String>,
    pub(crate) description: Option<String>,
}

/// One member of the generated function block.
#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct LayoutInfo {
    pub(crate) name: String,
    #[serde(rename = "type")]
    pub(crate) ty: String,
    /// `VAR_INPUT` or `VAR`.
    pub(crate) section: String,
    /// `link`, `parameter`, `diagnostic` or `field`.
    pub(crate) role: String,
    pub(crate) description: String,
}

impl From<LayoutEntry> for LayoutInfo {
    fn from(e: LayoutEntry) -> Self {
        LayoutInfo {
            name: e.name,
            ty: e.ty.name().to_owned(),
            section: e.section.name().to_owned(),
            role: e.role.to_owned(),
            description: e.description,
        }
    }
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct ProfileDetail {
    #[serde(flatten)]
    pub(crate) summary: ProfileSummary,
    pub(crate) fields: Vec<FieldInfo>,
    /// The generated function block's members, in order.
    pub(crate) layout: Vec<LayoutInfo>,
}

pub(crate) fn profile_detail(p: &Profile) -> ProfileDetail {
    ProfileDetail {
        summary: profile_summary(p),
        fields: p
            .fields
            .iter()
            .map(|f| FieldInfo {
                name: f.name.clone(),
                ty: f.ty.name().to_owned(),
                direction: f.direction.name().to_owned(),
                description: f.description.clone(),
                node: f
                    .point
                    .as_ref()
                    .filter(|p| !p.browse_path)
                    .map(|p| p.address.clone()),
                browse_path: f
                    .point
                    .as_ref()
                    .filter(|p| p.browse_path)
                    .map(|p| p.address.clone()),
                register: RegisterInfo {
                    address: f.register.address,
                    kind: f.register.kind.name().to_owned(),
                    bit: f.register.bit,
                    scale: f.register.scale,
                    offset: f.register.offset,
                    unit: f.register.unit.clone(),
                    byte_order: f.register.byte_order.name().to_owned(),
                    word_count: f.register.word_count,
                    raw_type: f.register.raw_type.map(|t| t.name().to_owned()),
                    on_value: f.register.switch.map(|s| s.on),
                    off_value: f.register.switch.map(|s| s.off),
                },
            })
            .collect(),
        layout: fb_layout(p).into_iter().map(LayoutInfo::from).collect(),
    }
}
