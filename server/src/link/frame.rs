//! Modbus PDUs: requests for the eight functions iogate uses, and strict parsing of the
//! answers. A response is accepted only if its function, length, byte count and echo match
//! the request exactly; anything else is an error value, never a panic.

use std::fmt;

/// The functions iogate issues.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Function {
    ReadCoils = 0x01,
    ReadDiscreteInputs = 0x02,
    ReadHoldingRegisters = 0x03,
    ReadInputRegisters = 0x04,
    WriteSingleCoil = 0x05,
    WriteSingleRegister = 0x06,
    WriteMultipleCoils = 0x0F,
    WriteMultipleRegisters = 0x10,
}

impl Function {
    pub(crate) const ALL: [Function; 8] = [
        Function::ReadCoils,
        Function::ReadDiscreteInputs,
        Function::ReadHoldingRegisters,
        Function::ReadInputRegisters,
        Function::WriteSingleCoil,
        Function::WriteSingleRegister,
        Function::WriteMultipleCoils,
        Function::WriteMultipleRegisters,
    ];

    pub(crate) fn code(self) -> u8 {
        self as u8
    }

    /// A short label for logs and metrics, e.g. `fc03`.
    pub(crate) fn label(self) -> &'static str {
        match self {
            Function::ReadCoils => "fc01",
            Function::ReadDiscreteInputs => "fc02",
            Function::ReadHoldingRegisters => "fc03",
            Function::ReadInputRegisters => "fc04",
            Function::WriteSingleCoil => "fc05",
            Function::WriteSingleRegister => "fc06",
            Function::WriteMultipleCoils => "fc15",
            Function::WriteMultipleRegisters => "fc16",
        }
    }
}

impl fmt::Display for Function {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "FC{:02}", self.code())
    }
}

/// Modbus limits per transaction.
pub(crate) const MAX_READ_BITS: u16 = 2000;
pub(crate) const MAX_READ_REGISTERS: u16 = 125;
pub(crate) const MAX_WRITE_BITS: u16 = 1968;
pub(crate) const MAX_WRITE_REGISTERS: u16 = 123;

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Request {
    ReadCoils { address: u16, count: u16 },
    ReadDiscreteInputs { address: u16, count: u16 },
    ReadHoldingRegisters { address: u16, count: u16 },
    ReadInputRegisters { address: u16, count: u16 },
    WriteSingleCoil { address: u16, value: bool },
    WriteSingleRegister { address: u16, value: u16 },
    WriteMultipleCoils { address: u16, values: Vec<bool> },
    WriteMultipleRegisters { address: u16, values: Vec<u16> },
}

impl Request {
    /// Whether the request changes the device (functions 05, 06, 15, 16).
    pub(crate) fn is_write(&self) -> bool {
        matches!(
            self,
            Request::WriteSingleCoil { .. }
                | Request::WriteSingleRegister { .. }
                | Request::WriteMultipleCoils { .. }
                | Request::WriteMultipleRegisters { .. }
        )
    }
}

/// The data of a good response.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Response {
    Bits(Vec<bool>),
    Registers(Vec<u16>),
    Written,
}

/// A Modbus exception code sent by the device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Exception(pub u8);

impl Exception {
    pub(crate) const ILLEGAL_FUNCTION: Exception = Exception(1);
    pub(crate) const ILLEGAL_DATA_ADDRESS: Exception = Exception(2);
    pub(crate) const ILLEGAL_DATA_VALUE: Exception = Exception(3);
    pub(crate) const ACKNOWLEDGE: Exception = Exception(5);
    pub(crate) const SERVER_DEVICE_BUSY: Exception = Exception(6);

    pub(crate) fn describe(self) -> &'static str {
        match self.0 {
            1 => "illegal function",
            2 => "illegal data address",
            3 => "illegal data value",
            4 => "server device failure",
            5 => "acknowledge",
            6 => "server device busy",
            8 => "memory parity error",
            10 => "gateway path unavailable",
            11 => "gateway target device failed to respond",
            _ => "unknown exception",
        }
    }
}

impl fmt::Display for Exception {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "exception {:02} ({})", self.0, self.describe())
    }
}

