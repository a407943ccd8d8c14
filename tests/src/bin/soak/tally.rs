//! What the soak counts, by name, and what it saw wrong, kept for the report.

use std::collections::BTreeMap;
use std::sync::Mutex;

use serde_json::Value;

use crate::field::Expected;

#[derive(Default)]
pub struct Tally {
    counts: Mutex<BTreeMap<String, u64>>,
    /// The first wrong things seen, with what they were.
    wrong: Mutex<Vec<String>>,
    /// The first of other things worth a look (a write's failure, a door's error).
    notes: Mutex<Vec<String>>,
}

impl Tally {
    pub fn add(&self, key: &str, n: u64) {
        if let Ok(mut c) = self.counts.lock() {
            *c.entry(key.to_owned()).or_default() += n;
        }
    }

    pub fn counts(&self) -> BTreeMap<String, u64> {
        self.counts.lock().map(|c| c.clone()).unwrap_or_default()
    }

    /// Counts `what` as wrong and keeps its first 50 descriptions.
    pub fn wrong(&self, door: &str, what: String) {
        self.add(&format!("{door} wrong"), 1);
        if let Ok(mut w) = self.wrong.lock()
            && w.len() < 50
        {
            w.push(format!("{door}: {what}"));
        }
    }

    /// Keeps `what` when fewer than 40 notes are kept.
    pub fn note(&self, what: String) {
        if let Ok(mut n) = self.notes.lock()
            && n.len() < 40
        {
            n.push(what);
        }
    }

    pub fn notes(&self) -> Vec<String> {
        self.notes.lock().map(|n| n.clone()).unwrap_or_default()
    }

    pub fn wrongs(&self) -> Vec<String> {
        self.wrong.lock().map(|w| w.clone()).unwrap_or_default()
    }

    /// Checks a field's value as a door told it (REST's JSON: `device`, `field`, `value`,
    /// `quality`): a good value must be the one its register holds.
    pub fn check_json(&self, door: &str, expected: &Expected, v: &Value) {
        let (Some(device), Some(field)) = (v["device"].as_str(), v["field"].as_str()) else {
            return;
        };
        self.check(door, expected, device, field, &v["value"], &v["quality"]);
    }

    pub fn check(
        &self,
        door: &str,
        expected: &Expected,
        device: &str,
        field: &str,
        value: &Value,
        quality: &Value,
    ) {
        let Some(want) = expected.get(&(device.to_owned(), field.to_owned())) else {
            return;
        };
        if quality != "good" {
            self.add(&format!("{door} not good ({device})"), 1);
            return;
        }
        self.add(&format!("{door} checked"), 1);
        if value.as_f64() != Some(*want) {
            self.wrong(door, format!("{device}.{field} = {value}, not {want}"));
        }
    }
}
