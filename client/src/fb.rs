//! The two Modbus function blocks for a scan-cycle runtime, run through the gateway's raw
//! transactions: [`ModbusRead`] (the modbus-read block of source document 004) and
//! [`ModbusWrite`] (the Modbus RTU write block of source document 002). A program calls
//! them every cycle; a call never blocks: a transaction runs in the background and its
//! outcome shows on a later call.

use std::time::Duration;

use tokio::task::JoinHandle;
use tokio::time::Instant;

use crate::proto::TransactRequest;
use crate::{Client, Error, TransactOutcome};

/// When the read block's main input starts a read.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputEdge {
    /// false -> true.
    Rising,
    /// true -> false.
    Falling,
    /// Any change of the logical state.
    Both,
    /// Every input that is true.
    True,
    /// Every input that is false.
    False,
    /// Every null input.
    Null,
    /// No triggering by input.
    None,
}

/// The read block's message for a bad `input_edge`.
pub const INVALID_INPUT_EDGE: &str = "Invalid input edge configuration.";
/// The read block's message for a bad `refreshInterval`.
pub const INVALID_REFRESH: &str = "Invalid refresh interval configuration.";

impl std::str::FromStr for InputEdge {
    type Err = &'static str;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s {
            "rising" => InputEdge::Rising,
            "falling" => InputEdge::Falling,
            "both" => InputEdge::Both,
            "true" => InputEdge::True,
            "false" => InputEdge::False,
            "null" => InputEdge::Null,
            "none" => InputEdge::None,
            _ => return Err(INVALID_INPUT_EDGE),
        })
    }
}

impl InputEdge {
    /// Whether the input `now` (None is null) starts a read, `last` being the last logical
    /// value the input had: a null is no logical value and is ignored by the edges
    /// (source document 004: "other values are ignored"), so false, null, true is a rising
    /// edge.
    pub fn fires(self, last: Option<bool>, now: Option<bool>) -> bool {
        let before = last;
        match self {
            InputEdge::Rising => before == Some(false) && now == Some(true),
            InputEdge::Falling => before == Some(true) && now == Some(false),
            InputEdge::Both => before.is_some() && now.is_some() && before != now,
            InputEdge::True => now == Some(true),
            InputEdge::False => now == Some(false),
            InputEdge::Null => now.is_none(),
            InputEdge::None => false,
        }
    }
}

/// The first cyclic read comes about this long after the block starts.
pub const FIRST_CYCLIC_READ: Duration = Duration::from_secs(2);

type Running = JoinHandle<Result<TransactOutcome, Error>>;

/// The modbus-read block: reads on an input edge and/or every `refresh_interval`.
/// Output 1 ([`ModbusRead::value`]) is the last value read correctly; output 2
/// ([`ModbusRead::ok`]) says whether the last read succeeded.
pub struct ModbusRead {
    client: Client,
    request: TransactRequest,
    edge: InputEdge,
    refresh: Duration,
    /// The input's last logical value (nulls do not change it).
    previous: Option<bool>,
    running: Option<Running>,
    next_cyclic: Option<Instant>,
    value: Option<f64>,
    ok: bool,
    status: String,
}

impl ModbusRead {
    /// A block reading with `request` (the one-shot transaction's parameters) on `link`.
    /// `refresh_interval` 0 disables cyclic reads; at most one hour.
    pub fn new(
        client: Client,
        request: TransactRequest,
        input_edge: &str,
        refresh_interval: Duration,
    ) -> Result<ModbusRead, Vec<&'static str>> {
        let mut errors = Vec::new();
        let edge = input_edge.parse::<InputEdge>().map_err(|e| errors.push(e));
        if refresh_interval > Duration::from_secs(3600) {
            errors.push(INVALID_REFRESH);
        }
        let edge = match edge {
            Ok(e) if errors.is_empty() => e,
            _ => return Err(errors),
        };
        Ok(ModbusRead {
            client,
            request,
            edge,
            refresh: refresh_interval,
            previous: None,
            running: None,
            next_cyclic: (!refresh_interval.is_zero()).then(|| Instant::now() + FIRST_CYCLIC_READ),
            value: None,
            ok: false,
            status: String::new(),
        })
    }

    /// One scan cycle with the main input (`None` is null). Returns (value, ok).
    pub fn call(&mut self, input: Option<bool>) -> (Option<f64>, bool) {
        let fired = self.edge.fires(self.previous, input);
        if input.is_some() {
            self.previous = input;
        }
        self.collect();
        let now = Instant::now();
        let cyclic = self.next_cyclic.is_some_and(|at| now >= at);
        // Triggers and cyclic reads are ignored while a read is in flight.
        if self.running.is_none() && (fired || cyclic) {
            if cyclic {
                self.next_cyclic = None;
            }
            let mut client = self.client.clone();
            let request = self.request.clone();
            self.running = Some(tokio::spawn(async move { client.transact(request).await }));
        }
        (self.value, self.ok)
    }

    /// Takes a finished read's outcome.
    fn collect(&mut self) {
        if !self.running.as_ref().is_some_and(JoinHandle::is_finished) {
            return;
        }
        let Some(handle) = self.running.take() else {
            return;
        };
        let outcome = futures_util::FutureExt::now_or_never(handle);
        match outcome {
            Some(Ok(Ok(o))) if o.actual => {
                self.value = o.value;
                self.ok = true;
                self.status = o.value.map(|v| v.to_string()).unwrap_or_default();
            }
            Some(Ok(Ok(o))) => {
                self.ok = false;
                self.status = o.error.unwrap_or_else(|| "Internal error".into());
            }
            // The gateway's words as they are (source document 004's messages, each on
            // its line), without the gRPC code a log line would add.
            Some(Ok(Err(Error::Status { message, .. }))) => {
                self.ok = false;
                self.status = message;
            }
            Some(Ok(Err(e))) => {
                self.ok = false;
                self.status = e.to_string();
            }
            _ => {
                self.ok = false;
                self.status = "Internal error".into();
            }
        }
        // The next cyclic read is scheduled once this one has finished.
        if !self.refresh.is_zero() {
            self.next_cyclic = Some(Instant::now() + self.refresh);
        }
    }

    /// Output 1: the last value read correctly (kept after an error).
    pub fn value(&self) -> Option<f64> {
        self.value
    }

    /// Output 2: the last read succeeded.
    pub fn ok(&self) -> bool {
        self.ok
    }

    /// The block's description: the value after a success, the error message after a
    /// failure.
    pub fn status(&self) -> &str {
        &self.status
    }

    /// Whether a read is in flight.
    pub fn busy(&self) -> bool {
        self.running.is_some()
    }
}