/// What is wrong with a response that is not the answer its request calls for.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Malformed {
    #[error("empty PDU")]
    EmptyPdu,
    #[error("exception response of {0} bytes")]
    ExceptionLength(usize),
    #[error("function {found:#04x} in the answer to {asked}")]
    Function { found: u8, asked: Function },
    #[error("{function} answer of {len} bytes, expected {expected}")]
    Length {
        function: Function,
        len: usize,
        expected: usize,
    },
    #[error("byte count {found}, expected {expected}")]
    ByteCount { found: usize, expected: usize },
    #[error("{function} echo {echo:02x?} does not match the request {request:02x?}")]
    Echo {
        function: Function,
        echo: Vec<u8>,
        request: Vec<u8>,
    },
    #[error("answer from slave {found}, expected {expected}")]
    Slave { found: u8, expected: u8 },
    #[error("answer from unit {found}, expected {expected}")]
    Unit { found: u8, expected: u8 },
    #[error("{function} answered with {response:?}")]
    Unexpected {
        function: Function,
        response: Response,
    },
    #[error("a scan's probe needs RTU frames; this link speaks MBAP or ASCII")]
    NotRtu,
    #[error("ASCII frame: {0}")]
    Ascii(super::ascii::AsciiError),
}

/// Why a response was not accepted.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub(crate) enum ResponseError {
    #[error("the device answered with {0}")]
    Exception(Exception),
    #[error("invalid response: {0}")]
    Invalid(Malformed),
}

impl Request {
    pub(crate) fn function(&self) -> Function {
        match self {
            Request::ReadCoils { .. } => Function::ReadCoils,
            Request::ReadDiscreteInputs { .. } => Function::ReadDiscreteInputs,
            Request::ReadHoldingRegisters { .. } => Function::ReadHoldingRegisters,
            Request::ReadInputRegisters { .. } => Function::ReadInputRegisters,
            Request::WriteSingleCoil { .. } => Function::WriteSingleCoil,
            Request::WriteSingleRegister { .. } => Function::WriteSingleRegister,
            Request::WriteMultipleCoils { .. } => Function::WriteMultipleCoils,
            Request::WriteMultipleRegisters { .. } => Function::WriteMultipleRegisters,
        }
    }

    pub(crate) fn address(&self) -> u16 {
        match *self {
            Request::ReadCoils { address, .. }
            | Request::ReadDiscreteInputs { address, .. }
            | Request::ReadHoldingRegisters { address, .. }
            | Request::ReadInputRegisters { address, .. }
            | Request::WriteSingleCoil { address, .. }
            | Request::WriteSingleRegister { address, .. }
            | Request::WriteMultipleCoils { address, .. }
            | Request::WriteMultipleRegisters { address, .. } => address,
        }
    }

    pub(crate) fn is_read(&self) -> bool {
        matches!(
            self,
            Request::ReadCoils { .. }
                | Request::ReadDiscreteInputs { .. }
                | Request::ReadHoldingRegisters { .. }
                | Request::ReadInputRegisters { .. }
        )
    }

    /// Items (bits or registers) the request covers.
    pub(crate) fn count(&self) -> u16 {
        match self {
            Request::ReadCoils { count, .. }
            | Request::ReadDiscreteInputs { count, .. }
            | Request::ReadHoldingRegisters { count, .. }
            | Request::ReadInputRegisters { count, .. } => *count,
            Request::WriteSingleCoil { .. } | Request::WriteSingleRegister { .. } => 1,
            Request::WriteMultipleCoils { values, .. } => values.len() as u16,
            Request::WriteMultipleRegisters { values, .. } => values.len() as u16,
        }
    }

    /// The PDU: function code and data.
    pub(crate) fn encode(&self, out: &mut Vec<u8>) {
        out.push(self.function().code());
        out.extend_from_slice(&self.address().to_be_bytes());
        match self {
            Request::ReadCoils { count, .. }
            | Request::ReadDiscreteInputs { count, .. }
            | Request::ReadHoldingRegisters { count, .. }
            | Request::ReadInputRegisters { count, .. } => {
                out.extend_from_slice(&count.to_be_bytes());
            }
            Request::WriteSingleCoil { value, .. } => {
                out.extend_from_slice(if *value { &[0xFF, 0x00] } else { &[0x00, 0x00] });
            }
            Request::WriteSingleRegister { value, .. } => {
                out.extend_from_slice(&value.to_be_bytes());
            }
            Request::WriteMultipleCoils { values, .. } => {
                out.extend_from_slice(&(values.len() as u16).to_be_bytes());
                let packed = pack_bits(values);
                out.push(packed.len() as u8);
                out.extend_from_slice(&packed);
            }
            Request::WriteMultipleRegisters { values, .. } => {
                out.extend_from_slice(&(values.len() as u16).to_be_bytes());
                out.push((values.len() * 2) as u8);
                for v in values {
                    out.extend_from_slice(&v.to_be_bytes());
                }
            }
        }
    }

