//! Devices for the tests: a register map served by tokio-modbus (an independent Modbus
//! implementation), and an RTU bus of our own whose slaves can be told to misbehave.

use std::collections::HashMap;
use std::future::{Ready, ready};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::task::JoinHandle;
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};
use tokio_serial::{SerialPort, SerialStream};

pub const MEMORY_SIZE: usize = 1024;

/// The four Modbus tables of one device.
#[derive(Debug, Clone)]
pub struct Tables {
    pub coils: Vec<bool>,
    pub discrete: Vec<bool>,
    pub holding: Vec<u16>,
    pub input: Vec<u16>,
}

impl Default for Tables {
    fn default() -> Self {
        Tables {
            coils: vec![false; MEMORY_SIZE],
            discrete: vec![false; MEMORY_SIZE],
            holding: vec![0; MEMORY_SIZE],
            input: vec![0; MEMORY_SIZE],
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

fn range(address: u16, count: u16) -> Option<std::ops::Range<usize>> {
    let start = usize::from(address);
    let end = start + usize::from(count);
    (end <= MEMORY_SIZE && count > 0).then_some(start..end)
}

/// A device served by tokio-modbus's RTU or TCP server.
#[derive(Debug, Clone, Default)]
pub struct ModbusDevice {
    pub tables: Arc<Mutex<Tables>>,
    /// Every register written (FC06, FC16), as (address, value), in the order they came.
    pub writes: Arc<Mutex<Vec<(u16, u16)>>>,
}

impl tokio_modbus::server::Service for ModbusDevice {
    type Request = SlaveRequest<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = Ready<Result<Response, ExceptionCode>>;

    fn call(&self, req: SlaveRequest<'static>) -> Self::Future {
        let mut t = lock(&self.tables);
        let bad = ExceptionCode::IllegalDataAddress;
        let result = match req.request {
            Request::ReadCoils(a, n) => range(a, n)
                .map(|r| Response::ReadCoils(t.coils[r].to_vec()))
                .ok_or(bad),
            Request::ReadDiscreteInputs(a, n) => range(a, n)
                .map(|r| Response::ReadDiscreteInputs(t.discrete[r].to_vec()))
                .ok_or(bad),
            Request::ReadHoldingRegisters(a, n) => range(a, n)
                .map(|r| Response::ReadHoldingRegisters(t.holding[r].to_vec()))
                .ok_or(bad),
            Request::ReadInputRegisters(a, n) => range(a, n)
                .map(|r| Response::ReadInputRegisters(t.input[r].to_vec()))
                .ok_or(bad),
            Request::WriteSingleCoil(a, v) => range(a, 1)
                .map(|r| {
                    t.coils[r.start] = v;
                    Response::WriteSingleCoil(a, v)
                })
                .ok_or(bad),
            Request::WriteSingleRegister(a, v) => range(a, 1)
                .map(|r| {
                    t.holding[r.start] = v;
                    lock(&self.writes).push((a, v));
                    Response::WriteSingleRegister(a, v)
                })
                .ok_or(bad),
            Request::WriteMultipleCoils(a, values) => range(a, values.len() as u16)
                .map(|r| {
                    t.coils[r].copy_from_slice(&values);
                    Response::WriteMultipleCoils(a, values.len() as u16)
                })
                .ok_or(bad),
            Request::WriteMultipleRegisters(a, values) => range(a, values.len() as u16)
                .map(|r| {
                    t.holding[r].copy_from_slice(&values);
                    let mut log = lock(&self.writes);
                    log.extend((a..).zip(values.iter().copied()));
                    Response::WriteMultipleRegisters(a, values.len() as u16)
                })
                .ok_or(bad),
            _ => Err(ExceptionCode::IllegalFunction),
        };
        ready(result)
    }
}

/// Serves `device` with tokio-modbus's TCP server on a free loopback port.
pub async fn modbus_tcp_server(device: ModbusDevice) -> (u16, tokio::task::JoinHandle<()>) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let server = tokio_modbus::server::tcp::Server::new(listener);
    let task = tokio::spawn(async move {
        let on_connected = move |stream, addr| {
            let device = device.clone();
            async move {
                tokio_modbus::server::tcp::accept_tcp_connection(stream, addr, move |_| {
                    Ok(Some(device.clone()))
                })
            }
        };
        let _ = server.serve(&on_connected, |_| {}).await;
    });
    (port, task)
}

/// A pseudo-terminal pair whose gateway end is reachable at `path` (a symlink), so that a
/// test can "unplug" it and plug a new one in at the same path, as a USB adapter would.
/// Returns the device's end and a holder that keeps the gateway's end alive until the
/// gateway opens it; dropping both unplugs the port.
pub fn pty_at(path: &Path) -> anyhow::Result<(SerialStream, SerialStream)> {
    let (device, holder) = pty_pair()?;
    let name = holder
        .name()
        .ok_or_else(|| anyhow::anyhow!("the pty has no name"))?;
    let _ = std::fs::remove_file(path);
    std::os::unix::fs::symlink(&name, path)?;
    Ok((device, holder))
}

/// A pseudo-terminal pair whose descriptors are closed on exec: a broker or simulator
/// started later by the same process does not inherit them, so dropping both ends still
/// closes the line (an inherited device end would keep a pulled adapter plugged in forever).
/// The pair is opened without the flag and copied with it; the originals are closed at once.
pub fn pty_pair() -> anyhow::Result<(SerialStream, SerialStream)> {
    let (device, holder) = serialport::TTYPort::pair()?;
    let device = SerialStream::try_from(device.try_clone_native()?)?;
    let holder = SerialStream::try_from(holder.try_clone_native()?)?;
    Ok((device, holder))
}

/// A unique temporary directory for one test.
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "iogate-{name}-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos())
    ));
    let _ = std::fs::create_dir_all(&dir);
    dir
}

