//! The soak's field side: an RTU bus of three slaves on a pseudo-terminal, a Modbus TCP
//! device behind a cable that can be pulled, Snap7's S7 server and asyncua's OPC UA server;
//! each register holds a value that names its device and address, so a value read anywhere
//! is right or wrong by itself.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use iogate_tests::devices::{ModbusDevice, RtuBus, modbus_tcp_server, pty_at};
use iogate_tests::plc::UaPlc;
use iogate_tests::s7::S7Plc;
use tokio::task::{AbortHandle, JoinHandle};

/// The RTU slaves' ids.
pub const SLAVES: [u8; 3] = [1, 2, 3];
/// Input registers 0-4 of each Modbus device are read; holding register 10 is written.
pub const READ: u16 = 5;
pub const WRITTEN: u16 = 10;

/// What a field must read: by (device, field).
pub type Expected = HashMap<(String, String), f64>;

/// The value input register `address` of RTU slave `slave` holds.
pub fn rtu_value(slave: u8, address: u16) -> u16 {
    u16::from(slave) * 100 + address
}

/// The value input register `address` of the TCP device holds.
pub fn tcp_value(address: u16) -> u16 {
    5000 + address
}

/// The profiles the soak's config names.
pub fn profiles(ns: u64) -> Vec<(&'static str, String)> {
    let mut reg = String::from("name: SoakReg\nfields:\n");
    for a in 0..READ {
        reg.push_str(&format!(
            "  - {{ name: R{a}, type: UINT, direction: input, register: {{ address: {a}, kind: input_register }} }}\n"
        ));
    }
    reg.push_str(&format!(
        "  - {{ name: W, type: UINT, direction: output, register: {{ address: {WRITTEN}, kind: holding_register }} }}\n"
    ));
    let s7 = "name: SoakS7\nprotocol: s7\nfields:\n  - { name: A, type: INT, direction: input, address: DB1.DBW88 }\n  - { name: B, type: INT, direction: input, address: DB1.DBW254 }\n  - { name: F, type: BYTE, direction: input, address: DB1.DBB0 }\n".to_owned();
    let ua = format!(
        "name: SoakUa\nprotocol: opcua\nfields:\n  - {{ name: Big, type: DINT, direction: input, node: \"ns={ns};s=Line1.Big\" }}\n  - {{ name: Locked, type: INT, direction: input, node: \"ns={ns};s=Line1.Locked\" }}\n"
    );
    vec![("reg.yaml", reg), ("s7.yaml", s7), ("ua.yaml", ua)]
}

/// Every field's right value (the written `W` fields aside).
pub fn expected() -> Expected {
    let mut e = Expected::new();
    for s in SLAVES {
        for a in 0..READ {
            e.insert(
                (format!("rtu{s}"), format!("R{a}")),
                f64::from(rtu_value(s, a)),
            );
        }
    }
    for a in 0..READ {
        e.insert(("tcp1".into(), format!("R{a}")), f64::from(tcp_value(a)));
    }
    // What tests/s7/plc.py and tests/opcua/plc.py hold.
    for (field, value) in [("A", 250.0), ("B", 258.0), ("F", 170.0)] {
        e.insert(("press".into(), field.into()), value);
    }
    for (field, value) in [("Big", 40000.0), ("Locked", 7.0)] {
        e.insert(("line1".into(), field.into()), value);
    }
    e
}

/// The RTU bus on its pseudo-terminal, which can be pulled out and plugged in again.
pub struct Line {
    pub bus: RtuBus,
    pub port: PathBuf,
    serving: Option<(JoinHandle<()>, tokio_serial::SerialStream)>,
}

impl Line {
    /// The bus, not plugged in yet: plug it in after the gateway's process has started, so
    /// that the gateway does not inherit the pseudo-terminal's device end (which would keep
    /// the port alive after it is pulled).
    pub fn new(dir: &Path) -> Line {
        let bus = RtuBus::default();
        for s in SLAVES {
            bus.slave(s, |slave| {
                for a in 0..READ {
                    slave.tables.input[usize::from(a)] = rtu_value(s, a);
                }
            });
        }
        Line {
            bus,
            port: dir.join("ttySOAK"),
            serving: None,
        }
    }

