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
    /// Holding registers (UINT fields) of each device, read from its first.
    pub fields_a_device: u16,
    pub devices_a_channel: usize,
    /// The devices' `refresh_rate`.
    pub rate: &'static str,
    /// NG Gateway: MiB and CPU (% of its one CPU) where published.
    pub ng: Option<(f64, Option<f64>)>,
    /// EMQ's published figure for the load (NeuronEX 3.2.1, or Neuron 2.2.1).
    pub neuron: &'static str,
    /// Whether the 100 writes are timed under this row's load.
    pub writes: bool,
}

impl Case {
    pub fn period(&self) -> Duration {
        match self.rate {
            "100ms" => Duration::from_millis(100),
            "500ms" => Duration::from_millis(500),
            _ => Duration::from_secs(1),
        }
    }

    /// Each device's registers are read in this many requests (125 registers each).
    pub fn requests_a_device(&self) -> f64 {
        f64::from(self.fields_a_device.div_ceil(125))
    }
}

pub const CASES: &[Case] = &[
    Case {
        name: "10k",
        fields: 10_000,
        fields_a_device: 1000,
        devices_a_channel: 10,
        rate: "1s",
        ng: Some((50.8, Some(2.6))),
        neuron: "NeuronEX 199 MB, 3 %",
        writes: false,
    },
    Case {
        name: "50k",
        fields: 50_000,
        fields_a_device: 1000,
        devices_a_channel: 10,
        rate: "1s",
        ng: Some((103.0, Some(4.4))),
        neuron: "NeuronEX 327 MB, 13 %",
        writes: false,
    },
    Case {
        name: "100k",
        fields: 100_000,
        fields_a_device: 1000,
        devices_a_channel: 10,
        rate: "1s",
        ng: Some((153.0, Some(7.0))),
        neuron: "NeuronEX 497 MB, 30 %",
        writes: true,
    },
    Case {
        name: "1k@100ms",
        fields: 1_000,
        fields_a_device: 1000,
        devices_a_channel: 1,
        rate: "100ms",
        ng: Some((44.8, None)),
        neuron: "NeuronEX 128 MB, 2 %",
        writes: false,
    },
    Case {
        name: "5k@100ms",
        fields: 5_000,
        fields_a_device: 1000,
        devices_a_channel: 5,
        rate: "100ms",
        ng: None,
        neuron: "NeuronEX 165 MB, 12 %",
        writes: false,
    },
    Case {
        name: "10k@100ms",
        fields: 10_000,
        fields_a_device: 1000,
        devices_a_channel: 10,
        rate: "100ms",
        ng: Some((55.2, Some(7.6))),
        neuron: "NeuronEX 189 MB, 21 %",
        writes: false,
    },
    Case {
        name: "500x30@1s",
        fields: 15_000,
        fields_a_device: 30,
        devices_a_channel: 1,
        rate: "1s",
        ng: None,
        neuron: "Neuron 2.2.1 about 124 % of a core (4 cores)",
        writes: true,
    },
    Case {
        name: "500x30@500ms",
        fields: 15_000,
        fields_a_device: 30,
        devices_a_channel: 1,
        rate: "500ms",
        ng: None,
        neuron: "Neuron 2.2.1 about 111 % of a core (4 cores)",
        writes: true,
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
        "| fields (a device), every | iogate RSS | iogate CPU | polls answered | Modbus bytes/s | NG Gateway (1 CPU) | EMQ (4 cores) | RSS / NG | CPU / NG |"
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
            "| {} ({}), {} | {:.1} MiB | {:.1} % | {:.3} | {:.0} KiB | {ng} | {} | {} | {} |",
            case.fields,
            case.fields_a_device,
            case.rate,
            m.rss_mib,
            m.cpu * 100.0,
            m.answered,
            m.bytes_a_second / 1024.0,
            case.neuron,
            ratio(m.rss_mib, case.ng.map(|n| n.0)),
            ratio(m.cpu * 100.0, case.ng.and_then(|n| n.1)),
        );
    }
    println!(
        "\nGoal: RSS / NG and CPU / NG at most 0.33 in every row; 500 devices of 30 fields each on its own connection: under 15 % of a core.\n"
    );
    for (case, m) in rows {
        if let Some(w) = &m.writes {
            println!(
                "100 writes through REST under the {}-field load ({} a device, every {}), request to the device's log: min {:.2} ms, avg {:.2} ms, max {:.2} ms (NG Gateway avg 75.6 ms, 14.6-536.5; NeuronEX avg 523 ms, 85-778; Neuron 2.2.1 with 500 devices: 50 points avg 91 ms; goal avg < 10 ms, max < 50 ms)",
                case.fields, case.fields_a_device, case.rate, w.min, w.avg, w.max
            );
        }
    }
}
