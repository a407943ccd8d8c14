//! PINGREQ (PINGRESP has no body: it is read where packets are told apart).

pub(crate) fn pingreq() -> Vec<u8> {
    vec![0xC0, 0]
}
