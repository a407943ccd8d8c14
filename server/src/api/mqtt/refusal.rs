//! How the MQTT front-end says no, in one table: every refusal has its kind (the service's
//! refusal kinds) and a stable code. A refused `/set` is answered on `/set/result` with the
//! code and message (`{"device", "field", "error": {"code", "message"}}`); a refused
//! Sparkplug command has no answer topic, so it is counted and logged with its kind and
//! code.

use crate::cache::{AccessError, Refusal};
use crate::service::ServiceError;

/// A write refused, as this front-end says it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Refused {
    pub(crate) kind: Refusal,
    /// The stable code (the REST API's for the same refusal).
    pub(crate) code: &'static str,
    pub(crate) message: String,
}

impl Refused {
    /// Writes are not this front-end's role (`mqtt.writes` is off).
    pub(crate) fn not_enabled() -> Refused {
        Refused {
            kind: Refusal::Forbidden,
            code: "forbidden",
            message: "writes over MQTT are not enabled (mqtt.writes)".to_owned(),
        }
    }

    /// A payload that is not what its topic takes (JSON for `/set`, a Sparkplug payload for
    /// DCMD), or a metric with nothing to write.
    pub(crate) fn invalid_body(message: impl Into<String>) -> Refused {
        Refused {
            kind: Refusal::Invalid,
            code: "invalid_body",
            message: message.into(),
        }
    }

    /// A Sparkplug metric whose alias names no field of the device.
    pub(crate) fn unknown_alias(alias: u64) -> Refused {
        Refused {
            kind: Refusal::NotFound,
            code: "unknown_field",
            message: format!("no field has alias {alias}"),
        }
    }

    /// An NCMD metric the node does not take.
    pub(crate) fn unknown_metric(name: &str) -> Refused {
        Refused {
            kind: Refusal::NotFound,
            code: "unknown_field",
            message: format!(
                "the node has no writable metric `{}`",
                crate::text::quote(name)
            ),
        }
    }

    /// The kind's name, as logs say it.
    pub(crate) fn kind_name(&self) -> &'static str {
        match self.kind {
            Refusal::Invalid => "invalid",
            Refusal::NotFound => "not_found",
            Refusal::Conflict => "conflict",
            Refusal::Forbidden => "forbidden",
            Refusal::Gone => "gone",
            Refusal::Unavailable => "unavailable",
            Refusal::TooMany => "too_many",
            Refusal::Busy => "busy",
        }
    }
}

impl From<ServiceError> for Refused {
    fn from(e: ServiceError) -> Refused {
        let (kind, code) = e.refusal();
        Refused {
            kind,
            code,
            message: e.to_string(),
        }
    }
}

impl From<AccessError> for Refused {
    fn from(e: AccessError) -> Refused {
        Refused::from(ServiceError::from(e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_keeps_the_services_kind_and_code() {
        let refused = Refused::from(AccessError::UnknownDevice("pump".into()));
        assert_eq!(refused.kind, Refusal::NotFound);
        assert_eq!(refused.code, "unknown_device");
        assert!(refused.message.contains("pump"), "{}", refused.message);
        let busy = Refused::from(ServiceError::Busy("rs485".into()));
        assert_eq!((busy.kind_name(), busy.code), ("busy", "busy"));
        assert_eq!(Refused::not_enabled().kind, Refusal::Forbidden);
    }
}
