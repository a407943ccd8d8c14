use super::sample::{DeviceCode, Quality};
use super::*;
use crate::codec::Value;
use crate::write_log::{Lookup, WriteStatus};
use std::time::Duration;
use tokio::time::Instant;

fn cache() -> Cache {
    let config = crate::config::parse(
        "c.yaml",
        "links:\n  - { name: bus, tcp: { host: 127.0.0.1 } }\ndevices:\n  - { name: io, profile: Io, link: bus, slave_id: 1 }\n",
    )
    .expect("config");
    let profile = crate::profile::load_str(
        "io.yaml",
        "name: Io\nfields:\n  - { name: DI, type: BOOL, direction: input, register: { address: 0, kind: discrete_input } }\n  - { name: SP, type: REAL, direction: output, register: { address: 0, kind: holding_register, scale: 0.1, raw_type: UINT } }\n",
    )
    .expect("profile");
    Cache::new(&config, Catalog::new([profile]))
}

#[tokio::test(start_paused = true)]
async fn a_connected_device_whose_polls_get_no_line_time_is_starved() {
    let cache = cache();
    let io = cache.device("io").expect("device");
    assert!(!io.starved(Instant::now()), "never polled: not starved");
    io.record_cycle(true, Duration::from_millis(3));
    assert!(!io.starved(Instant::now()));
    tokio::time::advance(io.stale_after() + Duration::from_millis(1)).await;
    assert!(io.starved(Instant::now()));
    io.record_cycle(false, Duration::from_millis(200));
    tokio::time::advance(io.stale_after() + Duration::from_millis(1)).await;
    assert!(
        !io.starved(Instant::now()),
        "not answering: backed off, not starved"
    );
}

#[tokio::test(start_paused = true)]
async fn a_value_waiting_for_a_busy_line_is_late_not_stale() {
    let cache = cache();
    let io = cache.device("io").expect("device");
    let bus = cache.link("bus").expect("link");
    let di = io.field_index("DI").expect("field");
    io.publish(di, Ok(Value::Bool(true)));
    let mut rx = io.subscribe(di);
    drop(rx.borrow_and_update());
    // The line works for others (a transaction ends every 100 ms) while this device's
    // poll waits: three times its stale time pass, and its value stays good, untold.
    let steps = (io.stale_after() * 3).as_millis() / 100;
    for _ in 0..steps {
        bus.progress
            .started(Instant::now() + Duration::from_millis(100));
        tokio::time::advance(Duration::from_millis(100)).await;
        bus.progress.ended();
        io.tell_stale(Instant::now());
        assert_eq!(io.quality(&io.sample(di), Instant::now()), Quality::Good);
    }
    assert!(!rx.has_changed().expect("open"), "late is not told");
    // The line goes quiet (down, reopening): once the stale time has passed with no
    // transaction on it, the value is stale, and told.
    tokio::time::advance(io.stale_after() / 2).await;
    io.tell_stale(Instant::now());
    assert_eq!(io.quality(&io.sample(di), Instant::now()), Quality::Good);
    tokio::time::advance(io.stale_after() / 2 + Duration::from_millis(1)).await;
    io.tell_stale(Instant::now());
    assert_eq!(io.quality(&io.sample(di), Instant::now()), Quality::Stale);
    assert!(rx.has_changed().expect("open"), "gone stale: told");
    // The line works again (for others first): the stale spell lasts until this
    // device's next refresh, no flip back to good before it.
    bus.progress.ended();
    assert_eq!(io.quality(&io.sample(di), Instant::now()), Quality::Stale);
    io.publish(di, Ok(Value::Bool(true)));
    assert_eq!(io.quality(&io.sample(di), Instant::now()), Quality::Good);
}

#[test]
fn before_its_first_answer_a_device_is_not_connected_and_says_why() {
    let cache = cache();
    let io = cache.device("io").expect("device");
    let d = io.diagnostics();
    assert_eq!((d.connected, d.error_code), (false, DeviceCode::CommError));
    io.record_cycle(true, Duration::from_millis(3));
    let d = io.diagnostics();
    assert_eq!((d.connected, d.error_code), (true, DeviceCode::Ok));
}

/// Device `io` with its field DI read good (true) and followed, its first value taken.
fn followed_di(cache: &Cache) -> (Arc<Device>, usize, SlotReceiver<sample::Sample>) {
    let io = cache.device("io").expect("device").clone();
    let di = io.field_index("DI").expect("field");
    io.publish(di, Ok(Value::Bool(true)));
    let mut rx = io.subscribe(di);
    drop(rx.borrow_and_update());
    (io, di, rx)
}

