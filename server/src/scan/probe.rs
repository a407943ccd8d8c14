//! One read of a device found, as the scan's follow-ups and profile probes make it.

use super::judge::{self, Heard};
use super::{Prober, ReadAnswer, ScanError};
use crate::profile::RegisterKind;

/// One read of `count` at `address` of `kind`; a second answer is a collision.
pub(super) async fn read(
    prober: &mut dyn Prober,
    id: u8,
    kind: RegisterKind,
    address: u16,
    count: u16,
) -> Result<(ReadAnswer, Option<String>), ScanError> {
    let pdu = read_pdu(kind, address, count);
    let heard = judge::judge(&prober.probe(id, &pdu, true).await?, id, pdu[0]);
    let two = matches!(heard, Heard::Two(_)).then(|| "two answers to one request".to_owned());
    Ok((judge::read_answer(kind, address, count, &heard), two))
}

/// The request PDU of a read.
pub(super) fn read_pdu(kind: RegisterKind, address: u16, count: u16) -> Vec<u8> {
    let mut pdu = Vec::with_capacity(5);
    crate::drivers::modbus::read_request(kind, address, count).encode(&mut pdu);
    pdu
}
