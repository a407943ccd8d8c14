//! Links as JSON, with their diagnostics.

use super::*;

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct LinkInfo {
    pub(crate) name: String,
    /// `serial`, `tcp`, or the protocol of a link of another field protocol (`opcua`).
    pub(crate) kind: String,
    /// Where a link of another field protocol goes (an OPC UA endpoint URL).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) endpoint: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) port: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) baud: Option<u32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) parity: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) data_bits: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) stop_bits: Option<u8>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) host: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) tcp_port: Option<u16>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) framing: Option<String>,
    pub(crate) connected: bool,
    /// 0 OK, 1 no port configured, 2 open failed, 3 port lost.
    pub(crate) error_code: i16,
    /// Why the link is down, in words (the last failure to open it, or how it was lost).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) error: Option<String>,
    pub(crate) devices: Vec<String>,
    /// The share of the line's time the devices' refresh rates demand (serial links; above
    /// 1 they cannot all be kept).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) planned_utilisation: Option<f64>,
    /// The share of time the line was busy over the last measuring window (about a
    /// second); absent before the first window ends.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) utilisation: Option<f64>,
    /// What the gateway learned of the device at the other end of a link of another field
    /// protocol (an S7 PLC's `order_number`, `module`, `serial_number`, `pdu_size`,
    /// `cpu_state`).
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    pub(crate) peer: std::collections::BTreeMap<String, String>,
}

pub(crate) fn link_info(link: &Link) -> LinkInfo {
    let diag = link.diagnostics();
    let devices = link.members().iter().map(|d| d.name().to_owned()).collect();
    let (planned_utilisation, utilisation) = link.utilisation.get();
    let mut info = LinkInfo {
        planned_utilisation,
        utilisation,
        name: link.name().to_owned(),
        kind: String::new(),
        endpoint: None,
        port: None,
        baud: None,
        parity: None,
        data_bits: None,
        stop_bits: None,
        host: None,
        tcp_port: None,
        framing: None,
        connected: diag.connected,
        error_code: diag.error_code.code(),
        error: link.down().filter(|_| !diag.connected),
        devices,
        peer: link
            .peer()
            .into_iter()
            .map(|(k, v)| (k.to_owned(), v))
            .collect(),
    };
    match link.config().transport {
        Transport::Serial(s) => {
            info.kind = "serial".into();
            info.port = Some(s.port);
            info.baud = Some(s.baud);
            info.parity = Some(s.parity.letter().to_string());
            info.data_bits = Some(s.data_bits);
            info.stop_bits = Some(s.stop_bits);
            info.framing = Some(s.framing.name().into());
        }
        Transport::Tcp {
            host,
            port,
            framing,
        } => {
            info.kind = "tcp".into();
            info.host = Some(host);
            info.tcp_port = Some(port);
            info.framing = Some(framing.name().into());
        }
        Transport::Driver(d) => {
            info.kind = d.protocol.into();
            info.endpoint = Some(d.endpoint);
        }
    }
    info
}

#[derive(Debug, Serialize, ToSchema)]
pub(crate) struct LinkList {
    pub(crate) links: Vec<LinkInfo>,
}
