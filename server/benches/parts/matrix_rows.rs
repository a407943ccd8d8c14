//! The matrix's rows and the published figures printed beside them (see `benches/matrix.rs`).
//!
//! NG Gateway: <https://ng-gateway.com/en/guide/benchmark/modbus.html>, a Docker container
//! capped at 1 CPU and 1,000 MiB on a 4-core Debian 12 host, memory and CPU as cAdvisor saw
//! them. NeuronEX 3.2.1 as EMQ published it, on 4 cores. Their devices are simulators of
//! their own; the hardware is not this machine's, so a ratio says more than a difference.

use std::time::Duration;

/// A row of the matrix.
pub struct Case {
    /// For `IOGATE_BENCH_ONLY`.
    pub name: &'static str,
    pub fields: usize,
    pub devices_a_channel: usize,
    /// The devices' `refresh_rate`.
    pub rate: &'static str,
    /// NG Gateway: MiB and CPU (% of its one CPU) where published.
    pub ng: Option<(f64, Option<f64>)>,
    /// NeuronEX 3.2.1: MB and CPU %.
    pub neuronex: (f64, f64),
    /// Whether the 100 writes are timed under this row's load.
    pub writes: bool,
}

impl Case {
    pub fn period(&self) -> Duration {
        if self.rate == "100ms" {
            Duration::from_millis(100)
        } else {
            Duration::from_secs(1)
        }
    }
}

pub const CASES: &[Case] = &[
    Case {
        name: "10k",
        fields: 10_000,
        devices_a_channel: 10,
        rate: "1s",
        ng: Some((50.8, Some(2.6))),
        neuronex: (199.0, 3.0),
        writes: false,
    },
    Case {
        name: "50k",
        fields: 50_000,
        devices_a_channel: 10,
        rate: "1s",
        ng: Some((103.0, Some(4.4))),
        neuronex: (327.0, 13.0),
        writes: false,
    },
    Case {
        name: "100k",
        fields: 100_000,
        devices_a_channel: 10,
        rate: "1s",
        ng: Some((153.0, Some(7.0))),
        neuronex: (497.0, 30.0),
        writes: true,
    },
    Case {
        name: "1k@100ms",
        fields: 1_000,
        devices_a_channel: 1,
        rate: "100ms",
        ng: Some((44.8, None)),
        neuronex: (128.0, 2.0),
        writes: false,
    },
    Case {
        name: "5k@100ms",
        fields: 5_000,
        devices_a_channel: 5,
        rate: "100ms",
        ng: None,
        neuronex: (165.0, 12.0),
        writes: false,
    },
    Case {
        name: "10k@100ms",
        fields: 10_000,
        devices_a_channel: 10,
        rate: "100ms",
        ng: Some((55.2, Some(7.6))),
        neuronex: (189.0, 21.0),
        writes: false,
    },
];

/// Request (sent) to the device's log, in ms.
pub struct Writes {
    pub min: f64,
    pub avg: f64,
    pub max: f64,
}

impl Writes {
    pub fn of(took: &[f64]) -> Writes {
        Writes {
            min: took.iter().copied().fold(f64::INFINITY, f64::min),
            avg: took.iter().sum::<f64>() / took.len().max(1) as f64,
            max: took.iter().copied().fold(0.0, f64::max),
        }
    }
}

/// What one row measured of the gateway.
pub struct Measured {
    pub rss_mib: f64,
    /// Share of one core.
    pub cpu: f64,
    pub bytes_a_second: f64,
    /// Polls answered against those planned.
    pub answered: f64,
    pub writes: Option<Writes>,
}

fn ratio(ours: f64, theirs: Option<f64>) -> String {
    theirs.map_or("".into(), |t| format!("{:.2}", ours / t))
}

/// The table, then the writes.
pub fn print(rows: &[(&Case, Measured)]) {
    println!(
        "| fields, every | iogate RSS | iogate CPU | polls answered | Modbus bytes/s | NG Gateway (1 CPU) | NeuronEX 3.2.1 (4 cores) | RSS / NG | CPU / NG |"
    );
    println!("| --- | ---: | ---: | ---: | ---: | --- | --- | ---: | ---: |");
    for (case, m) in rows {
        let ng = case.ng.map_or("not published".into(), |(mib, cpu)| {
            format!(
                "{mib} MiB, {}",
                cpu.map_or("CPU not published".into(), |c| format!("{c} %"))
            )
        });
        println!(
            "| {}, {} | {:.1} MiB | {:.1} % | {:.3} | {:.0} KiB | {ng} | {} MB, {} % | {} | {} |",
            case.fields,
            case.rate,
            m.rss_mib,
            m.cpu * 100.0,
            m.answered,
            m.bytes_a_second / 1024.0,
            case.neuronex.0,
            case.neuronex.1,
            ratio(m.rss_mib, case.ng.map(|n| n.0)),
            ratio(m.cpu * 100.0, case.ng.and_then(|n| n.1)),
        );
    }
    println!("\nGoal: RSS / NG and CPU / NG at most 0.33 in every row.\n");
    for (case, m) in rows {
        if let Some(w) = &m.writes {
            println!(
                "100 writes through REST under the {}-field load, request to the device's log: min {:.2} ms, avg {:.2} ms, max {:.2} ms (NG Gateway avg 75.6 ms, 14.6-536.5; NeuronEX avg 523 ms, 85-778; goal avg < 10 ms, max < 50 ms)",
                case.fields, w.min, w.avg, w.max
            );
        }
    }
}
