//! `kill -9` at random moments while the buffer is appended to and acknowledged, 100 times
//! over one directory (each life opening what the last one left): at every next open, the
//! records are whole, in order, without a gap from the first not acknowledged to the last
//! whose append returned. A killed process loses nothing written (the operating system has
//! it; the fsync policy is about power cuts); records acknowledged just before the kill may
//! come again (the head is written after them), never fewer.

use std::time::Duration;

use super::*;

const CHILD: &str = "IOGATE_BUFFER_CRASH_DIR";

fn config() -> BufferConfig {
    BufferConfig {
        max_bytes: 64 << 20,
        fsync: Fsync::Never,
        ..BufferConfig::default()
    }
}

fn record(n: u64) -> Record {
    Record {
        at_ms: now_ms(),
        kind: Kind::Json,
        device: "pump".into(),
        field: format!("f{n}"),
        payload: n.to_le_bytes().to_vec(),
    }
}

/// Every record's number, from the head on.
fn numbers(b: &mut Buffer) -> Vec<u64> {
    let mut out = Vec::new();
    while let Ok(Some((r, _))) = b.next() {
        let mut n = [0u8; 8];
        n.copy_from_slice(r.payload.get(..8).unwrap_or(&[0; 8]));
        out.push(u64::from_le_bytes(n));
    }
    out
}

/// The writer's life, in a process of its own: reopen, go on numbering after the last
/// record, append and acknowledge until killed, telling each append (`a N`) once it returned
/// and each acknowledgement (`k N`) before it is made.
#[test]
#[ignore = "run by the crash test in a process of its own"]
fn a_writer_until_killed() {
    let Ok(dir) = std::env::var(CHILD) else {
        return;
    };
    let mut b = Buffer::open(Path::new(&dir), &config()).expect("opens");
    let mut next = numbers(&mut b).last().map_or(0, |n| n + 1);
    b.rewind();
    let until = Instant::now() + Duration::from_secs(5);
    while Instant::now() < until {
        b.append(&record(next)).expect("appends");
        println!("a {next}");
        if next.is_multiple_of(7) {
            // Acknowledge all but the newest few.
            let mut acked = None;
            while let Ok(Some((r, end))) = b.next() {
                if u64::from_le_bytes(r.payload[..8].try_into().unwrap_or([0; 8])) + 3 > next {
                    break;
                }
                acked = Some((r, end));
            }
            if let Some((r, end)) = acked {
                let n = u64::from_le_bytes(r.payload[..8].try_into().unwrap_or([0; 8]));
                println!("k {n}");
                b.ack(end);
                b.write_head(next.is_multiple_of(21)).expect("head");
            }
            b.rewind();
        }
        next += 1;
    }
}

#[test]
fn a_writer_killed_a_hundred_times_loses_nothing_it_wrote() {
    let dir = tempfile::tempdir().expect("a directory");
    let mut moments = crate::killed::Moments::new();
    let (mut appended, mut acked) = (None::<u64>, None::<u64>);
    for life in 0..100 {
        // Killed once it has written a little, at a moment of its run that differs each life.
        let lines = crate::killed::run_and_kill(
            "api::mqtt::buffer::crash_tests::a_writer_until_killed",
            (CHILD, dir.path()),
            &mut moments,
            (Duration::from_micros(500), Duration::from_millis(20)),
        );
        for line in lines {
            match line.split_once(' ') {
                Some(("a", n)) => appended = n.parse().ok().or(appended),
                Some(("k", n)) => acked = n.parse().ok().or(acked),
                _ => {}
            }
        }
        let mut b = Buffer::open(dir.path(), &config()).expect("reopens after a kill");
        let got = numbers(&mut b);
        assert!(
            got.windows(2).all(|w| w[1] == w[0] + 1),
            "life {life}: a gap or a disorder in {:?}…",
            got.iter().take(20).collect::<Vec<_>>()
        );
        if let Some(last) = appended {
            assert!(
                got.last().is_some_and(|&l| l >= last),
                "life {life}: record {last} was appended, the buffer ends at {:?}",
                got.last()
            );
        }
        let first_kept = got.first().copied().unwrap_or(u64::MAX);
        let unacked = acked.map_or(0, |k| k + 1);
        assert!(
            first_kept <= unacked || got.is_empty() && appended.is_none_or(|a| a < unacked),
            "life {life}: records from {unacked} were not acknowledged, the buffer starts at {first_kept}"
        );
    }
    assert!(
        appended.is_some_and(|a| a > 100),
        "the writer wrote: {appended:?}"
    );
}
