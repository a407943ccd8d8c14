//! An EtherNet/IP device's tags packed into Multiple Service Packets: each packet's
//! requests and replies within the connection's size, in the profile's order. The driver
//! reads by this plan; `iogate plan` prints it.

use crate::codec::IecType;
use crate::profile::Profile;
use crate::profile::eip_tag::{self, Tag};

/// The size Large Forward Open asks for.
pub(crate) const LARGE: usize = 4002;
/// What a connected message's sequence count and reply header take of the connection.
pub(crate) const CONNECTED_OVERHEAD: usize = 16;
/// A packet's data on a connection Large Forward Open makes, at most.
pub(crate) const CONNECTED_MESSAGE: usize = LARGE - CONNECTED_OVERHEAD;

/// A tag's request in a packet and its reply's bytes (the reply of `code`, or of the
/// largest atomic type while its type is not known), each with its offset.
pub(crate) fn packet_sizes(tag: &Tag, ty: IecType, code: Option<u16>) -> (usize, usize) {
    let value = eip_tag::reply_value_len(ty, code.or_else(|| eip_tag::type_code(ty)));
    // Request: service, path size, path, element count. Reply: service, reserved,
    // status, extended size, type, value.
    (2 + 2 + tag.path.len() + 2, 2 + 4 + 2 + value)
}

/// Each field's tag, or why it has none.
pub(crate) fn tags(profile: &Profile) -> Vec<Result<Tag, String>> {
    profile
        .fields
        .iter()
        .map(|f| {
            let point = f.point.as_ref().ok_or("the field has no tag")?;
            eip_tag::parse(&point.address)
        })
        .collect()
}

/// The packets of a device's tags: each a list of field indexes, whose requests (`asked`)
/// and replies (`answered` bytes each) fit in `limit` bytes with the packet's own header
/// and offsets.
pub(crate) fn packets(sizes: &[(usize, usize, usize)], limit: usize) -> Vec<Vec<usize>> {
    let mut out: Vec<Vec<usize>> = Vec::new();
    let (mut asked, mut answered) = (0usize, 0usize);
    for &(idx, ask, answer) in sizes {
        let fits = out.last().is_some_and(|p| {
            asked + ask + 2 * (p.len() + 1) <= limit
                && answered + answer + 2 * (p.len() + 1) <= limit
        });
        if !fits {
            out.push(Vec::new());
            // The packet's service, path and count, and its reply's header and count.
            (asked, answered) = (8, 8);
        }
        if let Some(p) = out.last_mut() {
            p.push(idx);
        }
        asked += ask;
        answered += answer;
    }
    out
}

/// A profile's packets on a connection of the size Large Forward Open asks for.
pub(crate) fn planned(profile: &Profile) -> (Vec<Vec<usize>>, Vec<Result<Tag, String>>) {
    let tags = tags(profile);
    let sizes: Vec<(usize, usize, usize)> = tags
        .iter()
        .enumerate()
        .filter_map(|(idx, t)| {
            let t = t.as_ref().ok()?;
            let (ask, answer) = packet_sizes(t, profile.fields[idx].ty, None);
            Some((idx, ask, answer))
        })
        .collect();
    (packets(&sizes, CONNECTED_MESSAGE), tags)
}

#[cfg(test)]
mod tests {
    #[test]
    fn packets_are_filled_to_the_limit_both_ways_and_never_past_it() {
        // 100 tags of 16 bytes asked and 14 answered, within 480: 26 a packet.
        let sizes: Vec<(usize, usize, usize)> = (0..100).map(|i| (i, 16, 14)).collect();
        let p = super::packets(&sizes, 480);
        assert_eq!(
            p.iter().map(Vec::len).collect::<Vec<_>>(),
            vec![26, 26, 26, 22]
        );
        for packet in &p {
            assert!(8 + packet.len() * (16 + 2) <= 480);
        }
        // Large answers (a LINT each) bound the packet by the answer's side.
        let big: Vec<(usize, usize, usize)> = (0..10).map(|i| (i, 10, 100)).collect();
        assert_eq!(super::packets(&big, 480).len(), 3);
        assert!(super::packets(&[], 480).is_empty());
    }
}
