//! Simulated devices: fields held in memory, polled at their `refresh_rate` like real ones.
//! Outputs take the values clients write; inputs take what is set through the API.

use std::sync::Arc;

use tokio::time::{Instant, MissedTickBehavior};
use tokio_util::sync::CancellationToken;

use crate::cache::Device;

/// Runs one simulated device until `token` is cancelled.
pub(crate) async fn run(device: Arc<Device>, token: CancellationToken) {
    let period = device
        .config
        .refresh_rate
        .max(crate::config::rules::MIN_PERIOD);
    let mut tick = tokio::time::interval(period);
    // On the grid of its refresh rate: a late cycle does not shift the next ones.
    tick.set_missed_tick_behavior(MissedTickBehavior::Skip);
    loop {
        tokio::select! {
            _ = token.cancelled() => break,
            _ = tick.tick() => {}
        }
        let started = Instant::now();
        let writes = device.take_writes();
        let Some(values) = device.sim_cycle(&writes) else {
            break;
        };
        for w in &writes {
            device.finish_write(w.generation, Ok(()));
        }
        let now = crate::cache::Stamp::now();
        for (idx, value) in values.into_iter().enumerate() {
            device.publish_at(idx, Ok(value), now);
        }
        device.record_cycle(true, started.elapsed());
    }
    tracing::debug!(device = %device.name(), "simulated device stopped");
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cache::Cache;
    use crate::cache::sample::Quality;
    use crate::codec::Value;
    use crate::profile::Catalog;
    use crate::write_log::{Lookup, WriteStatus};
    use std::time::Duration;

    #[tokio::test(start_paused = true)]
    async fn outputs_show_writes_and_inputs_show_what_is_set() {
        let profile = crate::profile::load_str(
            "s.yaml",
            "name: S\nprotocol: simulated\nfields:\n  - { name: DI_0, type: BOOL, direction: input, register: { address: 0, kind: virtual } }\n  - { name: DO_0, type: BOOL, direction: output, register: { address: 1, kind: virtual } }\n",
        )
        .expect("profile");
        let config = crate::config::parse(
            "c.yaml",
            "devices:\n  - { name: sim, profile: S, refresh_rate: 100ms }\n",
        )
        .expect("config");
        let cache = Cache::new(&config, Catalog::new([profile]));
        let sim = cache.device("sim").expect("device").clone();
        let token = CancellationToken::new();
        let task = tokio::spawn(run(sim.clone(), token.clone()));

        tokio::time::sleep(Duration::from_millis(50)).await;
        assert_eq!(sim.sample(0).quality, Quality::Good);
        assert_eq!(sim.sample(1).value, Some(Value::Bool(false)));
        assert_eq!(sim.diagnostics().io_cycles, 1);
        assert!(sim.diagnostics().connected);

        let generation = sim.request_write(1, Value::Bool(true)).expect("write");
        sim.simulate(0, Value::Bool(true)).expect("simulate");
        assert!(
            sim.simulate(1, Value::Bool(true)).is_err(),
            "outputs are not simulated inputs"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert_eq!(sim.sample(0).value, Some(Value::Bool(true)));
        assert_eq!(sim.sample(1).value, Some(Value::Bool(true)));
        let Lookup::Found(record) = cache.writes.get(generation) else {
            panic!("write not logged")
        };
        assert_eq!(record.status, WriteStatus::Written);
        assert_eq!(sim.diagnostics().io_cycles, 2);

        token.cancel();
        task.await.expect("task ends");
    }
}