    /// A new pseudo-terminal at the port's path, the bus answering on it.
    pub fn plug(&mut self) -> anyhow::Result<()> {
        let (device_end, holder) = pty_at(&self.port)?;
        self.serving = Some((self.bus.serve(device_end), holder));
        Ok(())
    }

    /// The adapter pulled out: the port gone.
    pub fn pull(&mut self) {
        if let Some((task, _holder)) = self.serving.take() {
            task.abort();
        }
        let _ = std::fs::remove_file(&self.port);
    }
}

/// The TCP device, reached through a cable: pulled, every connection is cut and new ones
/// are closed at once.
pub struct Cable {
    pub device: ModbusDevice,
    pub port: u16,
    plugged: Arc<std::sync::atomic::AtomicBool>,
    connections: Arc<Mutex<Vec<AbortHandle>>>,
    _tasks: Vec<JoinHandle<()>>,
}

impl Cable {
    pub async fn new() -> anyhow::Result<Cable> {
        let device = ModbusDevice::default();
        {
            let mut t = device
                .tables
                .lock()
                .map_err(|_| anyhow::anyhow!("poisoned"))?;
            for a in 0..READ {
                t.input[usize::from(a)] = tcp_value(a);
            }
        }
        let (upstream, server) = modbus_tcp_server(device.clone()).await;
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
        let port = listener.local_addr()?.port();
        let plugged = Arc::new(std::sync::atomic::AtomicBool::new(true));
        let connections: Arc<Mutex<Vec<AbortHandle>>> = Arc::default();
        let (on, held) = (plugged.clone(), connections.clone());
        let proxy = tokio::spawn(async move {
            while let Ok((mut client, _)) = listener.accept().await {
                if !on.load(std::sync::atomic::Ordering::SeqCst) {
                    continue;
                }
                let task = tokio::spawn(async move {
                    if let Ok(mut up) =
                        tokio::net::TcpStream::connect(("127.0.0.1", upstream)).await
                    {
                        let _ = tokio::io::copy_bidirectional(&mut client, &mut up).await;
                    }
                });
                if let Ok(mut list) = held.lock() {
                    list.retain(|h| !h.is_finished());
                    list.push(task.abort_handle());
                }
            }
        });
        Ok(Cable {
            device,
            port,
            plugged,
            connections,
            _tasks: vec![server, proxy],
        })
    }

    pub fn pull(&self) {
        self.plugged
            .store(false, std::sync::atomic::Ordering::SeqCst);
        if let Ok(mut list) = self.connections.lock() {
            for h in list.drain(..) {
                h.abort();
            }
        }
    }

    pub fn plug(&self) {
        self.plugged
            .store(true, std::sync::atomic::Ordering::SeqCst);
    }

    /// The values written to holding register [`WRITTEN`], in the order they came.
    pub fn written(&self) -> Vec<u16> {
        self.device
            .writes
            .lock()
            .map(|w| {
                w.iter()
                    .filter(|(a, _)| *a == WRITTEN)
                    .map(|(_, v)| *v)
                    .collect()
            })
            .unwrap_or_default()
    }
}

/// The PLCs in their own processes, restarted on their ports.
pub struct Plcs {
    pub s7: S7Plc,
    pub ua: Option<UaPlc>,
    pub ua_port: String,
}

impl Plcs {
    pub async fn start() -> anyhow::Result<Plcs> {
        let s7 = S7Plc::start(None).await?;
        let ua = UaPlc::start(&[]).await?;
        let ua_port = ua.port();
        Ok(Plcs {
            s7,
            ua: Some(ua),
            ua_port,
        })
    }

    /// Ends the OPC UA server's process (the PLC switched off).
    pub fn switch_ua_off(&mut self) {
        self.ua = None;
    }

    pub async fn switch_ua_on(&mut self) -> anyhow::Result<()> {
        self.ua = Some(UaPlc::start(&["--port", &self.ua_port]).await?);
        Ok(())
    }
}