    /// The length of a good response PDU (function code included).
    pub(crate) fn response_len(&self) -> usize {
        match self {
            Request::ReadCoils { count, .. } | Request::ReadDiscreteInputs { count, .. } => {
                2 + usize::from(*count).div_ceil(8)
            }
            Request::ReadHoldingRegisters { count, .. }
            | Request::ReadInputRegisters { count, .. } => 2 + 2 * usize::from(*count),
            _ => 5,
        }
    }

    /// Parses a response PDU to this request.
    pub(crate) fn parse_response(&self, pdu: &[u8]) -> Result<Response, ResponseError> {
        let invalid = |m: Malformed| Err(ResponseError::Invalid(m));
        let Some(&code) = pdu.first() else {
            return invalid(Malformed::EmptyPdu);
        };
        let fc = self.function().code();
        if code == fc | 0x80 {
            return match pdu {
                [_, exception] => Err(ResponseError::Exception(Exception(*exception))),
                _ => invalid(Malformed::ExceptionLength(pdu.len())),
            };
        }
        if code != fc {
            return invalid(Malformed::Function {
                found: code,
                asked: self.function(),
            });
        }
        if pdu.len() != self.response_len() {
            return invalid(Malformed::Length {
                function: self.function(),
                len: pdu.len(),
                expected: self.response_len(),
            });
        }
        match self {
            Request::ReadCoils { count, .. } | Request::ReadDiscreteInputs { count, .. } => {
                let bytes = usize::from(pdu[1]);
                if bytes != pdu.len() - 2 {
                    return invalid(Malformed::ByteCount {
                        found: bytes,
                        expected: pdu.len() - 2,
                    });
                }
                Ok(Response::Bits(unpack_bits(&pdu[2..], usize::from(*count))))
            }
            Request::ReadHoldingRegisters { .. } | Request::ReadInputRegisters { .. } => {
                let bytes = usize::from(pdu[1]);
                if bytes != pdu.len() - 2 {
                    return invalid(Malformed::ByteCount {
                        found: bytes,
                        expected: pdu.len() - 2,
                    });
                }
                Ok(Response::Registers(
                    pdu[2..]
                        .chunks_exact(2)
                        .map(|p| u16::from_be_bytes([p[0], p[1]]))
                        .collect(),
                ))
            }
            _ => {
                // Writes echo the address and the value (single) or the quantity (multiple).
                let mut expected = Vec::with_capacity(5);
                self.encode(&mut expected);
                expected.truncate(5);
                if pdu != expected.as_slice() {
                    return invalid(Malformed::Echo {
                        function: self.function(),
                        echo: pdu.to_vec(),
                        request: expected,
                    });
                }
                Ok(Response::Written)
            }
        }
    }
}

pub(crate) fn pack_bits(bits: &[bool]) -> Vec<u8> {
    let mut out = vec![0u8; bits.len().div_ceil(8)];
    for (i, &b) in bits.iter().enumerate() {
        if b {
            out[i / 8] |= 1 << (i % 8);
        }
    }
    out
}

pub(crate) fn unpack_bits(bytes: &[u8], count: usize) -> Vec<bool> {
    (0..count)
        .map(|i| bytes[i / 8] >> (i % 8) & 1 == 1)
        .collect()
}

