//! The soak's writes: an increasing number written to the `W` output of the TCP device and
//! of RTU slave 1 through REST, each followed to its outcome; the devices keep what they
//! were sent. A write told `written` that its device never got is lost; a number arriving
//! after a greater one is a write executed again out of its order.

use std::sync::Arc;
use std::time::Duration;

use iogate_tests::devices::RtuBus;
use reqwest::Method;

use crate::doors::Ctx;
use crate::field::{Cable, WRITTEN};

/// What the RTU slave 1 was sent at holding register [`WRITTEN`], in order, taken from
/// the bus's log (which would otherwise keep every poll of hours).
#[derive(Default)]
pub struct RtuWrites(std::sync::Mutex<Vec<u16>>);

impl RtuWrites {
    fn update(&self, bus: &RtuBus) -> Vec<u16> {
        let new = bus
            .take_seen()
            .into_iter()
            .filter(|s| s.slave == 1 && matches!(s.function, 6 | 16) && s.address == WRITTEN)
            .filter_map(|s| s.value);
        match self.0.lock() {
            Ok(mut all) => {
                all.extend(new);
                all.clone()
            }
            Err(_) => Vec::new(),
        }
    }
}

/// The devices and what they were sent.
#[derive(Clone)]
pub struct Targets {
    pub cable: Arc<Cable>,
    pub bus: RtuBus,
    pub rtu: Arc<RtuWrites>,
}

impl Targets {
    /// What `device` was sent at holding register [`WRITTEN`], in order.
    pub fn sent_to(&self, device: &str) -> Vec<u16> {
        if device == "tcp1" {
            self.cable.written()
        } else {
            self.rtu.update(&self.bus)
        }
    }
}

/// Writes until the soak ends; answers the last number asked of each device.
pub async fn writer(ctx: Ctx, targets: Targets) -> u16 {
    let mut n: u16 = 0;
    let tick = Duration::from_millis(250);
    loop {
        tokio::select! {
            _ = ctx.stop.cancelled() => return n,
            _ = tokio::time::sleep(tick) => {}
        }
        n = n % 60_000 + 1;
        for device in ["tcp1", "rtu1"] {
            let outcome = write(&ctx, device, n).await;
            ctx.tally.add(&format!("writes {outcome}"), 1);
            if outcome == "written" && !targets.sent_to(device).contains(&n) {
                ctx.tally.wrong(
                    "writes",
                    format!("{device}.W = {n} told written, never sent"),
                );
            }
        }
    }
}

/// One write and its outcome: `written`, `failed`, `superseded`, `refused` (the API said
/// no: busy), `pending` (no outcome within a minute), `error` (no answer).
async fn write(ctx: &Ctx, device: &str, n: u16) -> String {
    let path = format!("/api/v1/devices/{device}/fields/W");
    let body = format!("{{\"value\": {n}}}");
    let Ok((status, answer)) = ctx.gw.send(Method::PUT, &path, body).await else {
        return "error".into();
    };
    let Some(generation) = answer["generation"].as_u64().filter(|_| status == 202) else {
        return "refused".into();
    };
    let status_path = format!("/api/v1/writes/{generation}");
    for _ in 0..600 {
        if let Ok((200, w)) = ctx.gw.get(&status_path).await
            && let Some(status) = w["status"].as_str()
            && status != "pending"
        {
            if status == "failed" {
                ctx.tally
                    .note(format!("{device}.W = {n} failed: {}", w["error"]));
            }
            return status.to_owned();
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    "pending".into()
}

/// At the end: each device holds the last number asked, and never got a number after a
/// greater one (numbers restart at 1 after 60,000).
pub fn verify(ctx: &Ctx, last: u16, targets: &Targets) {
    for device in ["tcp1", "rtu1"] {
        let sent = targets.sent_to(device);
        ctx.tally.add("writes sent to devices", sent.len() as u64);
        for pair in sent.windows(2) {
            let wrapped = pair[0] > 59_000 && pair[1] < 1_000;
            if pair[1] < pair[0] && !wrapped {
                ctx.tally.wrong(
                    "writes",
                    format!("{device}.W got {} after {}", pair[1], pair[0]),
                );
            }
        }
        if last > 0 && sent.last() != Some(&last) {
            ctx.tally.wrong(
                "writes",
                format!(
                    "{device}.W ends at {:?}, not the last asked, {last}",
                    sent.last()
                ),
            );
        }
    }
}
