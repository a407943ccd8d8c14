//! The pair's field: `pump`, tokio-modbus's Modbus TCP server, and `tank`, pymodbus
//! speaking RTU frames over TCP as a serial device server passes them on, each behind a
//! tap that logs every connection (and, for Modbus TCP, every write request on it);
//! pymodbus logs every write request it receives itself.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use iogate_tests::devices::{ModbusDevice, modbus_tcp_server};
use iogate_tests::tap::{Tap, modbus_writes};
use iogate_tests::{PATIENCE, Piped, python, repo_file, run_installer, spawn_piped};
use tokio::task::JoinHandle;

use crate::pair::WriteLog;

/// The setpoint's holding register.
const SETPOINT: u16 = 10;
pub const PROFILE: &str = "name: Setpoints\nvendor: test\nprotocol: modbus-rtu\ndescription: a setpoint and a level\nfields:\n  - { name: sp, type: UINT, direction: output, register: { address: 10, kind: holding_register } }\n  - { name: level, type: UINT, direction: input, register: { address: 11, kind: holding_register } }\n";

/// The device a value is written to: the client writes odd values to `pump`, even ones to
/// `tank`.
pub fn device_of(value: u16) -> &'static str {
    if value.is_multiple_of(2) {
        "tank"
    } else {
        "pump"
    }
}

/// A write request as the field received it: when, the register, the values.
type Received = (Instant, u16, Vec<u16>);

/// pymodbus's RTU-over-TCP slave (`tests/ha/rtu_slave.py`), with what it said it received.
struct RtuSlave {
    port: u16,
    received: Arc<Mutex<Vec<Received>>>,
    _reader: JoinHandle<()>,
}

impl RtuSlave {
    async fn start() -> anyhow::Result<RtuSlave> {
        run_installer("serial/install.sh")?;
        let mut command = tokio::process::Command::new(python());
        command.arg(repo_file("ha/rtu_slave.py"));
        let Piped {
            child, mut lines, ..
        } = spawn_piped(command)?;
        let line = tokio::time::timeout(PATIENCE, lines.next_line())
            .await??
            .ok_or_else(|| anyhow::anyhow!("the RTU slave ended before it listened"))?;
        let port = line.trim().parse()?;
        let received = Arc::new(Mutex::new(Vec::new()));
        let log = received.clone();
        let reader = tokio::spawn(async move {
            let _child = child;
            while let Ok(Some(line)) = lines.next_line().await {
                let words: Vec<u16> = line
                    .strip_prefix("write ")
                    .map(|w| w.split(' ').filter_map(|n| n.parse().ok()).collect())
                    .unwrap_or_default();
                if let Some((&register, values)) = words.split_first() {
                    let mut log = log.lock().unwrap_or_else(|e| e.into_inner());
                    log.push((Instant::now(), register, values.to_vec()));
                }
            }
        });
        Ok(RtuSlave {
            port,
            received,
            _reader: reader,
        })
    }
}

pub struct Field {
    /// `pump`'s tap.
    pub tap: Tap,
    /// `pump`'s tables, as the slave serves them.
    pub device: ModbusDevice,
    /// `tank`'s tap.
    pub rtu_tap: Tap,
    rtu: RtuSlave,
    _slave: JoinHandle<()>,
}

impl Field {
    pub async fn start() -> anyhow::Result<Field> {
        let device = ModbusDevice::default();
        let (port, slave) = modbus_tcp_server(device.clone()).await;
        let rtu = RtuSlave::start().await?;
        Ok(Field {
            tap: Tap::start(port).await?,
            device,
            rtu_tap: Tap::start(rtu.port).await?,
            rtu,
            _slave: slave,
        })
    }

