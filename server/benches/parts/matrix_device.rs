//! The matrix's Modbus TCP devices, in a process of their own (the bench runs itself again
//! with `IOGATE_MATRIX_CHANNELS=N`): N servers (a "channel" each, as NG Gateway's matrix
//! calls one connection), each answering any unit id with 1,000 holding registers whose
//! values change every 100 ms. It prints `PORT p` for each server, then once a second
//! `STAT requests bytes`: the requests answered and the Modbus bytes both ways (MBAP
//! header and PDU, the TCP payload), and for every register written
//! `W unit address value unix_ns` when the write arrives: the device's log.

use std::collections::HashMap;
use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use tokio_modbus::prelude::{ExceptionCode, Request, Response, SlaveRequest};

/// Holding registers of each unit.
pub const REGISTERS: u16 = 1000;

#[derive(Clone)]
struct Plant {
    started: Instant,
    written: Arc<Mutex<HashMap<(u8, u16), u16>>>,
    requests: Arc<AtomicU64>,
    bytes: Arc<AtomicU64>,
}

impl Plant {
    /// Register `a` of `unit`: what was written to it, else a number naming unit and
    /// address that moves on every 100 ms.
    fn value(&self, unit: u8, a: u16) -> u16 {
        if let Ok(w) = self.written.lock()
            && let Some(v) = w.get(&(unit, a))
        {
            return *v;
        }
        let tick = (self.started.elapsed().as_millis() / 100) as u16;
        u16::from(unit)
            .wrapping_mul(1000)
            .wrapping_add(a)
            .wrapping_add(tick)
    }

    fn log_writes(&self, unit: u8, first: u16, values: &[u16]) {
        let ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let mut out = std::io::stdout().lock();
        if let Ok(mut w) = self.written.lock() {
            for (i, v) in values.iter().enumerate() {
                let a = first.wrapping_add(i as u16);
                w.insert((unit, a), *v);
                let _ = writeln!(out, "W {unit} {a} {v} {ns}");
            }
        }
        let _ = out.flush();
    }

    fn answer(&self, unit: u8, request: Request<'static>) -> Result<Response, ExceptionCode> {
        match request {
            Request::ReadHoldingRegisters(a, n)
                if a.checked_add(n).is_some_and(|e| e <= REGISTERS) =>
            {
                self.bytes
                    .fetch_add(12 + 9 + 2 * u64::from(n), Ordering::Relaxed);
                Ok(Response::ReadHoldingRegisters(
                    (a..a + n).map(|r| self.value(unit, r)).collect(),
                ))
            }
            Request::WriteSingleRegister(a, v) if a < REGISTERS => {
                self.bytes.fetch_add(24, Ordering::Relaxed);
                self.log_writes(unit, a, &[v]);
                Ok(Response::WriteSingleRegister(a, v))
            }
            Request::WriteMultipleRegisters(a, values)
                if a.checked_add(values.len() as u16)
                    .is_some_and(|e| e <= REGISTERS) =>
            {
                self.bytes
                    .fetch_add(13 + 2 * values.len() as u64 + 12, Ordering::Relaxed);
                self.log_writes(unit, a, &values);
                Ok(Response::WriteMultipleRegisters(a, values.len() as u16))
            }
            Request::ReadHoldingRegisters(..)
            | Request::WriteSingleRegister(..)
            | Request::WriteMultipleRegisters(..) => Err(ExceptionCode::IllegalDataAddress),
            _ => Err(ExceptionCode::IllegalFunction),
        }
    }
}

impl tokio_modbus::server::Service for Plant {
    type Request = SlaveRequest<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Response, ExceptionCode>>;

    fn call(&self, req: SlaveRequest<'static>) -> Self::Future {
        self.requests.fetch_add(1, Ordering::Relaxed);
        std::future::ready(self.answer(req.slave, req.request))
    }
}

/// Serves `channels` devices until this process is killed.
pub fn serve(channels: usize) -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let plant = Plant {
            started: Instant::now(),
            written: Arc::default(),
            requests: Arc::default(),
            bytes: Arc::default(),
        };
        for _ in 0..channels {
            let port = crate::common::modbus_device(plant.clone()).await?;
            println!("PORT {port}");
        }
        println!("READY");
        let mut every = tokio::time::interval(Duration::from_secs(1));
        loop {
            every.tick().await;
            let (r, b) = (
                plant.requests.load(Ordering::Relaxed),
                plant.bytes.load(Ordering::Relaxed),
            );
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "STAT {r} {b}");
            let _ = out.flush();
        }
    })
}
