//! Serving Modbus requests from the cache, the way the Modbus TCP server front-end asks:
//! reads answer the bound fields' newest values (never waiting for a bus), writes go
//! through the same checked, last-value-wins write path as REST and gRPC (all or nothing
//! when a request spans several fields), unbound output and memory locations are gateway
//! memory, and foreign unit ids are forwarded to a link's queue.

use std::sync::Arc;
use std::time::Duration;

use tokio::time::Instant;

use super::Service;
use crate::cache::{AccessError, Cache, Device, Link, PassthroughError};
use crate::codec::Value;
use crate::config::modbus_server::{ModbusServerConfig, OnBadQuality};
use crate::config::rules::DEFAULT_TIMEOUT;
use crate::link::TxError;
use crate::link::frame::{Exception, Request, Response};
use crate::map::memory::{Memory, MemoryError};
use crate::map::{Binding, Diag, Plan, Space, Table, Target};
use iogate_types::Quality;

/// How long past a forwarded request's own timeout a master is waited for: a request still
/// in the link's inbox after that is dropped (exception 06), never sent late.
pub(crate) const FORWARD_PATIENCE: Duration = Duration::from_secs(1);

/// A binding with its device.
#[derive(Debug)]
pub(crate) struct Bound {
    pub(crate) binding: Binding,
    pub(crate) device: Arc<Device>,
}

/// The server's image: bindings by table address, memory, and the routes of unit ids.
#[derive(Debug)]
pub(crate) struct ModbusImage {
    pub(crate) config: ModbusServerConfig,
    pub(crate) space: Space,
    pub(crate) bound: Vec<Bound>,
    /// For every address of each table: the binding there and the offset in it.
    index: [Vec<Option<(u32, u16)>>; 4],
    pub(crate) memory: Memory,
}

fn table_index(table: Table) -> usize {
    match table {
        Table::Coils => 0,
        Table::DiscreteInputs => 1,
        Table::InputRegisters => 2,
        Table::HoldingRegisters => 3,
    }
}

const TABLES: [Table; 4] = [
    Table::Coils,
    Table::DiscreteInputs,
    Table::InputRegisters,
    Table::HoldingRegisters,
];

impl ModbusImage {
    /// The image of `plan` over the devices of `cache`.
    pub(crate) fn new(
        config: &ModbusServerConfig,
        plan: &Plan,
        cache: &Cache,
    ) -> Result<Self, MemoryError> {
        let space = plan.space;
        let mut index: [Vec<Option<(u32, u16)>>; 4] =
            TABLES.map(|t| vec![None; space.table_len(t) as usize]);
        let mut bound = Vec::new();
        for binding in &plan.bindings {
            let Ok(device) = cache.device(&binding.device) else {
                continue;
            };
            let n = bound.len() as u32;
            let slots = &mut index[table_index(binding.slot.table)];
            for k in 0..binding.slot.width {
                if let Some(slot) = slots.get_mut(usize::from(binding.slot.address + k)) {
                    *slot = Some((n, k));
                }
            }
            bound.push(Bound {
                binding: binding.clone(),
                device,
            });
        }
        let memory = Memory::new(
            space.table_len(Table::Coils) as usize,
            space.table_len(Table::HoldingRegisters) as usize,
            config.memory_file.clone(),
        )?;
        Ok(ModbusImage {
            config: config.clone(),
            space,
            bound,
            index,
            memory,
        })
    }

    /// The image of a reloaded map over the devices now in the cache, keeping this one's
    /// memory (see [`Memory::carried`]).
    pub(crate) fn reloaded(
        &self,
        config: &ModbusServerConfig,
        plan: &Plan,
        cache: &Cache,
    ) -> Result<Self, MemoryError> {
        let mut next = ModbusImage::new(config, plan, cache)?;
        next.memory = self.memory.carried(
            plan.space.table_len(Table::Coils) as usize,
            plan.space.table_len(Table::HoldingRegisters) as usize,
            config.memory_file.clone(),
        )?;
        Ok(next)
    }

    fn at(&self, table: Table, address: u16) -> Option<(&Bound, u16)> {
        let (n, k) = (*self.index[table_index(table)].get(usize::from(address))?)?;
        Some((&self.bound[n as usize], k))
    }

