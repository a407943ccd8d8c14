use super::*;

#[test]
fn a_generation_the_other_node_of_a_pair_handed_out_is_unknown_here_not_expired() {
    let log = WriteLog::default();
    let mine = log.begin("d", "f", Value::Bool(true));
    log.enter_epoch(2);
    let next = log.begin("d", "f", Value::Bool(false));
    assert_eq!(crate::role::epoch_of(next), 2);
    assert!(matches!(log.get(mine), Lookup::Found(_)));
    // Epoch 1 was the other node's: its generations were never handed out here.
    assert_eq!(log.get(crate::role::first_generation(1)), Lookup::Unknown);
    assert_eq!(log.get(mine + 1), Lookup::Unknown);
}

#[test]
fn generations_increase_and_keep_their_outcome() {
    let log = WriteLog::default();
    let a = log.begin("d", "f", Value::Bool(true));
    let b = log.begin("d", "f", Value::Bool(false));
    assert!(b > a);
    log.finish(a, WriteStatus::Superseded, None);
    log.finish(b, WriteStatus::Failed, Some("timeout".into()));
    let Lookup::Found(ra) = log.get(a) else {
        panic!("a not found")
    };
    assert_eq!(ra.status, WriteStatus::Superseded);
    let Lookup::Found(rb) = log.get(b) else {
        panic!("b not found")
    };
    assert_eq!(rb.error.as_deref(), Some("timeout"));
    assert_eq!(log.get(b + 1), Lookup::Unknown);
    assert_eq!(log.get(0), Lookup::Unknown);
}

#[test]
fn old_generations_of_a_field_expire_and_a_burst_elsewhere_erases_none() {
    let log = WriteLog::default();
    let first = log.begin("d", "f", Value::Int(0));
    let waiting = log.begin("d", "g", Value::Int(7));
    for i in 0..FIELD_HISTORY {
        log.begin("d", "f", Value::Int(i as i64));
    }
    assert_eq!(log.get(first), Lookup::Expired);
    assert!(matches!(log.get(first + 2), Lookup::Found(_)));
    // Ten thousand writes to other fields leave field g's write in place.
    for i in 0..10_000 {
        log.begin("other", &format!("f{}", i % 500), Value::Int(i));
    }
    assert!(matches!(log.get(waiting), Lookup::Found(r) if r.value == Some(Value::Int(7))));
    assert_eq!(log.history("d", "f").len(), FIELD_HISTORY);
}

#[test]
fn the_gateways_own_writes_say_where_they_came_from() {
    let log = WriteLog::default();
    let g = log.begin_from("d", "f", Some(Value::Bool(true)), Origin::Replay);
    log.finish_after(g, WriteStatus::Written, None, 3);
    let Lookup::Found(r) = log.get(g) else {
        panic!("not found")
    };
    assert_eq!((r.origin, r.attempts), (Origin::Replay, 3));
}

fn shipped(generation: u64, status: WriteStatus, value: i64) -> WriteRecord {
    WriteRecord {
        generation,
        device: "d".into(),
        field: "f".into(),
        value: Some(Value::Int(value)),
        status,
        origin: Origin::Client,
        attempts: u32::from(status != WriteStatus::Pending),
        error: None,
        requested: SystemTime::now(),
        finished: (status != WriteStatus::Pending).then(SystemTime::now),
        forgets: false,
    }
}

#[test]
fn a_record_the_active_shipped_is_found_here_and_never_goes_back_to_an_earlier_state() {
    let log = WriteLog::default();
    let g = crate::role::first_generation(2) + 4;
    assert!(log.adopt(shipped(g, WriteStatus::Pending, 5)));
    assert!(matches!(log.get(g), Lookup::Found(r) if r.status == WriteStatus::Pending));
    assert!(log.adopt(shipped(g, WriteStatus::Written, 5)));
    // A pending copy arriving late (a snapshot) does not undo the outcome.
    assert!(!log.adopt(shipped(g, WriteStatus::Pending, 5)));
    assert!(matches!(log.get(g), Lookup::Found(r) if r.status == WriteStatus::Written));
    // Nothing of it is left to orphan at a takeover.
    assert_eq!(log.orphan_adopted(3), 0);
}

#[test]
fn a_write_the_old_active_left_pending_fails_here_at_the_takeover() {
    let log = WriteLog::default();
    let g = crate::role::first_generation(2) + 1;
    log.adopt(shipped(g, WriteStatus::Pending, 9));
    log.enter_epoch(3);
    assert_eq!(log.orphan_adopted(3), 1);
    let Lookup::Found(r) = log.get(g) else {
        panic!("not found")
    };
    assert_eq!(r.status, WriteStatus::Failed);
    assert!(
        r.error
            .expect("why")
            .contains("may or may not have reached the device")
    );
    // The new epoch's own writes come after it.
    assert!(log.begin("d", "f", Value::Int(1)) > g);
}

#[test]
fn the_journal_carries_each_change_and_a_snapshot_the_newest_of_each_field() {
    let log = WriteLog::default();
    let before = log.begin("d", "f", Value::Int(0));
    log.finish(before, WriteStatus::Superseded, None);
    log.start_journal();
    let a = log.begin("d", "f", Value::Int(1));
    log.finish(a, WriteStatus::Written, None);
    let (records, dropped) = log.drain_journal(10);
    assert_eq!(dropped, 0);
    let states: Vec<_> = records.iter().map(|r| (r.generation, r.status)).collect();
    assert_eq!(
        states,
        [(a, WriteStatus::Pending), (a, WriteStatus::Written)]
    );
    let pending = log.begin("d", "g", Value::Int(2));
    log.drain_journal(10);
    log.journal_snapshot();
    let (snapshot, _) = log.drain_journal(10);
    let mut generations: Vec<_> = snapshot.iter().map(|r| r.generation).collect();
    generations.sort_unstable();
    generations.dedup();
    assert_eq!(
        generations,
        [a, pending],
        "not {before}, which is older than f's newest"
    );
}

#[test]
fn hellos_make_at_most_one_snapshot_a_second() {
    let log = WriteLog::default();
    log.start_journal();
    let g = log.begin("d", "f", Value::Int(1));
    log.finish(g, WriteStatus::Written, None);
    log.drain_journal(10);
    let every = std::time::Duration::from_secs(1);
    log.journal_snapshot_at_most(every);
    log.journal_snapshot_at_most(every);
    let (records, _) = log.drain_journal(10);
    assert_eq!(records.len(), 1, "one snapshot of f's newest record");
}
