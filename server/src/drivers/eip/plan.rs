//! An EtherNet/IP device's tags packed into Multiple Service Packets: each packet's
//! requests and replies within the connection's size, in the profile's order. The driver
//! reads by this plan; `iogate plan` prints it.

use super::tag::{self, Tag};
use crate::codec::IecType;
use crate::profile::Profile;

/// The size Large Forward Open asks for.
pub(crate) const LARGE: usize = 4002;
/// What a connected message's sequence count and reply header take of the connection.
pub(crate) const CONNECTED_OVERHEAD: usize = 16;
/// A packet's data on a connection Large Forward Open makes, at most.
pub(crate) const CONNECTED_MESSAGE: usize = LARGE - CONNECTED_OVERHEAD;

/// The most elements one request reads together.
pub(crate) const MAX_RUN: usize = 10_000;

/// A read's request in a packet and its reply's bytes (`count` elements of `code`, or of
/// the largest atomic type while its type is not known), each with its offset.
pub(crate) fn packet_sizes(
    tag: &Tag,
    ty: IecType,
    code: Option<u16>,
    count: usize,
) -> (usize, usize) {
    let value = tag::reply_value_len(ty, code.or_else(|| tag::type_code(ty)));
    // Request: service, path size, path, element count. Reply: service, reserved,
    // status, extended size, type, values.
    (2 + 2 + tag.path.len() + 2, 2 + 4 + 2 + count * value)
}

/// Whether a reply of `answer` bytes is too large for a packet within `limit`: such a
/// read goes alone, with Read Tag Fragmented.
pub(crate) fn fragmented(answer: usize, limit: usize) -> bool {
    answer + 8 + 2 > limit
}

/// The device's reads: each a list of fields, one tag or consecutive elements of one
/// array (in the profile's order, of one atomic type, no bits) read with one request of
/// their count from the first one's path. `alone[i]`: field `i` is read on its own.
pub(crate) fn runs(
    tags: &[Result<Tag, String>],
    profile: &Profile,
    alone: &[bool],
) -> Vec<Vec<usize>> {
    let mut out: Vec<Vec<usize>> = Vec::new();
    // The last read's first field, last index and the length of its array's path, while
    // the next element may join it.
    let mut open: Option<(usize, u32, usize)> = None;
    for (idx, tag) in tags.iter().enumerate() {
        let Ok(tag) = tag else {
            open = None;
            continue;
        };
        let ty = profile.fields[idx].ty;
        let element = tag.element.filter(|_| {
            tag.bit.is_none() && ty != IecType::String && !alone.get(idx).copied().unwrap_or(false)
        });
        if let (Some((first, last, at)), Some((here, index)), Some(run)) =
            (open, element, out.last_mut())
            && here == at
            && index == last.wrapping_add(1)
            && run.len() < MAX_RUN
            && profile.fields[first].ty == ty
            && tags[first]
                .as_ref()
                .is_ok_and(|f| f.path.get(..at) == tag.path.get(..at))
        {
            run.push(idx);
            open = Some((first, index, at));
            continue;
        }
        out.push(vec![idx]);
        open = element.map(|(at, index)| (idx, index, at));
    }
    out
}

/// Each field's tag, or why it has none.
pub(crate) fn tags(profile: &Profile) -> Vec<Result<Tag, String>> {
    profile
        .fields
        .iter()
        .map(|f| {
            let point = f.point.as_ref().ok_or("the field has no tag")?;
            tag::parse(&point.address)
        })
        .collect()
}

/// The packets of a device's reads (`(read, asked, answered)`): each a list of reads
/// whose requests and replies fit in `limit` bytes with the packet's own header and
/// offsets; a read too large for any packet is one alone.
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

/// A profile's plan on a connection of the size Large Forward Open asks for: its reads (each a list of fields, [`runs`]), the packets (each a list of reads; a read
/// too large for one goes alone, fragmented) and the fields' tags.
pub(crate) struct Planned {
    pub(crate) runs: Vec<Vec<usize>>,
    pub(crate) packets: Vec<Vec<usize>>,
    pub(crate) tags: Vec<Result<Tag, String>>,
    /// The reply bytes of each read.
    pub(crate) answers: Vec<usize>,
}

pub(crate) fn planned(profile: &Profile) -> Planned {
    let tags = tags(profile);
    let runs = runs(&tags, profile, &[]);
    let sizes: Vec<(usize, usize, usize)> = runs
        .iter()
        .enumerate()
        .map(|(r, fields)| {
            let (ask, answer) = tags[fields[0]].as_ref().map_or((0, 0), |t| {
                packet_sizes(t, profile.fields[fields[0]].ty, None, fields.len())
            });
            (r, ask, answer)
        })
        .collect();
    let answers = sizes.iter().map(|s| s.2).collect();
    Planned {
        packets: packets(&sizes, CONNECTED_MESSAGE),
        runs,
        tags,
        answers,
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn elements_next_to_each_other_of_one_type_are_one_read() {
        crate::drivers::register();
        let yaml = r#"name: R
protocol: ab-eip
fields:
  - { name: a0, type: DINT, direction: input, tag: "A[0]" }
  - { name: a1, type: DINT, direction: input, tag: "A[1]" }
  - { name: a2, type: DINT, direction: input, tag: "A[2]" }
  - { name: a3, type: REAL, direction: input, tag: "A[3]" }
  - { name: a5, type: REAL, direction: input, tag: "A[5]" }
  - { name: m0, type: INT, direction: input, tag: "M.H[0]" }
  - { name: n1, type: INT, direction: input, tag: "N.H[1]" }
  - { name: g0, type: INT, direction: input, tag: "G[0,1]" }
  - { name: g1, type: INT, direction: input, tag: "G[0,2]" }
  - { name: s0, type: STRING, direction: input, tag: "S[0]" }
  - { name: s1, type: STRING, direction: input, tag: "S[1]" }
  - { name: b0, type: DINT, direction: input, tag: "B[0]" }
  - { name: b1, type: DINT, direction: input, tag: "B[1]" }
  - { name: b2, type: DINT, direction: input, tag: "B[2]" }
"#;
        let profile = crate::profile::load_str("r.yaml", yaml).expect("profile");
        let tags = super::tags(&profile);
        // Same array and type, next index: together; another type, a gap, another
        // structure's member of the same name, two dimensions, strings: apart.
        let runs = super::runs(&tags, &profile, &[]);
        let expect: Vec<Vec<usize>> = vec![
            vec![0, 1, 2],
            vec![3],
            vec![4],
            vec![5],
            vec![6],
            vec![7],
            vec![8],
            vec![9],
            vec![10],
            vec![11, 12, 13],
        ];
        assert_eq!(runs, expect);
        // A field read on its own splits its run.
        let mut alone = vec![false; 14];
        alone[12] = true;
        let split = super::runs(&tags, &profile, &alone);
        assert_eq!(&split[9..], &[vec![11], vec![12], vec![13]]);
        // 2,000 DINTs answer 8,008 bytes: past a packet, read fragmented.
        let (_, answer) = super::packet_sizes(
            tags[0].as_ref().expect("tag"),
            crate::codec::IecType::Dint,
            Some(0xC4),
            2000,
        );
        assert_eq!(answer, 8008);
        assert!(super::fragmented(answer, super::CONNECTED_MESSAGE));
        assert!(!super::fragmented(8 + 4 * 900, super::CONNECTED_MESSAGE));
    }

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
