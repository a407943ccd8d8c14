//! The demo's field bus: a Modbus TCP endpoint on loopback that the demo answers itself, as
//! two devices behind one serial device server would: an Eastron SDM630 energy meter at
//! unit 1 and a Waveshare 8-channel I/O module at unit 2. The gateway polls them over a real
//! socket through the link `field` of `examples/demo.yaml`, so `iogate plan`, a link's page
//! and the Modbus server's map show a line with devices on it. The module's inputs follow
//! its outputs (a relay's feedback contact; DI8 a sensor that toggles), and each output
//! switched on adds a load the meter measures.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinSet;
use tokio_util::sync::CancellationToken;

use crate::config::{Config, Transport};
use crate::link::frame::{Exception, Request, Response};
use crate::link::mbap;

/// The link of the demo's configuration that reaches the simulated devices.
pub(crate) const LINK: &str = "field";
/// The meter's and the I/O module's unit ids.
const METER: u8 = 1;
const IO: u8 = 2;
/// Masters served at once (the gateway needs one; `iogate scan` or mbpoll may be another).
const MAX_CONNECTIONS: usize = 4;
/// How often the devices' readings move.
const STEP: Duration = Duration::from_millis(500);
/// A master that asks nothing for this long is let go (its place is one of the few).
const IDLE: Duration = Duration::from_secs(60);
/// Answered at register 0x8000 of the I/O module: its software version (1.00).
const IO_VERSION: u16 = 100;

/// Binds the address of the demo's link `field`; when that port is taken, any free port on
/// the same host, written into the link so that the gateway polls where the devices answer.
/// `None` when the configuration has no such TCP link or nothing could be bound.
pub(crate) async fn bind(config: &mut Config) -> Option<TcpListener> {
    let link = config.links.iter_mut().find(|l| l.name == LINK)?;
    let Transport::Tcp { host, port, .. } = &mut link.transport else {
        return None;
    };
    let listener = match TcpListener::bind((host.as_str(), *port)).await {
        Ok(listener) => listener,
        Err(e) => {
            tracing::info!(port = *port, error = %e, "the demo's field devices take another port");
            TcpListener::bind((host.as_str(), 0)).await.ok()?
        }
    };
    *port = listener.local_addr().ok()?.port();
    Some(listener)
}

/// Answers as the demo's devices until `token` is cancelled, moving their readings.
pub(crate) async fn run(listener: TcpListener, token: CancellationToken) {
    let devices = Arc::new(Mutex::new(Devices::new()));
    let mut connections = JoinSet::new();
    let mut tick = tokio::time::interval(STEP);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    loop {
        tokio::select! {
            _ = token.cancelled() => return,
            _ = tick.tick() => lock(&devices).step(),
            accepted = listener.accept() => {
                while connections.try_join_next().is_some() {}
                match accepted {
                    Ok((stream, _)) if connections.len() < MAX_CONNECTIONS => {
                        connections.spawn(serve(stream, devices.clone()));
                    }
                    Ok((_, peer)) => tracing::debug!(%peer, "the demo's field devices are busy"),
                    Err(e) => tracing::debug!(error = %e, "the demo's field devices accept"),
                }
            }
        }
    }
}

fn lock(devices: &Mutex<Devices>) -> std::sync::MutexGuard<'_, Devices> {
    devices.lock().unwrap_or_else(|e| e.into_inner())
}

/// Answers one master's requests until it leaves, stays idle for [`IDLE`], or sends what
/// is no MBAP frame.
async fn serve(mut stream: TcpStream, devices: Arc<Mutex<Devices>>) {
    let peer: Option<SocketAddr> = stream.peer_addr().ok();
    let mut head = [0u8; mbap::HEADER_LEN];
    let mut pdu = Vec::new();
    let mut out = Vec::new();
    loop {
        match tokio::time::timeout(IDLE, stream.read_exact(&mut head)).await {
            Ok(Ok(_)) => {}
            _ => return,
        }
        let Ok(header) = mbap::Header::parse(&head) else {
            tracing::debug!(?peer, "the demo's field devices: not an MBAP frame");
            return;
        };
        pdu.resize(header.pdu_len, 0);
        match tokio::time::timeout(IDLE, stream.read_exact(&mut pdu)).await {
            Ok(Ok(_)) => {}
            _ => return,
        }
        mbap::start_frame(&mut out);
        let code = pdu.first().copied().unwrap_or(0);
        match Request::parse(&pdu)
            .and_then(|r| lock(&devices).answer(header.unit, &r).map(|a| (r, a)))
        {
            Ok((request, answer)) => answer.write_pdu(&request, &mut out),
            Err(x) => out.extend_from_slice(&x.to_pdu(code)),
        }
        mbap::finish_frame(&mut out, header.transaction, header.unit);
        if stream.write_all(&out).await.is_err() {
            return;
        }
    }
}

/// One device's tables; an address never written reads 0.
#[derive(Debug, Default)]
struct Bank {
    coils: BTreeMap<u16, bool>,
    inputs: BTreeMap<u16, bool>,
    holding: BTreeMap<u16, u16>,
    input_registers: BTreeMap<u16, u16>,
}

/// The two devices and what moves them.
#[derive(Debug)]
struct Devices {
    meter: Bank,
    io: Bank,
    steps: u64,
    /// kWh imported so far.
    energy: f64,
}

impl Devices {
    fn new() -> Devices {
        let mut devices = Devices {
            meter: Bank::default(),
            io: Bank::default(),
            steps: 0,
            energy: 1234.5,
        };
        devices.io.holding.insert(0x8000, IO_VERSION);
        devices.step();
        devices
    }

