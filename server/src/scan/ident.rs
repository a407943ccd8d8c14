//! Modbus device identification (FC 43, MEI type 14): the request for one category of
//! objects from one object id, and its answer's objects.

use std::collections::BTreeMap;

use serde::Serialize;

/// FC 43: encapsulated interface transport.
pub(crate) const FUNCTION: u8 = 0x2B;
/// MEI type 14: read device identification.
const MEI: u8 = 0x0E;
/// Read device id codes: the basic objects (0-2) and the regular ones (3-6).
pub(crate) const BASIC: u8 = 0x01;
pub(crate) const REGULAR: u8 = 0x02;

/// The request PDU for the objects of `code` from `object`.
pub(crate) fn request(code: u8, object: u8) -> Vec<u8> {
    vec![FUNCTION, MEI, code, object]
}

/// One answer: its objects, and the object to ask for next when more follow.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Answer {
    /// The conformity level: which categories the device offers (1 basic, 2 regular,
    /// 3 extended; bit 7 for individual access).
    pub(crate) conformity: u8,
    pub(crate) next: Option<u8>,
    pub(crate) objects: Vec<(u8, Vec<u8>)>,
}

/// An answer's PDU (function code first), or what is wrong with it.
pub(crate) fn parse(pdu: &[u8]) -> Result<Answer, String> {
    let [
        function,
        mei,
        _code,
        conformity,
        more,
        next,
        count,
        rest @ ..,
    ] = pdu
    else {
        return Err(format!("{} bytes are too short for an answer", pdu.len()));
    };
    if (*function, *mei) != (FUNCTION, MEI) {
        return Err(format!(
            "function {function:#04x}/{mei:#04x}, not 0x2b/0x0e"
        ));
    }
    let mut objects = Vec::new();
    let mut at = rest;
    for _ in 0..*count {
        let [id, len, tail @ ..] = at else {
            return Err("an object runs past the end of the answer".to_owned());
        };
        let len = usize::from(*len);
        if tail.len() < len {
            return Err(format!("object {id} is longer than the answer"));
        }
        objects.push((*id, tail[..len].to_vec()));
        at = &tail[len..];
    }
    if !at.is_empty() {
        return Err(format!("{} bytes after the last object", at.len()));
    }
    Ok(Answer {
        conformity: *conformity,
        next: (*more == 0xFF).then_some(*next),
        objects,
    })
}

/// What a device says it is: the standard objects by name, any other by number.
#[derive(Debug, Clone, Default, PartialEq, Serialize, utoipa::ToSchema)]
pub struct Identification {
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vendor: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub product_code: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub revision: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vendor_url: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub product_name: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model_name: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub application_name: Option<String>,
    /// Objects beyond the standard ones, by id.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub other: BTreeMap<u8, String>,
}

impl Identification {
    /// Takes an object's value (text, with control characters and invalid UTF-8 replaced).
    pub(crate) fn add(&mut self, id: u8, value: &[u8]) {
        let text: String = String::from_utf8_lossy(value)
            .chars()
            .map(|c| if c.is_control() { '\u{FFFD}' } else { c })
            .collect();
        let text = text.trim().to_owned();
        let slot = match id {
            0 => &mut self.vendor,
            1 => &mut self.product_code,
            2 => &mut self.revision,
            3 => &mut self.vendor_url,
            4 => &mut self.product_name,
            5 => &mut self.model_name,
            6 => &mut self.application_name,
            _ => {
                self.other.insert(id, text);
                return;
            }
        };
        *slot = Some(text);
    }

    /// A stated object's value by the profile key that names it.
    pub(crate) fn get(&self, key: &str) -> Option<&str> {
        match key {
            "vendor" => self.vendor.as_deref(),
            "product_code" => self.product_code.as_deref(),
            "product_name" => self.product_name.as_deref(),
            "model_name" => self.model_name.as_deref(),
            "revision" => self.revision.as_deref(),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_answer_with_three_objects_and_more_to_come() {
        let mut pdu = vec![0x2B, 0x0E, 0x01, 0x81, 0xFF, 0x02, 0x02];
        pdu.extend_from_slice(&[0, 4, b'A', b'C', b'M', b'E']);
        pdu.extend_from_slice(&[1, 2, b'X', b'1']);
        let answer = parse(&pdu).expect("parses");
        assert_eq!(answer.next, Some(2));
        assert_eq!(answer.conformity, 0x81);
        let mut id = Identification::default();
        for (k, v) in &answer.objects {
            id.add(*k, v);
        }
        assert_eq!(id.vendor.as_deref(), Some("ACME"));
        assert_eq!(id.product_code.as_deref(), Some("X1"));
        assert_eq!(id.get("vendor"), Some("ACME"));
    }

    #[test]
    fn a_truncated_or_foreign_answer_is_named() {
        assert!(parse(&[0x2B, 0x0E]).is_err());
        let e = parse(&[0x2B, 0x0E, 1, 1, 0, 0, 1, 0, 9, b'A']).expect_err("short");
        assert!(e.contains("longer than the answer"), "{e}");
        let e = parse(&[0x03, 0x0E, 1, 1, 0, 0, 0]).expect_err("foreign");
        assert!(e.contains("not 0x2b"), "{e}");
        let e = parse(&[0x2B, 0x0E, 1, 1, 0, 0, 0, 7]).expect_err("trailing");
        assert!(e.contains("after the last object"), "{e}");
    }
}
