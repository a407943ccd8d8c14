//! The built-in demo's plant moves, so that a newcomer sees values change, trends draw and
//! subscriptions deliver: the pump runs when `plant.PumpStart` says so, the tank's level
//! rises while it runs and falls while it stands, the flow totalises, the pressure swings,
//! and `sim.DI_0` toggles every five seconds. Only the demo runs it; it sets the simulated
//! devices' inputs as a client would (`Device::simulate`), and ends with the gateway.

use std::sync::Arc;
use std::time::Duration;

use tokio_util::sync::CancellationToken;

use crate::cache::Device;
use crate::codec::Value;
use crate::service::Service;

/// How often the plant moves.
const STEP: Duration = Duration::from_millis(500);

/// The state the plant carries from one step to the next.
struct Plant {
    level: f64,
    flow: f64,
    run_ms: u64,
    step: u64,
}

pub(crate) async fn run(service: Arc<Service>, token: CancellationToken) {
    let mut tick = tokio::time::interval(STEP);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut plant = Plant {
        level: 40.0,
        flow: 0.0,
        run_ms: 0,
        step: 0,
    };
    loop {
        tokio::select! {
            _ = token.cancelled() => return,
            _ = tick.tick() => {}
        }
        plant.step += 1;
        if let Ok(device) = service.device("plant") {
            plant.move_on(&device);
        }
        if let Ok(device) = service.device("sim")
            && plant.step.is_multiple_of(10)
        {
            set(&device, "DI_0", Value::Bool(plant.step.is_multiple_of(20)));
        }
    }
}

impl Plant {
    fn move_on(&mut self, device: &Device) {
        let running = device
            .field_index("PumpStart")
            .ok()
            .and_then(|i| device.sample(i).value)
            == Some(Value::Bool(true));
        if running {
            self.level = (self.level + 0.8).min(95.0);
            self.flow += 0.012;
            self.run_ms += STEP.as_millis() as u64;
        } else {
            self.level = (self.level - 0.4).max(5.0);
        }
        let swing = (self.step as f64 / 12.0).sin();
        set(device, "PumpRunning", Value::Bool(running));
        set(
            device,
            "Level",
            Value::Real((self.level * 10.0).round() as f32 / 10.0),
        );
        set(
            device,
            "FlowTotal",
            Value::LReal((self.flow * 1000.0).round() / 1000.0),
        );
        set(
            device,
            "Pressure",
            Value::Int(1013 + (swing * 40.0).round() as i64),
        );
        set(
            device,
            "SpeedRpm",
            Value::UInt(if running { 1450 } else { 0 }),
        );
        set(device, "RunSeconds", Value::UInt(self.run_ms / 1000));
    }
}

/// Sets a simulated input; one the demo's profile has not is left alone.
fn set(device: &Device, field: &str, value: Value) {
    if let Ok(idx) = device.field_index(field) {
        let _ = device.simulate(idx, value);
    }
}