#[tokio::test(start_paused = true)]
async fn a_value_gone_stale_is_told_once_and_its_next_refresh_again() {
    let cache = cache();
    let (io, di, mut rx) = followed_di(&cache);
    let quality = |rx: &mut SlotReceiver<sample::Sample>| {
        rx.borrow_and_update()
            .quality_at(Instant::now(), io.stale_after())
    };
    io.tell_stale(Instant::now());
    assert!(!rx.has_changed().expect("open"), "fresh: nothing to tell");
    tokio::time::advance(io.stale_after() + Duration::from_millis(1)).await;
    io.tell_stale(Instant::now());
    assert!(rx.has_changed().expect("open"), "gone stale: told");
    assert_eq!(quality(&mut rx), Quality::Stale);
    io.tell_stale(Instant::now());
    assert!(!rx.has_changed().expect("open"), "told once");
    // Read again, unchanged: subscribers learn it is fresh again.
    io.publish(di, Ok(Value::Bool(true)));
    assert!(
        rx.has_changed().expect("open"),
        "the refresh after a stale spell"
    );
    assert_eq!(quality(&mut rx), Quality::Good);
    io.publish(di, Ok(Value::Bool(true)));
    assert!(
        !rx.has_changed().expect("open"),
        "an unchanged refresh is not told"
    );
    // A value never read is never stale.
    let sp = io.field_index("SP").expect("field");
    let mut never = io.subscribe(sp);
    drop(never.borrow_and_update());
    tokio::time::advance(io.stale_after() * 2).await;
    io.tell_stale(Instant::now());
    assert!(!never.has_changed().expect("open"));
}

#[test]
fn a_burst_of_writes_leaves_one_pending_and_supersedes_the_rest() {
    let cache = cache();
    let io = cache.device("io").expect("device");
    let sp = io.field_index("sp").expect("field ignoring case");
    let gens: Vec<u64> = (0..5)
        .map(|i| io.request_write(sp, Value::Real(i as f32)).expect("write"))
        .collect();
    let taken = io.take_writes();
    assert_eq!(taken.len(), 1);
    assert_eq!(taken[0].value, Some(Value::Real(4.0)));
    assert_eq!(taken[0].generation, gens[4]);
    for g in &gens[..4] {
        let Lookup::Found(r) = cache.writes.get(*g) else {
            panic!("missing")
        };
        assert_eq!(r.status, WriteStatus::Superseded);
    }
    io.finish_write(taken[0].generation, Ok(()));
    let Lookup::Found(r) = cache.writes.get(gens[4]) else {
        panic!("missing")
    };
    assert_eq!(r.status, WriteStatus::Written);
    assert_eq!(io.latest_value(sp), Some(Value::Real(4.0)));
}

#[test]
fn a_value_the_device_refused_or_the_link_kept_dropping_is_not_written_again() {
    use crate::link::LinkFault;
    let cache = cache();
    let io = cache.device("io").expect("device");
    io.outputs().set_rewrites(true);
    let sp = io.field_index("SP").expect("field");
    let lost = || WriteError::LinkDown(LinkFault::NoPort);
    // Refused by the device: forgotten, not replayed after a reconnect.
    io.request_write(sp, Value::Real(1.0)).expect("write");
    let w = io.take_writes().remove(0);
    io.finish_write_after(w.generation, Err(WriteError::Refused("no".into())), 1);
    assert!(io.replayable().is_empty());
    // A write not sent (attempts 0) never counts; the link lost with it sent twice keeps
    // it, the third time forgets it and says so.
    let g = io.request_write(sp, Value::Real(2.0)).expect("write");
    io.take_writes();
    io.finish_write_after(g, Err(lost()), 0);
    for round in 1..=super::outputs::LOST_AT_WRITE {
        assert_eq!(io.replayable(), vec![(sp, Value::Real(2.0))]);
        let g = io.outputs().replay("io", "SP", sp, Value::Real(2.0));
        io.finish_write_after(g, Err(lost()), 1);
        let Lookup::Found(r) = cache.writes.get(g) else {
            panic!("missing")
        };
        let said = r.error.unwrap_or_default();
        assert_eq!(
            said.contains("not written again"),
            round == super::outputs::LOST_AT_WRITE,
            "{said}"
        );
    }
    assert!(io.replayable().is_empty());
    // Asked again: written again after the next reconnect.
    io.request_write(sp, Value::Real(3.0)).expect("write");
    assert_eq!(io.replayable(), vec![(sp, Value::Real(3.0))]);
}

