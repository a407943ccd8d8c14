//! A fault every interval, in turn: RTU slaves silent, the serial adapter pulled, the
//! broker killed, the TCP device's cable pulled, the S7 PLC in STOP, the OPC UA PLC
//! switched off, a reload of a changed config; each undone after a while.

use std::path::Path;
use std::time::Duration;

use iogate_tests::devices::Behaviour;
use iogate_tests::mqtt::Broker;
use reqwest::Method;

use crate::doors::Ctx;
use crate::field::{Cable, Line, Plcs, SLAVES};

pub const KINDS: [&str; 7] = [
    "rtu slaves silent",
    "serial adapter pulled",
    "broker killed",
    "tcp cable pulled",
    "s7 plc stopped",
    "opcua plc switched off",
    "config reloaded",
];

/// What faults act on.
pub struct Field<'a> {
    pub line: &'a mut Line,
    pub cable: &'a Cable,
    pub plcs: &'a mut Plcs,
    pub broker: &'a mut Broker,
    pub config: &'a Path,
    pub config_text: &'a dyn Fn(u32) -> String,
}

/// Fault number `n` (of [`KINDS`], in turn): made, held for `hold`, undone.
pub async fn inject(ctx: &Ctx, field: &mut Field<'_>, n: u32, hold: Duration) {
    let kind = KINDS[n as usize % KINDS.len()];
    ctx.tally.add(&format!("fault: {kind}"), 1);
    match kind {
        "rtu slaves silent" => set_slaves(field.line, Behaviour::Silent),
        "serial adapter pulled" => field.line.pull(),
        "broker killed" => field.broker.pause().await,
        "tcp cable pulled" => field.cable.pull(),
        "s7 plc stopped" => note(ctx, field.plcs.s7.cmd("stop").await),
        "opcua plc switched off" => field.plcs.switch_ua_off(),
        _ => {
            reload(ctx, field, n).await;
            return;
        }
    }
    tokio::select! {
        _ = ctx.stop.cancelled() => {}
        _ = tokio::time::sleep(hold) => {}
    }
    match kind {
        "rtu slaves silent" => set_slaves(field.line, Behaviour::Normal),
        "serial adapter pulled" => note(ctx, field.line.plug()),
        "broker killed" => note(ctx, field.broker.resume().await),
        "tcp cable pulled" => field.cable.plug(),
        "s7 plc stopped" => note(ctx, field.plcs.s7.cmd("run").await),
        _ => note(ctx, field.plcs.switch_ua_on().await),
    }
}

fn set_slaves(line: &Line, behaviour: Behaviour) {
    for s in SLAVES {
        line.bus
            .slave(s, |slave| slave.behaviour = behaviour.clone());
    }
}

fn note<T>(ctx: &Ctx, result: anyhow::Result<T>) {
    if let Err(e) = result {
        ctx.tally
            .wrong("harness", format!("a fault could not be undone: {e:#}"));
    }
}

/// The config changed (a device's refresh rate) and reloaded through the API.
async fn reload(ctx: &Ctx, field: &mut Field<'_>, n: u32) {
    let tmp = field.config.with_extension("yaml.new");
    let written = std::fs::write(&tmp, (field.config_text)(n))
        .and_then(|()| std::fs::rename(&tmp, field.config));
    if let Err(e) = written {
        ctx.tally
            .wrong("harness", format!("config not written: {e}"));
        return;
    }
    match ctx.gw.send(Method::POST, "/api/v1/config/reload", "").await {
        Ok((200, answer)) if answer["applied"] == true => ctx.tally.add("reloads applied", 1),
        Ok((status, answer)) => ctx.tally.wrong("reload", format!("{status}: {answer}")),
        Err(e) => ctx.tally.wrong("reload", e.to_string()),
    }
}