    /// The addresses `[address, address + count)` exist in `table`.
    fn check_range(&self, table: Table, address: u16, count: u16) -> Result<(), Exception> {
        if u32::from(address) + u32::from(count) > self.space.table_len(table) {
            return Err(Exception::ILLEGAL_DATA_ADDRESS);
        }
        Ok(())
    }

    /// The value a binding shows now, or exception 0x0B when it is not good and the server
    /// is set to say so.
    fn current(&self, b: &Bound) -> Result<Option<Value>, Exception> {
        let d = &b.device;
        match b.binding.target {
            Target::Diagnostic(which) => {
                let diag = d.diagnostics();
                Ok(Some(match which {
                    Diag::Connected => Value::Bool(diag.connected),
                    Diag::ErrorCode => Value::Int(diag.error_code.code().into()),
                    Diag::IoCycles => Value::UInt(diag.io_cycles & u64::from(u32::MAX)),
                    Diag::LastResponseMs => Value::Real(diag.last_response_ms as f32),
                }))
            }
            Target::Field(idx) => {
                let sample = d.sample(idx);
                let quality = d.quality(&sample, Instant::now());
                if quality != Quality::Good && self.config.on_bad_quality == OnBadQuality::Exception
                {
                    return Err(Exception::GATEWAY_TARGET_FAILED);
                }
                Ok(sample.value)
            }
        }
    }

    fn encoding(b: &Bound) -> Option<&crate::codec::Encoding> {
        match b.binding.target {
            Target::Field(idx) => Some(&b.device.field(idx).encoding),
            Target::Diagnostic(_) => None,
        }
    }

    pub(crate) fn read_bits(
        &self,
        table: Table,
        address: u16,
        count: u16,
    ) -> Result<Vec<bool>, Exception> {
        self.check_range(table, address, count)?;
        let end = address + count;
        let mut out = Vec::with_capacity(usize::from(count));
        let mut a = address;
        while a < end {
            if let Some((b, _)) = self.at(table, a) {
                out.push(matches!(self.current(b)?, Some(Value::Bool(true))));
                a += 1;
                continue;
            }
            // A run of unbound bits: gateway memory (coils) under one lock, or false.
            let run = self.unbound_run(table, a, end);
            if table == Table::Coils {
                self.memory.coils_into(a, run, &mut out);
            } else {
                out.extend(std::iter::repeat_n(false, usize::from(run)));
            }
            a += run;
        }
        Ok(out)
    }

    /// How many addresses from `a` (before `end`) are bound to nothing.
    fn unbound_run(&self, table: Table, a: u16, end: u16) -> u16 {
        (a..end)
            .take_while(|&x| self.at(table, x).is_none())
            .count() as u16
    }

    pub(crate) fn read_registers(
        &self,
        table: Table,
        address: u16,
        count: u16,
    ) -> Result<Vec<u16>, Exception> {
        self.check_range(table, address, count)?;
        let mut out = Vec::with_capacity(usize::from(count));
        let mut a = address;
        while a < address + count {
            match self.at(table, a) {
                Some((b, k)) => {
                    let value = self.current(b)?;
                    // A value the location cannot show is refused as a bad value is.
                    let regs = b
                        .binding
                        .repr
                        .registers(value.as_ref(), Self::encoding(b))
                        .ok_or(Exception::GATEWAY_TARGET_FAILED)?;
                    let take = (b.binding.slot.width - k).min(address + count - a);
                    out.extend_from_slice(&regs[usize::from(k)..usize::from(k + take)]);
                    a += take;
                }
                None => {
                    // A run of unbound registers: gateway memory (holding registers) under
                    // one lock, or 0.
                    let run = self.unbound_run(table, a, address + count);
                    if table == Table::HoldingRegisters {
                        self.memory.registers_into(a, run, &mut out);
                    } else {
                        out.extend(std::iter::repeat_n(0, usize::from(run)));
                    }
                    a += run;
                }
            }
        }
        Ok(out)
    }
}

/// Where a unit id's requests go.
#[derive(Debug)]
pub(crate) enum Route {
    /// Answered from the map (this image).
    Local(Arc<ModbusImage>),
    /// Forwarded to this slave on this link, with this timeout.
    Forward(Arc<Link>, Duration),
    /// No route: exception 0x0A.
    Unknown,
}