    /// The links and devices of the gateways' configuration.
    pub fn config(&self) -> String {
        format!(
            "links:\n  - {{ name: field, tcp: {{ host: 127.0.0.1, port: {} }} }}\n\
             \x20 - {{ name: server, tcp: {{ host: 127.0.0.1, port: {}, framing: rtu }} }}\n\
             devices:\n  - {{ name: pump, profile: Setpoints, link: field, slave_id: 1, refresh_rate: 20ms }}\n\
             \x20 - {{ name: tank, profile: Setpoints, link: server, slave_id: 1, refresh_rate: 20ms }}\n",
            self.tap.port, self.rtu_tap.port
        )
    }

    /// Every setpoint value written on the field, with when and to which device.
    fn written(&self) -> Vec<(Instant, u16, &'static str)> {
        let pump = self.tap.passages();
        let pump = pump.iter().flat_map(modbus_writes).map(|w| (w, "pump"));
        let tank = self.rtu.received.lock().unwrap_or_else(|e| e.into_inner());
        let tank = tank.iter().cloned().map(|w| (w, "tank"));
        let mut all: Vec<(Instant, u16, &'static str)> = pump
            .chain(tank)
            .filter(|((_, at, _), _)| *at == SETPOINT)
            .flat_map(|((t, _, values), d)| values.into_iter().map(move |v| (t, v, d)))
            .collect();
        all.sort();
        all
    }

    /// No two connections to either field device were ever open at once: one master.
    pub fn assert_one_master_at_a_time(&self) {
        self.one_master(2);
    }

    /// As [`Self::assert_one_master_at_a_time`], where one node may have kept the field
    /// throughout; and every write said written is on the field once, nothing unasked.
    pub fn assert_one_master_at_a_time_or_one(&self, log: &WriteLog) {
        self.one_master(1);
        self.assert_written_once(log);
        self.assert_only_asked(log);
    }

    fn one_master(&self, at_least: usize) {
        for (device, tap) in [("pump", &self.tap), ("tank", &self.rtu_tap)] {
            let mut passages = tap.passages();
            passages.sort_by_key(|p| p.opened);
            assert!(
                passages.len() >= at_least,
                "{device} was reached by too few connections"
            );
            for w in passages.windows(2) {
                let closed = w[0].closed.unwrap_or_else(|| {
                    panic!(
                        "{device}: connection {} still open when {} opened: two masters",
                        w[0].id, w[1].id
                    )
                });
                assert!(
                    closed <= w[1].opened,
                    "{device}: connection {} was open {:?} after connection {} opened: two masters",
                    w[0].id,
                    closed - w[1].opened,
                    w[1].id
                );
            }
        }
    }

    /// Every write the gateways said was written is on the field, once, on the device it
    /// was asked of; no value is on the field twice.
    pub fn assert_written_once(&self, log: &WriteLog) {
        let on_field = self.written();
        for value in log.written() {
            let times: Vec<_> = on_field.iter().filter(|(_, v, _)| *v == value).collect();
            assert_eq!(
                times.len(),
                1,
                "value {value} was written {} times on the field",
                times.len()
            );
            assert_eq!(
                times[0].2,
                device_of(value),
                "value {value} on the wrong device"
            );
        }
        for device in ["pump", "tank"] {
            let n = on_field.iter().filter(|(_, _, d)| *d == device).count();
            assert!(n > 0, "nothing was written to {device}");
        }
        let mut values: Vec<u16> = on_field.iter().map(|(_, v, _)| *v).collect();
        values.sort_unstable();
        let before = values.len();
        values.dedup();
        assert_eq!(values.len(), before, "a value was written twice");
    }

    /// Nothing is on the field that the client did not ask for before it was written.
    pub fn assert_only_asked(&self, log: &WriteLog) {
        for (at, value, device) in self.written() {
            let asked = log.entries.iter().find(|e| e.value == value);
            let asked = asked.unwrap_or_else(|| panic!("{value} was written, never asked"));
            assert!(asked.at <= at, "{value} was written before it was asked");
            assert_eq!(device, device_of(value), "{value} was written to {device}");
        }
    }
}