    fn answer(&mut self, unit: u8, request: &Request) -> Result<Response, Exception> {
        let bank = match unit {
            METER => &mut self.meter,
            IO => &mut self.io,
            // As a serial device server answers for a slave that is not on its line.
            _ => return Err(Exception(11)),
        };
        bank.answer(request)
    }

    /// Half a second later: the module's inputs follow its outputs, the meter measures.
    fn step(&mut self) {
        self.steps += 1;
        let outputs: Vec<bool> = (0..8).map(|i| self.io.coil(i)).collect();
        for (i, on) in outputs.iter().enumerate().take(7) {
            self.io.inputs.insert(i as u16, *on);
        }
        self.io.inputs.insert(7, (self.steps / 6) % 2 == 1);
        let t = self.steps as f64 * STEP.as_secs_f64();
        let mut readings = Readings::default();
        for phase in 0..3 {
            let volts = 230.0 + 2.5 * (t / 7.0 + phase as f64 * 2.1).sin();
            let loads = outputs
                .iter()
                .skip(phase)
                .step_by(3)
                .filter(|on| **on)
                .count();
            let amps = 0.8 + 0.1 * (t / 5.0 + phase as f64).sin() + 2.0 * loads as f64;
            let pf = [0.95, 0.92, 0.97][phase];
            readings.phase(phase, volts, amps, pf);
        }
        self.energy += readings.power / 1000.0 * STEP.as_secs_f64() / 3600.0;
        readings.frequency = 50.0 + 0.03 * (t / 11.0).sin();
        readings.write(&mut self.meter, self.energy);
    }
}

/// What the meter measured in one step.
#[derive(Debug, Default)]
struct Readings {
    volts: [f64; 3],
    amps: [f64; 3],
    watts: [f64; 3],
    pf: [f64; 3],
    power: f64,
    apparent: f64,
    frequency: f64,
}

impl Readings {
    fn phase(&mut self, phase: usize, volts: f64, amps: f64, pf: f64) {
        self.volts[phase] = volts;
        self.amps[phase] = amps;
        self.pf[phase] = pf;
        self.watts[phase] = volts * amps * pf;
        self.power += self.watts[phase];
        self.apparent += volts * amps;
    }

    /// Into the meter's input registers, at the addresses of its published map.
    fn write(&self, meter: &mut Bank, energy: f64) {
        let reactive = (self.apparent.powi(2) - self.power.powi(2)).max(0.0).sqrt();
        let mut at = |address: u16, value: f64| meter.float(address, value);
        for p in 0..3 {
            let a = p as u16 * 2;
            at(a, self.volts[p]);
            at(6 + a, self.amps[p]);
            at(12 + a, self.watts[p]);
            at(30 + a, self.pf[p]);
            at(200 + a, self.volts[p] * 3f64.sqrt());
        }
        at(52, self.power);
        at(56, self.apparent);
        at(60, reactive);
        at(62, self.power / self.apparent);
        at(70, self.frequency);
        at(72, energy);
        at(74, 0.0);
        at(342, energy);
    }
}

impl Bank {
    fn coil(&self, address: u16) -> bool {
        self.coils.get(&address).copied().unwrap_or(false)
    }

    /// An IEEE-754 single as the SDM630 stores it: two input registers, high word first.
    fn float(&mut self, address: u16, value: f64) {
        let bits = (value as f32).to_bits();
        self.input_registers.insert(address, (bits >> 16) as u16);
        self.input_registers.insert(address + 1, bits as u16);
    }

    fn answer(&mut self, request: &Request) -> Result<Response, Exception> {
        Ok(match request {
            Request::ReadCoils { address, count } => {
                Response::Bits(read(&self.coils, *address, *count)?)
            }
            Request::ReadDiscreteInputs { address, count } => {
                Response::Bits(read(&self.inputs, *address, *count)?)
            }
            Request::ReadHoldingRegisters { address, count } => {
                Response::Registers(read(&self.holding, *address, *count)?)
            }
            Request::ReadInputRegisters { address, count } => {
                Response::Registers(read(&self.input_registers, *address, *count)?)
            }
            Request::WriteSingleCoil { address, value } => {
                self.coils.insert(*address, *value);
                Response::Written
            }
            Request::WriteSingleRegister { address, value } => {
                self.holding.insert(*address, *value);
                Response::Written
            }
            Request::WriteMultipleCoils { address, values } => {
                write(&mut self.coils, *address, values)?;
                Response::Written
            }
            Request::WriteMultipleRegisters { address, values } => {
                write(&mut self.holding, *address, values)?;
                Response::Written
            }
        })
    }
}

/// `count` values from `address` on (0 where none was written); past the last address is
/// the illegal data address it is on a device.
fn read<T: Copy + Default>(
    table: &BTreeMap<u16, T>,
    address: u16,
    count: u16,
) -> Result<Vec<T>, Exception> {
    let end = u32::from(address) + u32::from(count);
    if end > 0x1_0000 {
        return Err(Exception::ILLEGAL_DATA_ADDRESS);
    }
    Ok((u32::from(address)..end)
        .map(|a| table.get(&(a as u16)).copied().unwrap_or_default())
        .collect())
}

fn write<T: Copy>(
    table: &mut BTreeMap<u16, T>,
    address: u16,
    values: &[T],
) -> Result<(), Exception> {
    if usize::from(address) + values.len() > 0x1_0000 {
        return Err(Exception::ILLEGAL_DATA_ADDRESS);
    }
    for (i, v) in values.iter().enumerate() {
        table.insert(address + i as u16, *v);
    }
    Ok(())
}

#[cfg(test)]
#[path = "field_tests.rs"]
mod tests;