/// How a slave on [`RtuBus`] answers.
#[derive(Debug, Clone, PartialEq)]
pub enum Behaviour {
    Normal,
    /// Never answers.
    Silent,
    /// Answers after this long, with registers full of 0xBAD0.
    Late(Duration),
    /// Answers after this long, with its real data (a slow device).
    Slow(Duration),
    /// Answers with a corrupted CRC.
    BadCrc,
    /// Answers a register read with one register too few (and a valid CRC).
    WrongLength,
    /// Answers every request with this exception.
    Exception(u8),
    /// Answers with this slave id in its frames, not the one asked (a device set to
    /// another address than the one its label says, behind a gateway that rewrites it).
    AnswersAs(u8),
    /// Every second answer has a corrupted CRC (a noisy line).
    EverySecondGarbled,
}

#[derive(Debug, Clone)]
pub struct Slave {
    pub tables: Tables,
    pub behaviour: Behaviour,
    /// Reads that cover one of these addresses (any table) get exception 02.
    pub refused: Vec<u16>,
    /// An input register incremented on every read that covers it.
    pub counter: Option<u16>,
    /// Knows only single writes: FC15 and FC16 get exception 01.
    pub single_writes_only: bool,
    /// The next this many write requests get exception 06 (server device busy).
    pub busy_writes: u32,
    /// How many answers it sent.
    pub answers: u64,
}

impl Default for Slave {
    fn default() -> Self {
        Slave {
            tables: Tables::default(),
            behaviour: Behaviour::Normal,
            refused: Vec::new(),
            counter: None,
            single_writes_only: false,
            busy_writes: 0,
            answers: 0,
        }
    }
}

/// One request seen on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Seen {
    pub slave: u8,
    pub function: u8,
    pub address: u16,
    pub count: u16,
    /// FC06: the value written; FC16: the first value written.
    pub value: Option<u16>,
    /// When the request was read.
    pub at: std::time::Instant,
}

#[derive(Debug, Default)]
struct BusState {
    slaves: HashMap<u8, Slave>,
    seen: Vec<Seen>,
}

/// An RS-485 bus of slaves answering Modbus RTU, some of which may misbehave.
#[derive(Clone, Default)]
pub struct RtuBus {
    state: Arc<Mutex<BusState>>,
    /// When set, each answer comes after the wire time of request and answer at this baud
    /// rate (10 bits per character), as on a real line; a pty has no baud rate of its own.
    pub baud: Option<u32>,
}