#[test]
fn a_value_the_device_never_answered_three_times_is_not_written_again() {
    let cache = cache();
    let io = cache.device("io").expect("device");
    io.outputs().set_rewrites(true);
    let sp = io.field_index("SP").expect("field");
    let silent = || WriteError::NoResponse(crate::link::TxError::Timeout);
    let g = io.request_write(sp, Value::Real(2.0)).expect("write");
    io.take_writes();
    io.finish_write_after(g, Err(silent()), 1);
    for round in 2..=super::outputs::LOST_AT_WRITE {
        assert_eq!(
            io.replayable(),
            vec![(sp, Value::Real(2.0))],
            "round {round}"
        );
        let g = io.outputs().replay("io", "SP", sp, Value::Real(2.0));
        io.finish_write_after(g, Err(silent()), 1);
        let Lookup::Found(r) = cache.writes.get(g) else {
            panic!("missing")
        };
        let said = r.error.unwrap_or_default();
        assert_eq!(
            said.contains("did not answer this value"),
            round == super::outputs::LOST_AT_WRITE,
            "{said}"
        );
    }
    assert!(io.replayable().is_empty());
}

#[test]
fn writing_an_input_or_out_of_raw_range_is_refused() {
    let cache = cache();
    let io = cache.device("io").expect("device");
    assert!(matches!(
        io.request_write(0, Value::Bool(true)),
        Err(AccessError::NotWritable { .. })
    ));
    // 0.1 * 65535 is the largest value a UINT register holds.
    assert!(io.request_write(1, Value::Real(6553.5)).is_ok());
    assert!(matches!(
        io.request_write(1, Value::Real(6553.6)),
        Err(AccessError::InvalidValue { .. })
    ));
    assert!(matches!(
        io.request_write(1, Value::Bool(true)),
        Err(AccessError::InvalidValue { .. })
    ));
}

#[tokio::test(start_paused = true)]
async fn good_values_go_stale_without_refresh() {
    let cache = cache();
    let io = cache.device("io").expect("device");
    assert_eq!(io.sample(0).quality, Quality::NeverRead);
    io.publish(0, Ok(Value::Bool(true)));
    let stale_after = io.stale_after();
    assert_eq!(
        io.sample(0).quality_at(Instant::now(), stale_after),
        Quality::Good
    );
    tokio::time::advance(stale_after + Duration::from_millis(1)).await;
    assert_eq!(
        io.sample(0).quality_at(Instant::now(), stale_after),
        Quality::Stale
    );
    io.publish(
        0,
        Err(FieldError::Exception(
            crate::link::frame::Exception::ILLEGAL_DATA_ADDRESS,
        )),
    );
    let s = io.sample(0);
    assert_eq!(s.quality, Quality::Bad);
    assert_eq!(s.value, Some(Value::Bool(true)), "last good value is kept");
}

#[tokio::test]
async fn subscribers_wake_only_on_change() {
    let cache = cache();
    let io = cache.device("io").expect("device");
    let mut rx = io.subscribe(0);
    rx.mark_unchanged();
    io.publish(0, Ok(Value::Bool(true)));
    assert!(rx.has_changed().expect("open"));
    rx.mark_unchanged();
    io.publish(0, Ok(Value::Bool(true)));
    assert!(!rx.has_changed().expect("open"), "same value, no wake-up");
    assert!(io.sample(0).updated.is_some());
}

#[tokio::test(start_paused = true)]
async fn a_source_vouching_for_its_values_ends_the_stale_spell_told_and_only_that() {
    let cache = cache();
    let (io, _, mut rx) = followed_di(&cache);
    io.vouch();
    assert!(
        !rx.has_changed().expect("open"),
        "nothing told: nothing to end"
    );
    tokio::time::advance(io.stale_after() + Duration::from_millis(1)).await;
    io.tell_stale(Instant::now());
    assert!(rx.borrow_and_update().stale_told, "gone stale: told");
    io.vouch();
    assert!(rx.has_changed().expect("open"), "the spell's end is told");
    assert!(!rx.borrow_and_update().stale_told);
    io.vouch();
    assert!(!rx.has_changed().expect("open"), "ended once");
}
