//! The lease's timing and what a standby makes of what it hears.

use super::*;

fn topics() -> Topics {
    Topics::new("g")
}

#[test]
fn a_holder_stops_before_the_broker_can_release_it_and_is_replaced_within_two_leases() {
    for lease in 2..=60 {
        let lease = Duration::from_secs(lease);
        let k = keep_alive(lease).as_secs();
        // The broker drops a silent lock between floor(1.5 k) - 1 and floor(1.5 k) + 1
        // seconds after the last packet (whole-second clocks).
        let earliest = Duration::from_secs(k * 3 / 2 - 1);
        let latest = Duration::from_secs(k * 3 / 2 + 1);
        assert!(
            holds(lease) > Duration::ZERO && holds(lease) < earliest,
            "{lease:?}"
        );
        // A takeover: the last renewal a third of `holds` before the loss, the drop, the
        // settling of the new holder.
        let takeover = latest + holds(lease) / 3 + SETTLE_MAX;
        if lease >= Duration::from_secs(3) {
            assert!(takeover <= 2 * lease, "{lease:?}: {takeover:?}");
        }
    }
}

#[tokio::test(start_paused = true)]
async fn a_lease_is_free_when_absent_released_or_silent_for_two_leases() {
    let lease = Duration::from_secs(3);
    let t = topics();
    let mut seen = Seen {
        claim: None,
        epoch: 0,
        heard: Instant::now(),
        bd_seq: None,
    };
    assert!(seen.free(lease));
    seen.take(&t.claim, br#"{"node":"b","epoch":4,"held":true}"#, &t);
    assert!(!seen.free(lease));
    assert_eq!(seen.epoch, 4);
    tokio::time::advance(Duration::from_secs(5)).await;
    seen.take(&t.alive, br#"{"node":"b","epoch":4,"held":true}"#, &t);
    tokio::time::advance(Duration::from_secs(5)).await;
    assert!(!seen.free(lease), "heard of 5 s ago");
    tokio::time::advance(Duration::from_secs(1)).await;
    assert!(seen.free(lease), "silent for two leases");
    seen.take(&t.claim, br#"{"node":"b","epoch":4,"held":false}"#, &t);
    assert!(seen.free(lease));
    seen.take(&t.claim, b"not json", &t);
    assert_eq!(seen.epoch, 4, "a claim that does not parse changes nothing");
}