impl RtuBus {
    /// A bus that answers as fast as a line at `baud` would.
    pub fn at_baud(baud: u32) -> Self {
        RtuBus {
            baud: Some(baud),
            ..RtuBus::default()
        }
    }

    pub fn slave(&self, id: u8, edit: impl FnOnce(&mut Slave)) {
        edit(lock(&self.state).slaves.entry(id).or_default());
    }

    pub fn read_slave<T>(&self, id: u8, read: impl FnOnce(&Slave) -> T) -> Option<T> {
        lock(&self.state).slaves.get(&id).map(read)
    }

    /// Every request seen so far.
    pub fn seen(&self) -> Vec<Seen> {
        lock(&self.state).seen.clone()
    }

    /// Every request seen since the last call (and forgets them).
    pub fn take_seen(&self) -> Vec<Seen> {
        std::mem::take(&mut lock(&self.state).seen)
    }

    pub fn clear_seen(&self) {
        lock(&self.state).seen.clear();
    }

    /// Serves the bus on a stream until it closes or the task is aborted.
    pub fn serve<S>(&self, stream: S) -> JoinHandle<()>
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let bus = self.clone();
        tokio::spawn(async move {
            let mut stream = stream;
            while let Ok(Some(frame)) = read_request(&mut stream).await {
                if let Some((delay, answer)) = bus.answer(&frame) {
                    let wire = bus.baud.map_or(Duration::ZERO, |baud| {
                        Duration::from_micros(
                            (frame.len() + answer.len()) as u64 * 10_000_000 / u64::from(baud),
                        )
                    });
                    let delay = delay + wire;
                    if !delay.is_zero() {
                        tokio::time::sleep(delay).await;
                    }
                    if stream.write_all(&answer).await.is_err() {
                        break;
                    }
                }
            }
        })
    }

    fn answer(&self, frame: &[u8]) -> Option<(Duration, Vec<u8>)> {
        let mut state = lock(&self.state);
        let (slave_id, function) = (frame[0], frame[1]);
        let address = u16::from_be_bytes([frame[2], frame[3]]);
        let count = match function {
            5 | 6 => 1,
            _ => u16::from_be_bytes([frame[4], frame[5]]),
        };
        state.seen.push(Seen {
            slave: slave_id,
            function,
            address,
            count,
            value: match function {
                6 => Some(u16::from_be_bytes([frame[4], frame[5]])),
                16 => frame.get(7..9).map(|v| u16::from_be_bytes([v[0], v[1]])),
                _ => None,
            },
            at: std::time::Instant::now(),
        });
        let slave = state.slaves.get_mut(&slave_id)?;
        let write = matches!(function, 5 | 6 | 15 | 16);
        let busy = write && slave.busy_writes > 0;
        if busy {
            slave.busy_writes -= 1;
        }
        let mut pdu = match &slave.behaviour {
            Behaviour::Silent => return None,
            _ if busy => vec![function | 0x80, 6],
            Behaviour::Exception(code) => vec![function | 0x80, *code],
            _ => respond(slave, function, address, count, &frame[..frame.len() - 2]),
        };
        let mut delay = Duration::ZERO;
        match slave.behaviour {
            Behaviour::Late(after) => {
                delay = after;
                if matches!(function, 3 | 4) && pdu.len() > 2 {
                    for pair in pdu[2..].chunks_exact_mut(2) {
                        pair.copy_from_slice(&0xBAD0u16.to_be_bytes());
                    }
                }
            }
            Behaviour::Slow(after) => delay = after,
            Behaviour::WrongLength if matches!(function, 3 | 4) && pdu.len() > 3 => {
                pdu.truncate(pdu.len() - 2);
                pdu[1] -= 2;
            }
            _ => {}
        }
        let id = match slave.behaviour {
            Behaviour::AnswersAs(other) => other,
            _ => slave_id,
        };
        let mut out = vec![id];
        out.extend_from_slice(&pdu);
        let mut crc = crc16(&out);
        slave.answers += 1;
        if slave.behaviour == Behaviour::BadCrc
            || (slave.behaviour == Behaviour::EverySecondGarbled && slave.answers % 2 == 0)
        {
            crc ^= 0xFFFF;
        }
        out.extend_from_slice(&crc.to_le_bytes());
        Some((delay, out))
    }
}