/// The Modbus exception of each kind of refusal: the Modbus server's one table.
fn exception(refusal: super::Refusal) -> Exception {
    use super::Refusal as R;
    match refusal {
        R::Invalid => Exception::ILLEGAL_DATA_VALUE,
        R::Conflict | R::NotFound => Exception::ILLEGAL_DATA_ADDRESS,
        R::Busy => Exception::SERVER_DEVICE_BUSY,
        R::Forbidden => Exception::ILLEGAL_FUNCTION,
        R::Gone | R::Unavailable | R::TooMany => Exception::SERVER_DEVICE_FAILURE,
    }
}

fn refusal(e: &AccessError) -> Exception {
    exception(e.refusal().0)
}

impl Service {
    /// The Modbus server's image, when one is configured.
    pub(crate) fn modbus(&self) -> Option<Arc<ModbusImage>> {
        self.modbus
            .read()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Where requests for `unit` go: the server's own unit id (and 0 and 255, as Modbus
    /// TCP devices answer them) from the map; a unit listed under `forward` to its link.
    pub(crate) fn modbus_route(&self, unit: u8) -> Route {
        let Some(image) = self.modbus() else {
            return Route::Unknown;
        };
        if unit == image.config.unit_id || unit == 0 || unit == 255 {
            return Route::Local(image);
        }
        let Some(forward) = image
            .config
            .forward
            .iter()
            .find(|f| (f.first..=f.last).contains(&unit))
        else {
            return Route::Unknown;
        };
        let Ok(link) = self.cache.link(&forward.link) else {
            return Route::Unknown;
        };
        let timeout = link
            .members()
            .iter()
            .find(|d| d.slave_id() == Some(unit))
            .map_or(DEFAULT_TIMEOUT, |d| d.config.timeout);
        Route::Forward(link, timeout)
    }

    /// Answers one request for `unit`. A read-only gateway answers every write function with exception 01, whether it would
    /// land in the map, the memory or a forwarded device.
    pub(crate) async fn modbus_request(
        &self,
        unit: u8,
        request: &Request,
    ) -> Result<Response, Exception> {
        if request.is_write() && self.is_read_only() {
            return Err(Exception::ILLEGAL_FUNCTION);
        }
        match self.modbus_route(unit) {
            Route::Local(image) => self.modbus_local(&image, request),
            Route::Unknown => Err(Exception::GATEWAY_PATH_UNAVAILABLE),
            Route::Forward(link, timeout) => {
                // A master waits about a second for an answer; a request the link cannot
                // send by then (after the slave's timeout) is dropped, never sent late.
                let deadline = Instant::now() + timeout + FORWARD_PATIENCE;
                match self
                    .pass_through(&link, unit, request, timeout, deadline, None)
                    .await
                {
                    Ok(response) => Ok(response),
                    Err(PassthroughError::Tx(TxError::Exception(x))) => Err(x),
                    Err(PassthroughError::LinkDown(_) | PassthroughError::NotModbus) => {
                        Err(Exception::GATEWAY_PATH_UNAVAILABLE)
                    }
                    Err(PassthroughError::Busy | PassthroughError::Expired) => {
                        Err(Exception::SERVER_DEVICE_BUSY)
                    }
                    Err(PassthroughError::Tx(_) | PassthroughError::NoAnswer) => {
                        Err(Exception::GATEWAY_TARGET_FAILED)
                    }
                }
            }
        }
    }

    /// Answers one request from the server's own map and memory (a serial port's unit id,
    /// whatever the TCP server's): the same rules as [`Service::modbus_request`].
    pub(crate) fn modbus_request_local(&self, request: &Request) -> Result<Response, Exception> {
        if request.is_write() && self.is_read_only() {
            return Err(Exception::ILLEGAL_FUNCTION);
        }
        let image = self.modbus().ok_or(Exception::GATEWAY_PATH_UNAVAILABLE)?;
        self.modbus_local(&image, request)
    }

    fn modbus_local(&self, image: &ModbusImage, request: &Request) -> Result<Response, Exception> {
        match request {
            Request::ReadCoils { address, count } => image
                .read_bits(Table::Coils, *address, *count)
                .map(Response::Bits),
            Request::ReadDiscreteInputs { address, count } => image
                .read_bits(Table::DiscreteInputs, *address, *count)
                .map(Response::Bits),
            Request::ReadHoldingRegisters { address, count } => image
                .read_registers(Table::HoldingRegisters, *address, *count)
                .map(Response::Registers),
            Request::ReadInputRegisters { address, count } => image
                .read_registers(Table::InputRegisters, *address, *count)
                .map(Response::Registers),
            Request::WriteSingleCoil { address, value } => {
                self.write_coils(image, *address, &[*value])
            }
            Request::WriteMultipleCoils { address, values } => {
                self.write_coils(image, *address, values)
            }
            Request::WriteSingleRegister { address, value } => {
                self.write_registers(image, *address, &[*value])
            }
            Request::WriteMultipleRegisters { address, values } => {
                self.write_registers(image, *address, values)
            }
        }
        .map(|r| {
            if request.is_read() {
                r
            } else {
                Response::Written
            }
        })
    }

    fn write_coils(
        &self,
        image: &ModbusImage,
        address: u16,
        values: &[bool],
    ) -> Result<Response, Exception> {
        if image.config.read_only || self.is_read_only() {
            return Err(Exception::ILLEGAL_FUNCTION);
        }
        image.check_range(Table::Coils, address, values.len() as u16)?;
        let mut writes = Vec::new();
        let mut memory = Vec::new();
        for (a, &v) in (address..).zip(values) {
            match image.at(Table::Coils, a) {
                Some((b, _)) => writes.push(self.prepare_bound(b, Value::Bool(v))?),
                None => memory.push((a, v)),
            }
        }
        self.commit(image, writes, &memory, &[])
    }

    fn write_registers(
        &self,
        image: &ModbusImage,
        address: u16,
        values: &[u16],
    ) -> Result<Response, Exception> {
        if image.config.read_only || self.is_read_only() {
            return Err(Exception::ILLEGAL_FUNCTION);
        }
        let end = address as usize + values.len();
        image.check_range(Table::HoldingRegisters, address, values.len() as u16)?;
        let mut writes = Vec::new();
        let mut memory = Vec::new();
        let mut a = address;
        while usize::from(a) < end {
            match image.at(Table::HoldingRegisters, a) {
                Some((b, k)) => {
                    let slot = b.binding.slot;
                    // A write covers a bound value whole, or not at all.
                    if k != 0 || usize::from(slot.address + slot.width) > end {
                        return Err(Exception::ILLEGAL_DATA_ADDRESS);
                    }
                    let from = usize::from(a - address);
                    let regs = &values[from..from + usize::from(slot.width)];
                    let value = b
                        .binding
                        .repr
                        .value(regs, b.binding.ty, ModbusImage::encoding(b))
                        .map_err(|_| Exception::ILLEGAL_DATA_VALUE)?;
                    writes.push(self.prepare_bound(b, value)?);
                    a += slot.width;
                }
                None => {
                    memory.push((a, values[usize::from(a - address)]));
                    a += 1;
                }
            }
        }
        self.commit(image, writes, &[], &memory)
    }

    /// Checks a write of `value` to a bound location; nothing is written.
    fn prepare_bound(&self, b: &Bound, value: Value) -> Result<super::Prepared, Exception> {
        let Target::Field(idx) = b.binding.target else {
            return Err(Exception::ILLEGAL_DATA_ADDRESS);
        };
        if !b.binding.writable {
            return Err(Exception::ILLEGAL_DATA_ADDRESS);
        }
        let name = &b.device.field(idx).name;
        self.prepare(&b.device, name, |_| {
            Ok::<_, crate::codec::CodecError>(value)
        })
        .map_err(|e| refusal(&e))
    }

    /// Requests every checked write (all or nothing) and sets the memory locations.
    fn commit(
        &self,
        image: &ModbusImage,
        writes: Vec<super::Prepared>,
        coils: &[(u16, bool)],
        registers: &[(u16, u16)],
    ) -> Result<Response, Exception> {
        if !writes.is_empty() {
            self.write_all(writes.into_iter().map(Ok::<_, AccessError>).collect())
                .map_err(|e| exception(e.refusal().0))?;
        }
        if !coils.is_empty() || !registers.is_empty() {
            image.memory.set(coils, registers).map_err(|e| {
                tracing::error!(error = %e, "memory not saved");
                Exception::SERVER_DEVICE_FAILURE
            })?;
        }
        Ok(Response::Written)
    }
}
