//! A link's endpoint as a declaration gives it, turned into a transport by the config's
//! rules and defaults.

use super::DeclareError;
use crate::config::rules;
use crate::config::{Framing, Parity, SerialSettings, Transport};

/// A link's endpoint as a declaration gives it: numbers unchecked, zero or empty for "the
/// default" (8 data bits, 1 stop bit, no parity, RTU framing on a line; port 502, MBAP
/// framing over TCP).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) enum Endpoint {
    Serial {
        port: String,
        baud: u64,
        parity: String,
        data_bits: u64,
        stop_bits: u64,
        framing: String,
    },
    Tcp {
        host: String,
        port: u64,
        framing: String,
    },
}

impl Endpoint {
    /// The transport, checked by the same rules as the config file's.
    pub(crate) fn transport(&self) -> Result<Transport, DeclareError> {
        let or = |n: u64, default: u8| if n == 0 { u64::from(default) } else { n };
        match self {
            Endpoint::Serial {
                port,
                baud,
                parity,
                data_bits,
                stop_bits,
                framing,
            } => {
                let parity = match parity.as_str() {
                    "" => Ok(Parity::None),
                    text => rules::parse_parity(text),
                };
                // An empty port is a state, not a mistake, at run time: the link reports
                // `SerialLink` error 1 until it is declared again with one.
                let unset = port.trim().is_empty();
                let checked = rules::serial(
                    if unset { "-".to_owned() } else { port.clone() },
                    *baud,
                    parity,
                    or(*data_bits, rules::DEFAULT_DATA_BITS),
                    or(*stop_bits, rules::DEFAULT_STOP_BITS),
                );
                let framing = match framing.as_str() {
                    "" => Ok(Framing::Rtu),
                    text => rules::parse_serial_framing(text),
                };
                let mut settings = match (checked, framing) {
                    (Ok(settings), Ok(framing)) => SerialSettings {
                        framing,
                        ..settings
                    },
                    (Err(mut errors), framing) => {
                        errors.extend(framing.err());
                        return Err(DeclareError::Rules(errors));
                    }
                    (Ok(_), Err(e)) => return Err(DeclareError::Rules(vec![e])),
                };
                if unset {
                    settings.port = String::new();
                }
                Ok(Transport::Serial(settings))
            }
            Endpoint::Tcp {
                host,
                port,
                framing,
            } => {
                let framing = match framing.as_str() {
                    "" => Ok(Framing::Mbap),
                    text => rules::parse_framing(text),
                }
                .map_err(|e| DeclareError::Rules(vec![e]))?;
                let port = if *port == 0 {
                    u64::from(rules::DEFAULT_TCP_PORT)
                } else {
                    *port
                };
                let port = rules::tcp_endpoint(host, port).map_err(DeclareError::Rules)?;
                Ok(Transport::Tcp {
                    host: host.clone(),
                    port,
                    framing,
                })
            }
        }
    }
}
