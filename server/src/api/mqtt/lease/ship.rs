//! What the active of a pair ships to its standby over the broker, beside the lease: every
//! write record as it begins and as it ends (`iogate/ha/<group>/writes`, QoS 0, never
//! retained: a record is state, not a command, and the standby writes none of them). A
//! standby that comes says so (`iogate/ha/<group>/hello`) and the active ships each field's
//! newest record and every pending one again.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};
use tokio::time::Instant;

use super::super::conn::{ConnError, Connection};
use crate::codec::Value;
use crate::write_log::{Origin, WriteLog, WriteRecord, WriteStatus};

/// Records in one message at most.
const BATCH: usize = 256;

/// One message of records.
#[derive(Debug, Serialize, Deserialize)]
pub(super) struct Shipment {
    /// The epoch of the node that shipped it.
    epoch: u64,
    /// Records the active's journal dropped (full) before these.
    #[serde(default)]
    dropped: u64,
    records: Vec<Shipped>,
}

#[derive(Debug, Serialize, Deserialize)]
struct Shipped {
    generation: u64,
    device: String,
    field: String,
    value: Option<Wire>,
    status: String,
    origin: String,
    attempts: u32,
    error: Option<String>,
    requested_ms: u64,
    finished_ms: Option<u64>,
    #[serde(default)]
    forgets: bool,
}

/// A value exactly as the gateway holds it (floats by their bits: NaN and -0.0 survive).
#[derive(Debug, Serialize, Deserialize)]
#[serde(tag = "t", content = "v", rename_all = "lowercase")]
enum Wire {
    Bool(bool),
    Int(i64),
    Uint(u64),
    Real(u32),
    Lreal(u64),
    String(String),
    Time(i64),
}

impl From<&Value> for Wire {
    fn from(v: &Value) -> Wire {
        match v {
            Value::Bool(b) => Wire::Bool(*b),
            Value::Int(i) => Wire::Int(*i),
            Value::UInt(u) => Wire::Uint(*u),
            Value::Real(f) => Wire::Real(f.to_bits()),
            Value::LReal(f) => Wire::Lreal(f.to_bits()),
            Value::String(s) => Wire::String(s.clone()),
            Value::Time(t) => Wire::Time(*t),
        }
    }
}

impl From<Wire> for Value {
    fn from(w: Wire) -> Value {
        match w {
            Wire::Bool(b) => Value::Bool(b),
            Wire::Int(i) => Value::Int(i),
            Wire::Uint(u) => Value::UInt(u),
            Wire::Real(bits) => Value::Real(f32::from_bits(bits)),
            Wire::Lreal(bits) => Value::LReal(f64::from_bits(bits)),
            Wire::String(s) => Value::String(s),
            Wire::Time(t) => Value::Time(t),
        }
    }
}

fn ms(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis().min(u128::from(u64::MAX)) as u64)
}

impl From<&WriteRecord> for Shipped {
    fn from(r: &WriteRecord) -> Shipped {
        Shipped {
            generation: r.generation,
            device: r.device.clone(),
            field: r.field.clone(),
            value: r.value.as_ref().map(Wire::from),
            status: r.status.name().to_owned(),
            origin: r.origin.name().to_owned(),
            attempts: r.attempts,
            error: r.error.clone(),
            requested_ms: ms(r.requested),
            finished_ms: r.finished.map(ms),
            forgets: r.forgets,
        }
    }
}

impl Shipped {
    /// The record, or `None` when a name in it is not one this build knows.
    fn record(self) -> Option<WriteRecord> {
        let status = [
            WriteStatus::Pending,
            WriteStatus::Written,
            WriteStatus::Superseded,
            WriteStatus::Failed,
        ]
        .into_iter()
        .find(|s| s.name() == self.status)?;
        let origin = [
            Origin::Client,
            Origin::Replay,
            Origin::Reconcile,
            Origin::Safety,
        ]
        .into_iter()
        .find(|o| o.name() == self.origin)?;
        let at = |ms| UNIX_EPOCH + Duration::from_millis(ms);
        Some(WriteRecord {
            generation: self.generation,
            device: self.device,
            field: self.field,
            value: self.value.map(Value::from),
            status,
            origin,
            attempts: self.attempts,
            error: self.error,
            requested: at(self.requested_ms),
            finished: self.finished_ms.map(at),
            forgets: self.forgets,
        })
    }
}

/// How often an active ships at most: a record journaled after a quiet spell goes at
/// once, those that follow it closely wait and go together (fewer, larger messages for
/// the standby to read). A kill can lose this much more.
const GATHER: Duration = Duration::from_millis(20);