/// The Modbus write block: while `enable` is TRUE it sends its values, and again every
/// `polling_period` from the start of the previous transaction. Outputs `actual` and
/// `state` (0 not active, 1 waiting for access to the interface, 2 access received, 3 in
/// progress, 4 done, -1 interface unavailable, -2 response timeout, -3 unknown error).
pub struct ModbusWrite {
    client: Client,
    request: TransactRequest,
    polling_period: Duration,
    running: Option<Running>,
    started: Option<Instant>,
    calls_in_flight: u32,
    actual: bool,
    state: i32,
    was_enabled: bool,
}

impl ModbusWrite {
    /// The block for `request` (its function, slave, address, type, byte order and
    /// timeout), re-sending every `polling_period` while `enable` is held TRUE.
    pub fn new(client: Client, request: TransactRequest, polling_period: Duration) -> ModbusWrite {
        ModbusWrite {
            client,
            request,
            polling_period,
            running: None,
            started: None,
            calls_in_flight: 0,
            actual: false,
            state: 0,
            was_enabled: false,
        }
    }

    /// One scan cycle: `enable` and the values to write. Returns (actual, state).
    pub fn call(&mut self, enable: bool, values: &[f64]) -> (bool, i32) {
        let ended = self.collect();
        if let Some(_running) = &self.running {
            self.calls_in_flight += 1;
            self.state = if self.calls_in_flight == 1 { 2 } else { 3 };
        } else if enable {
            let due = !self.was_enabled
                || self
                    .started
                    .is_none_or(|s| Instant::now() >= s + self.polling_period);
            if due {
                let mut request = self.request.clone();
                request.values = values.to_vec();
                let mut client = self.client.clone();
                self.started = Some(Instant::now());
                self.calls_in_flight = 0;
                self.state = 1;
                self.running = Some(tokio::spawn(async move { client.transact(request).await }));
            }
        } else if !ended {
            // Not active. A transaction `enable` started still runs to its end after
            // `enable` drops (a one-cycle pulse), and the call that sees it end reports its
            // outcome (4, or the failure) for that cycle, as a DONE bit does.
            self.state = 0;
        }
        self.was_enabled = enable;
        (self.actual, self.state)
    }

    /// Takes a finished transaction's outcome; whether one ended.
    fn collect(&mut self) -> bool {
        if !self.running.as_ref().is_some_and(JoinHandle::is_finished) {
            return false;
        }
        let Some(handle) = self.running.take() else {
            return false;
        };
        match futures_util::FutureExt::now_or_never(handle) {
            Some(Ok(Ok(o))) => {
                self.actual = o.actual;
                self.state = o.state;
            }
            Some(Ok(Err(_))) => {
                self.actual = false;
                self.state = -1;
            }
            _ => {
                self.actual = false;
                self.state = -3;
            }
        }
        true
    }

    /// Output `actual`: the last command got a correct response.
    pub fn actual(&self) -> bool {
        self.actual
    }

    /// Output `state`: 0 not active, 1 waiting, 2 access, 3 in progress, 4 done, -1, -2, -3
    /// failures (source document 002).
    pub fn state(&self) -> i32 {
        self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_input_edge_fires_as_the_read_block_says() {
        use InputEdge as E;
        let t = Some(true);
        let f = Some(false);
        // (edge, before, now, fires)
        let cases = [
            (E::Rising, f, t, true),
            (E::Rising, t, t, false),
            (E::Rising, None, t, false),
            (E::Falling, t, f, true),
            (E::Falling, f, f, false),
            (E::Both, t, f, true),
            (E::Both, f, t, true),
            (E::Both, t, t, false),
            (E::Both, None, t, false),
            (E::True, t, t, true),
            (E::True, f, f, false),
            (E::False, f, f, true),
            (E::Null, t, None, true),
            (E::Null, None, t, false),
            (E::None, f, t, false),
        ];
        for (edge, before, now, fires) in cases {
            assert_eq!(
                edge.fires(before, now),
                fires,
                "{edge:?} {before:?} -> {now:?}"
            );
        }
        assert_eq!("sideways".parse::<InputEdge>(), Err(INVALID_INPUT_EDGE));
    }

    #[test]
    fn a_null_between_false_and_true_is_ignored_and_the_rising_edge_fires() {
        // What a block keeps as `last`: the input's last logical value.
        let mut last = None;
        let mut fired = Vec::new();
        for input in [Some(false), None, Some(true), None, Some(true)] {
            fired.push(InputEdge::Rising.fires(last, input));
            if input.is_some() {
                last = input;
            }
        }
        assert_eq!(fired, [false, false, true, false, false]);
    }
}
