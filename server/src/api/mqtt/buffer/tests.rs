use super::*;

fn config(max_bytes: u64) -> BufferConfig {
    BufferConfig {
        max_bytes,
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

fn field_no(r: &Record) -> u64 {
    u64::from_le_bytes(r.payload[..8].try_into().expect("test"))
}

#[test]
fn crc32_is_zlibs() {
    assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
}

#[test]
fn records_come_back_in_order_and_survive_a_reopen() {
    let dir = tempfile::tempdir().expect("test");
    let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
    for n in 0..1000 {
        b.append(&record(n)).expect("test");
    }
    // Replay 300 and acknowledge them; the rest is still there after a reopen.
    let mut last = Pos::default();
    for n in 0..300 {
        let (r, end) = b.next().expect("test").expect("test");
        assert_eq!(field_no(&r), n);
        last = end;
    }
    b.ack(last);
    b.write_head(true).expect("test");
    assert_eq!(b.stats().depth, 700);
    drop(b);
    let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
    assert_eq!(b.stats().depth, 700);
    let mut n = 300;
    while let Some((r, end)) = b.next().expect("test") {
        assert_eq!(field_no(&r), n);
        n += 1;
        b.ack(end);
    }
    assert_eq!(n, 1000);
    assert!(b.is_empty());
}

#[test]
fn unacknowledged_records_are_replayed_again_after_a_rewind() {
    let dir = tempfile::tempdir().expect("test");
    let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
    for n in 0..10 {
        b.append(&record(n)).expect("test");
    }
    let (_, end) = b.next().expect("test").expect("test");
    b.ack(end);
    b.next().expect("test").expect("test");
    b.next().expect("test").expect("test");
    b.rewind();
    assert_eq!(field_no(&b.next().expect("test").expect("test").0), 1);
}

#[test]
fn a_torn_tail_is_cut_off_and_the_rest_kept() {
    let dir = tempfile::tempdir().expect("test");
    let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
    for n in 0..5 {
        b.append(&record(n)).expect("test");
    }
    drop(b);
    let seg = std::fs::read_dir(dir.path())
        .expect("test")
        .filter_map(|e| e.ok())
        .find(|e| e.file_name().to_string_lossy().ends_with(".seg"))
        .expect("test")
        .path();
    let mut f = OpenOptions::new().append(true).open(&seg).expect("test");
    f.write_all(&[40, 0, 0, 0, 1, 2]).expect("test");
    drop(f);
    let mut b = Buffer::open(dir.path(), &config(1 << 30)).expect("test");
    assert_eq!(b.stats().depth, 5);
    b.append(&record(5)).expect("test");
    let mut seen = Vec::new();
    while let Some((r, _)) = b.next().expect("test") {
        seen.push(field_no(&r));
    }
    assert_eq!(seen, vec![0, 1, 2, 3, 4, 5]);
}

#[test]
fn over_max_bytes_the_oldest_are_dropped_and_counted() {
    let dir = tempfile::tempdir().expect("test");
    // Segments of 64 KiB; a 256 KiB buffer keeps about four of them.
    let mut b = Buffer::open(dir.path(), &config(256 << 10)).expect("test");
    for n in 0..20_000 {
        b.append(&record(n)).expect("test");
    }
    let s = b.stats();
    assert!(s.bytes <= 256 << 10, "{s:?}");
    assert!(s.dropped > 0);
    assert_eq!(s.depth + s.dropped, 20_000);
    // What is left is the newest, in order.
    let (first, _) = b.next().expect("test").expect("test");
    assert_eq!(field_no(&first), s.dropped);
}