/// When the journal's records are shipped next.
pub(super) struct Gathering {
    last: Instant,
    at: Option<Instant>,
}

impl Gathering {
    pub(super) fn new() -> Gathering {
        Gathering {
            last: Instant::now()
                .checked_sub(GATHER)
                .unwrap_or_else(Instant::now),
            at: None,
        }
    }

    /// Whether a shipment is waiting for its time.
    pub(super) fn waiting(&self) -> bool {
        self.at.is_some()
    }

    /// The journal has records: they go at once, or a gathering after the last shipment.
    pub(super) fn journaled(&mut self) {
        self.at = Some(Instant::now().max(self.last + GATHER));
    }

    /// When the waiting shipment is due (far away when none is).
    pub(super) fn due(&self) -> Instant {
        self.at
            .unwrap_or_else(|| Instant::now() + Duration::from_secs(3600))
    }

    pub(super) fn shipped(&mut self) {
        self.at = None;
        self.last = Instant::now();
    }
}

/// Ships what the journal holds, in messages of at most [`BATCH`] records.
pub(super) async fn ship(
    conn: &mut Connection,
    topic: &str,
    epoch: u64,
    log: &WriteLog,
) -> Result<(), ConnError> {
    loop {
        let (records, dropped) = log.drain_journal(BATCH);
        if records.is_empty() {
            return Ok(());
        }
        if dropped > 0 {
            tracing::warn!(
                dropped,
                "HA: the journal for the standby was full: records dropped"
            );
        }
        let shipment = Shipment {
            epoch,
            dropped,
            records: records.iter().map(Shipped::from).collect(),
        };
        let payload = serde_json::to_vec(&shipment).unwrap_or_default();
        conn.publish(topic, &payload, 0, false, 0).await?;
        if records.len() < BATCH {
            return conn.flush().await;
        }
    }
}

/// Publishes what clients declared here, retained: the pair's declarations.
pub(super) async fn declared(
    conn: &mut Connection,
    topic: &str,
    service: &crate::service::Service,
) -> Result<(), ConnError> {
    conn.publish(topic, &service.declared_set(), 0, true, 0)
        .await?;
    conn.flush().await
}

/// The records of a shipment, those this build can read; `None` for a payload that is not
/// a shipment at all (logged by the caller).
pub(super) fn unpack(payload: &[u8]) -> Option<(u64, Vec<WriteRecord>)> {
    let shipment: Shipment = serde_json::from_slice(payload).ok()?;
    let records = shipment
        .records
        .into_iter()
        .filter_map(Shipped::record)
        .collect();
    Some((shipment.epoch, records))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_crosses_exactly_floats_included() {
        let record = WriteRecord {
            generation: crate::role::first_generation(3) + 7,
            device: "pump".into(),
            field: "speed".into(),
            value: Some(Value::Real(-0.0)),
            status: WriteStatus::Failed,
            origin: Origin::Reconcile,
            attempts: 2,
            error: Some("refused".into()),
            requested: UNIX_EPOCH + Duration::from_millis(1_700_000_000_123),
            finished: Some(UNIX_EPOCH + Duration::from_millis(1_700_000_000_456)),
            forgets: true,
        };
        let shipment = Shipment {
            epoch: 3,
            dropped: 0,
            records: vec![Shipped::from(&record)],
        };
        let bytes = serde_json::to_vec(&shipment).expect("encoded");
        let (epoch, back) = unpack(&bytes).expect("a shipment");
        assert_eq!(epoch, 3);
        assert_eq!(back.len(), 1);
        let Some(Value::Real(f)) = back[0].value else {
            panic!("not a REAL: {:?}", back[0].value)
        };
        assert!(f == 0.0 && f.is_sign_negative());
        assert_eq!(back[0].status, WriteStatus::Failed);
        assert_eq!(back[0].origin, Origin::Reconcile);
        assert_eq!(back[0].requested, record.requested);
        assert!(back[0].forgets);
    }

    #[test]
    fn a_shipment_from_a_stranger_is_not_taken() {
        assert!(unpack(b"{\"epoch\":1}").is_none());
        assert!(unpack(b"not json").is_none());
        let odd = br#"{"epoch":1,"records":[{"generation":5,"device":"d","field":"f","value":null,"status":"exploded","origin":"client","attempts":0,"error":null,"requested_ms":0,"finished_ms":null}]}"#;
        assert_eq!(unpack(odd).map(|(_, r)| r.len()), Some(0));
    }
}
