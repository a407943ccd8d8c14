//! The server's side of the PDUs: a master's request read (exception 01 for a function
//! iogate does not serve, 03 for a quantity out of bounds or a malformed body), and the
//! response and exception PDUs that answer it.

use super::*;

impl Request {
    /// A request PDU as a master sends it (the server side): exception 01 for a function
    /// iogate does not serve, 03 for a quantity out of bounds or a malformed body.
    pub(crate) fn parse(pdu: &[u8]) -> Result<Request, Exception> {
        let Some((&code, body)) = pdu.split_first() else {
            return Err(Exception::ILLEGAL_FUNCTION);
        };
        let function = Function::ALL
            .into_iter()
            .find(|f| f.code() == code)
            .ok_or(Exception::ILLEGAL_FUNCTION)?;
        let (address, second) = (word(body, 0)?, word(body, 2)?);
        let exact = |len: usize| match body.len() == len {
            true => Ok(()),
            false => Err(Exception::ILLEGAL_DATA_VALUE),
        };
        Ok(match function {
            Function::ReadCoils | Function::ReadDiscreteInputs => {
                exact(4)?;
                let count = within(second, MAX_READ_BITS)?;
                if function == Function::ReadCoils {
                    Request::ReadCoils { address, count }
                } else {
                    Request::ReadDiscreteInputs { address, count }
                }
            }
            Function::ReadHoldingRegisters | Function::ReadInputRegisters => {
                exact(4)?;
                let count = within(second, MAX_READ_REGISTERS)?;
                if function == Function::ReadHoldingRegisters {
                    Request::ReadHoldingRegisters { address, count }
                } else {
                    Request::ReadInputRegisters { address, count }
                }
            }
            Function::WriteSingleCoil => {
                exact(4)?;
                let value = match second {
                    0xFF00 => true,
                    0x0000 => false,
                    _ => return Err(Exception::ILLEGAL_DATA_VALUE),
                };
                Request::WriteSingleCoil { address, value }
            }
            Function::WriteSingleRegister => {
                exact(4)?;
                Request::WriteSingleRegister {
                    address,
                    value: second,
                }
            }
            Function::WriteMultipleCoils => {
                let count = within(second, MAX_WRITE_BITS)?;
                let values = written(body, usize::from(count).div_ceil(8))?;
                Request::WriteMultipleCoils {
                    address,
                    values: unpack_bits(values, usize::from(count)),
                }
            }
            Function::WriteMultipleRegisters => {
                let count = within(second, MAX_WRITE_REGISTERS)?;
                let values = written(body, usize::from(count) * 2)?;
                Request::WriteMultipleRegisters {
                    address,
                    values: values
                        .chunks_exact(2)
                        .map(|p| u16::from_be_bytes([p[0], p[1]]))
                        .collect(),
                }
            }
        })
    }
}

impl Response {
    /// The response PDU answering `request` (the server side).
    pub(crate) fn to_pdu(&self, request: &Request) -> Vec<u8> {
        let mut out = Vec::new();
        self.write_pdu(request, &mut out);
        out
    }

    /// Appends the response PDU answering `request` to `out` (a frame being built).
    pub(crate) fn write_pdu(&self, request: &Request, out: &mut Vec<u8>) {
        match self {
            Response::Bits(bits) => {
                let packed = pack_bits(bits);
                out.reserve(2 + packed.len());
                out.push(request.function().code());
                out.push(packed.len() as u8);
                out.extend_from_slice(&packed);
            }
            Response::Registers(regs) => {
                out.reserve(2 + 2 * regs.len());
                out.push(request.function().code());
                out.push((regs.len() * 2) as u8);
                for r in regs {
                    out.extend_from_slice(&r.to_be_bytes());
                }
            }
            Response::Written => {
                // The echo: function, address and quantity or value.
                let start = out.len();
                request.encode(out);
                out.truncate(start + 5);
            }
        }
    }
}

impl Exception {
    pub(crate) const SERVER_DEVICE_FAILURE: Exception = Exception(4);
    pub(crate) const GATEWAY_PATH_UNAVAILABLE: Exception = Exception(0x0A);
    pub(crate) const GATEWAY_TARGET_FAILED: Exception = Exception(0x0B);

    /// The exception response PDU to a request of function `code`.
    pub(crate) fn to_pdu(self, code: u8) -> Vec<u8> {
        vec![code | 0x80, self.0]
    }
}

/// The big-endian word at `i`.
fn word(body: &[u8], i: usize) -> Result<u16, Exception> {
    body.get(i..i + 2)
        .map(|b| u16::from_be_bytes([b[0], b[1]]))
        .ok_or(Exception::ILLEGAL_DATA_VALUE)
}

/// A quantity from 1 to `max`.
fn within(n: u16, max: u16) -> Result<u16, Exception> {
    match (1..=max).contains(&n) {
        true => Ok(n),
        false => Err(Exception::ILLEGAL_DATA_VALUE),
    }
}

/// The values of a multiple write: its byte count says `bytes`, and that many follow, no
/// more.
fn written(body: &[u8], bytes: usize) -> Result<&[u8], Exception> {
    if body.get(4).map(|&b| usize::from(b)) != Some(bytes) || body.len() != 5 + bytes {
        return Err(Exception::ILLEGAL_DATA_VALUE);
    }
    Ok(&body[5..])
}