mod server;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::rtu_frame::rtu_frame;

    #[test]
    fn write_block_example_frame_has_its_crc() {
        // Source document 002: slave 17, FC06, register 1, value 3 -> 11 06 00 01 00 03 9A 9B.
        let frame = rtu_frame(
            17,
            &Request::WriteSingleRegister {
                address: 1,
                value: 3,
            },
        );
        assert_eq!(frame, [0x11, 0x06, 0x00, 0x01, 0x00, 0x03, 0x9A, 0x9B]);
        let request = Request::WriteSingleRegister {
            address: 1,
            value: 3,
        };
        assert_eq!(request.parse_response(&frame[1..6]), Ok(Response::Written));
    }

    #[test]
    fn read_registers_parse_and_reject_wrong_lengths() {
        let request = Request::ReadHoldingRegisters {
            address: 0,
            count: 2,
        };
        assert_eq!(
            request.parse_response(&[0x03, 4, 0x12, 0x34, 0xAB, 0xCD]),
            Ok(Response::Registers(vec![0x1234, 0xABCD]))
        );
        assert!(matches!(
            request.parse_response(&[0x03, 2, 0x12, 0x34]),
            Err(ResponseError::Invalid(_))
        ));
        assert!(matches!(
            request.parse_response(&[0x03, 6, 0x12, 0x34, 0xAB, 0xCD]),
            Err(ResponseError::Invalid(_))
        ));
        assert!(matches!(
            request.parse_response(&[0x04, 4, 0, 0, 0, 0]),
            Err(ResponseError::Invalid(_))
        ));
        assert_eq!(
            request.parse_response(&[0x83, 0x02]),
            Err(ResponseError::Exception(Exception::ILLEGAL_DATA_ADDRESS))
        );
        assert!(request.parse_response(&[]).is_err());
    }

    #[test]
    fn coils_pack_lsb_first() {
        let bits = [true, false, true, true, false, false, false, false, true];
        assert_eq!(pack_bits(&bits), vec![0b0000_1101, 0b0000_0001]);
        assert_eq!(unpack_bits(&pack_bits(&bits), bits.len()), bits);
        let request = Request::ReadCoils {
            address: 0,
            count: 9,
        };
        assert_eq!(
            request.parse_response(&[0x01, 2, 0b0000_1101, 1]),
            Ok(Response::Bits(bits.to_vec()))
        );
    }

    #[test]
    fn write_echo_must_match() {
        let request = Request::WriteMultipleRegisters {
            address: 10,
            values: vec![1, 2, 3],
        };
        assert_eq!(
            request.parse_response(&[0x10, 0, 10, 0, 3]),
            Ok(Response::Written)
        );
        assert!(request.parse_response(&[0x10, 0, 10, 0, 2]).is_err());
        assert!(request.parse_response(&[0x10, 0, 11, 0, 3]).is_err());
        let coil = Request::WriteSingleCoil {
            address: 3,
            value: true,
        };
        assert_eq!(
            coil.parse_response(&[0x05, 0, 3, 0xFF, 0]),
            Ok(Response::Written)
        );
        assert!(coil.parse_response(&[0x05, 0, 3, 0, 0]).is_err());
    }

    proptest::proptest! {
        #[test]
        fn any_bytes_parse_without_panic(bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..300), fc in 0usize..8, count in 1u16..200) {
            let request = match fc {
                0 => Request::ReadCoils { address: 0, count },
                1 => Request::ReadDiscreteInputs { address: 0, count },
                2 => Request::ReadHoldingRegisters { address: 0, count: count.min(125) },
                3 => Request::ReadInputRegisters { address: 0, count: count.min(125) },
                4 => Request::WriteSingleCoil { address: 0, value: true },
                5 => Request::WriteSingleRegister { address: 0, value: count },
                6 => Request::WriteMultipleCoils { address: 0, values: vec![true; usize::from(count)] },
                _ => Request::WriteMultipleRegisters { address: 0, values: vec![1; usize::from(count.min(123))] },
            };
            let _ = request.parse_response(&bytes);
        }

        // The Modbus server's request parser. A long run:
        // `PROPTEST_CASES=1000000 cargo test --release -p iogate --lib request_pdus`.
        #[test]
        fn request_pdus_parse_or_are_refused_and_round_trip(
            code in proptest::sample::select(vec![1u8, 2, 3, 4, 5, 6, 15, 16, 0, 7, 0x2B, 0x80, 0xFF]),
            body in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..260),
        ) {
            let mut pdu = vec![code];
            pdu.extend_from_slice(&body);
            if let Ok(request) = Request::parse(&pdu) {
                let mut again = Vec::new();
                request.encode(&mut again);
                proptest::prop_assert_eq!(Request::parse(&again), Ok(request));
            }
        }
    }
}