fn respond(slave: &mut Slave, function: u8, address: u16, count: u16, request: &[u8]) -> Vec<u8> {
    let exception = |code: u8| vec![function | 0x80, code];
    let Some(r) = range(address, count) else {
        return exception(2);
    };
    if slave.single_writes_only && matches!(function, 15 | 16) {
        return exception(1);
    }
    let reads = matches!(function, 1..=4);
    if reads && slave.refused.iter().any(|a| r.contains(&usize::from(*a))) {
        return exception(2);
    }
    if function == 4
        && let Some(c) = slave.counter.filter(|c| r.contains(&usize::from(*c)))
    {
        let i = usize::from(c);
        slave.tables.input[i] = slave.tables.input[i].wrapping_add(1);
    }
    let t = &mut slave.tables;
    let bits = |table: &[bool]| {
        let mut out = vec![function, 0];
        let mut packed = vec![0u8; r.len().div_ceil(8)];
        for (i, &b) in table[r.clone()].iter().enumerate() {
            if b {
                packed[i / 8] |= 1 << (i % 8);
            }
        }
        out[1] = packed.len() as u8;
        out.extend_from_slice(&packed);
        out
    };
    let regs = |table: &[u16]| {
        let mut out = vec![function, (r.len() * 2) as u8];
        for v in &table[r.clone()] {
            out.extend_from_slice(&v.to_be_bytes());
        }
        out
    };
    match function {
        1 => bits(&t.coils),
        2 => bits(&t.discrete),
        3 => regs(&t.holding),
        4 => regs(&t.input),
        5 => {
            t.coils[r.start] = request[4] == 0xFF;
            request[1..6].to_vec()
        }
        6 => {
            t.holding[r.start] = u16::from_be_bytes([request[4], request[5]]);
            request[1..6].to_vec()
        }
        15 => {
            for (i, slot) in t.coils[r.clone()].iter_mut().enumerate() {
                *slot = request[7 + i / 8] >> (i % 8) & 1 == 1;
            }
            request[1..6].to_vec()
        }
        16 => {
            for (i, slot) in t.holding[r.clone()].iter_mut().enumerate() {
                *slot = u16::from_be_bytes([request[7 + 2 * i], request[8 + 2 * i]]);
            }
            request[1..6].to_vec()
        }
        _ => exception(1),
    }
}

/// Reads one request frame (checked by CRC); `None` at the end of the stream.
async fn read_request<S: AsyncRead + Unpin>(stream: &mut S) -> std::io::Result<Option<Vec<u8>>> {
    loop {
        let mut frame = vec![0u8; 2];
        if stream.read_exact(&mut frame).await.is_err() {
            return Ok(None);
        }
        let rest = match frame[1] {
            1..=6 => 6,
            // FC 43 / MEI 14 (read device identification): MEI type, code, object, CRC.
            0x2B => 5,
            15 | 16 => {
                let mut head = [0u8; 5];
                stream.read_exact(&mut head).await?;
                frame.extend_from_slice(&head);
                usize::from(head[4]) + 2
            }
            _ => continue,
        };
        let start = frame.len();
        frame.resize(start + rest, 0);
        stream.read_exact(&mut frame[start..]).await?;
        let n = frame.len();
        if crc16(&frame[..n - 2]).to_le_bytes() == [frame[n - 2], frame[n - 1]] {
            return Ok(Some(frame));
        }
    }
}

/// CRC-16/MODBUS, written here again so the tests do not trust the gateway's.
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &byte in data {
        crc ^= u16::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// A Modbus TCP profile `name` of `fields` UINT input registers `R0` .. from address 0.
pub fn input_register_profile(name: &str, fields: usize) -> String {
    let mut text = format!("name: {name}\nprotocol: modbus-tcp\nfields:\n");
    for i in 0..fields {
        text.push_str(&format!(
            "  - {{ name: R{i}, type: UINT, direction: input, register: {{ address: {i}, kind: input_register }} }}\n"
        ));
    }
    text
}
