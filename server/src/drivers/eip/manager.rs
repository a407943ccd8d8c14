//! The Connection Manager's requests: Forward Open (and Large Forward Open) of the class 3
//! connection connected messages go on, and Forward Close, which frees it on the
//! controller when the gateway leaves.

use super::cip::request;

/// The Connection Manager object (class 6, instance 1).
const MANAGER: [u8; 4] = [0x20, 0x06, 0x24, 0x01];
/// The Message Router (class 2, instance 1): where the connection ends.
const ROUTER: [u8; 4] = [0x20, 0x02, 0x24, 0x01];
/// Forward Close, Forward Open, Large Forward Open.
pub(super) const FORWARD_CLOSE: u8 = 0x4E;
const FORWARD_OPEN: u8 = 0x54;
const LARGE_FORWARD_OPEN: u8 = 0x5B;

/// The vendor id and serial number this originator gives in Forward Open and Close.
const VENDOR: u16 = 0x4947;
const ORIGINATOR: u32 = 0x0106_A7E0;

/// The connection path: the route (padded to words), then the Message Router; with its
/// size in words first.
fn connection_path(route: &[u8], d: &mut Vec<u8>) {
    let mut path = route.to_vec();
    if path.len() % 2 == 1 {
        path.push(0);
    }
    path.extend_from_slice(&ROUTER);
    d.push((path.len() / 2) as u8);
    d.extend_from_slice(&path);
}

/// The triad that names a connection: its serial, the originator's vendor and serial.
fn triad(serial: u16, d: &mut Vec<u8>) {
    d.extend_from_slice(&serial.to_le_bytes());
    d.extend_from_slice(&VENDOR.to_le_bytes());
    d.extend_from_slice(&ORIGINATOR.to_le_bytes());
}

/// A Forward Open (`large`: Large Forward Open, 32-bit parameters) of a class 3
/// connection of `size` bytes to the Message Router at the end of `route`, our side's
/// connection id `t_o` and serial `serial`.
pub(super) fn forward_open(route: &[u8], size: u16, large: bool, t_o: u32, serial: u16) -> Vec<u8> {
    let mut d = vec![0x0A, 0x0E]; // ticks of 1,024 ms, 14 of them
    d.extend_from_slice(&0u32.to_le_bytes()); // O->T id: the controller chooses
    d.extend_from_slice(&t_o.to_le_bytes());
    triad(serial, &mut d);
    d.extend_from_slice(&[0x03, 0, 0, 0]); // timeout multiplier x32, reserved
    // O->T, then T->O: the requested packet interval (µs) and the connection's
    // parameters (point to point, variable size, `size` bytes).
    for _ in 0..2 {
        d.extend_from_slice(&2_000_000u32.to_le_bytes());
        if large {
            d.extend_from_slice(&(0x4200_0000u32 | u32::from(size)).to_le_bytes());
        } else {
            d.extend_from_slice(&(0x4200u16 | (size & 0x01FF)).to_le_bytes());
        }
    }
    d.push(0xA3); // server class 3, application triggered
    connection_path(route, &mut d);
    let service = if large {
        LARGE_FORWARD_OPEN
    } else {
        FORWARD_OPEN
    };
    request(service, &MANAGER, &d)
}

/// The Forward Close of the connection Forward Open made with `serial` on `route`.
pub(super) fn forward_close(route: &[u8], serial: u16) -> Vec<u8> {
    let mut d = vec![0x0A, 0x0E];
    triad(serial, &mut d);
    // The path's size in words, then a reserved byte (unlike Forward Open's).
    let mut path = Vec::new();
    connection_path(route, &mut path);
    d.push(path[0]);
    d.push(0);
    d.extend_from_slice(&path[1..]);
    request(FORWARD_CLOSE, &MANAGER, &d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forward_open_and_close_are_laid_out_as_the_specification_says() {
        let large = forward_open(&[1, 0], 4002, true, 0x1234_5678, 7);
        assert_eq!(&large[..6], b"\x5b\x02\x20\x06\x24\x01");
        let d = &large[6..];
        assert_eq!(d.len(), 46);
        assert_eq!(&d[6..10], &0x1234_5678u32.to_le_bytes());
        assert_eq!(&d[10..12], &7u16.to_le_bytes());
        assert_eq!(&d[22..26], &2_000_000u32.to_le_bytes());
        assert_eq!(&d[26..30], &(0x4200_0000u32 | 4002).to_le_bytes());
        assert_eq!(&d[34..38], &(0x4200_0000u32 | 4002).to_le_bytes());
        assert_eq!(&d[38..], b"\xa3\x03\x01\x00\x20\x02\x24\x01");
        let small = forward_open(&[], 504, false, 1, 1);
        assert_eq!(small[0], 0x54);
        assert_eq!(&small[6 + 26..6 + 28], &(0x4200u16 | 504).to_le_bytes());
        assert_eq!(&small[small.len() - 4..], b"\x20\x02\x24\x01");
        // Forward Close names the same triad and path, with a reserved byte after the
        // path's size.
        let close = forward_close(&[1, 0], 7);
        assert_eq!(&close[..6], b"\x4e\x02\x20\x06\x24\x01");
        let c = &close[6..];
        assert_eq!(&c[2..10], &d[10..18]);
        assert_eq!(&c[10..], b"\x03\x00\x01\x00\x20\x02\x24\x01");
        // An odd route is padded to a word.
        assert_eq!(
            &forward_close(&[1, 0, 2], 7)[16..],
            b"\x04\x00\x01\x00\x02\x00\x20\x02\x24\x01"
        );
    }
}
