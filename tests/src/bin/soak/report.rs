//! The soak's report: what each door checked and found wrong, the writes and their
//! outcomes, the faults, and the gateway's memory and open files over time.

use std::time::{Duration, Instant};

use crate::doors::Ctx;
use crate::gauge::{Sample, slope_per_hour};

/// A line after each fault.
pub fn progress(ctx: &Ctx, started: Instant, faults: u32) {
    let wrong: u64 = ctx
        .tally
        .counts()
        .iter()
        .filter(|(k, _)| k.ends_with(" wrong"))
        .map(|(_, v)| v)
        .sum();
    eprintln!(
        "{:>6.1} min: {faults} faults, {} values checked, {wrong} wrong",
        started.elapsed().as_secs_f64() / 60.0,
        ctx.tally
            .counts()
            .iter()
            .filter(|(k, _)| k.ends_with(" checked"))
            .map(|(_, v)| v)
            .sum::<u64>(),
    );
}

/// Each link's state at the end (every fault undone: all should be connected).
pub async fn links(ctx: &Ctx) {
    if let Ok((_, links)) = ctx.gw.get("/api/v1/links").await {
        for l in links.as_array().into_iter().flatten() {
            let state = format!("{} {} {}", l["connected"], l["error_code"], l["error"]);
            println!("link {} at the end: {state}", l["name"]);
        }
    }
}

/// Prints the report; whether nothing was lost.
pub fn print(ctx: &Ctx, took: Duration, samples: &[Sample]) -> bool {
    println!("## Soak: {:.1} minutes\n", took.as_secs_f64() / 60.0);
    println!("| what | count |\n| --- | ---: |");
    for (key, n) in ctx.tally.counts() {
        println!("| {key} | {n} |");
    }
    let first = samples.first().copied().unwrap_or_default();
    let last = samples.last().copied().unwrap_or_default();
    let peak = samples.iter().map(|s| s.1).fold(0.0, f64::max);
    let rss = slope_per_hour(samples, |s| s.1);
    let fds = slope_per_hour(samples, |s| s.2);
    println!(
        "\nGateway resident memory: {:.1} MiB at the first sample, {:.1} at the last, {peak:.1} at most; slope {} MiB/h",
        first.1,
        last.1,
        rss.map_or("?".into(), |r| format!("{r:+.2}"))
    );
    println!(
        "Open files: {} first, {} last; slope {} per hour ({} samples)",
        first.2,
        last.2,
        fds.map_or("?".into(), |r| format!("{r:+.2}")),
        samples.len()
    );
    let notes = ctx.tally.notes();
    if !notes.is_empty() {
        println!("\nNotes (the first {}):", notes.len());
        for n in &notes {
            println!("- {n}");
        }
    }
    let wrongs = ctx.tally.wrongs();
    if wrongs.is_empty() {
        println!("\nNothing wrong.");
    } else {
        println!("\nWrong ({} kept):", wrongs.len());
        for w in &wrongs {
            println!("- {w}");
        }
    }
    wrongs.is_empty()
}
