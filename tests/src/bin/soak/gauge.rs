//! The gateway process watched from outside: its resident memory and open files every ten
//! seconds (with their slope per hour, fitted after the first tenth of the run), and
//! whether `/readyz` tells the truth: 200 exactly while no link is stalled.

use std::time::{Duration, Instant};

use crate::doors::Ctx;

/// One sample: seconds since the start, resident MiB, open files.
pub type Sample = (f64, f64, f64);

/// Samples until the soak ends.
pub async fn watch(ctx: Ctx, pid: u32) -> Vec<Sample> {
    let start = Instant::now();
    let mut samples = Vec::new();
    let mut tick = tokio::time::interval(Duration::from_secs(10));
    loop {
        tokio::select! {
            _ = ctx.stop.cancelled() => return samples,
            _ = tick.tick() => {}
        }
        if let Some((rss, fds)) = process(pid) {
            samples.push((start.elapsed().as_secs_f64(), rss, fds));
        }
        readyz(&ctx).await;
    }
}

/// Resident MiB and open files of `pid`.
fn process(pid: u32) -> Option<(f64, f64)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))?
        .split_whitespace()
        .next()?
        .parse()
        .ok()?;
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd")).ok()?.count();
    Some((kb / 1024.0, fds as f64))
}

/// Whether `/readyz` and the stalled links agree.
async fn readyz(ctx: &Ctx) {
    let status = ctx
        .gw
        .client
        .get(ctx.gw.url("/readyz"))
        .send()
        .await
        .map(|r| r.status().as_u16());
    let metrics = ctx.gw.metrics().await;
    let (Ok(status), Ok(metrics)) = (status, metrics) else {
        ctx.tally.add("readyz errors", 1);
        return;
    };
    let stalled = metrics
        .lines()
        .any(|l| l.starts_with("iogate_link_stalled{") && l.ends_with(" 1"));
    ctx.tally.add("readyz checked", 1);
    if (status == 200) == stalled {
        ctx.tally.wrong(
            "readyz",
            format!("answered {status} while a link stalled: {stalled}"),
        );
    }
}

/// The least-squares slope per hour of `value` over the samples after the first tenth.
pub fn slope_per_hour(samples: &[Sample], value: impl Fn(&Sample) -> f64) -> Option<f64> {
    let kept = &samples[samples.len() / 10..];
    if kept.len() < 3 {
        return None;
    }
    let n = kept.len() as f64;
    let mean_t = kept.iter().map(|s| s.0).sum::<f64>() / n;
    let mean_v = kept.iter().map(&value).sum::<f64>() / n;
    let (mut num, mut den) = (0.0, 0.0);
    for s in kept {
        num += (s.0 - mean_t) * (value(s) - mean_v);
        den += (s.0 - mean_t).powi(2);
    }
    (den > 0.0).then(|| num / den * 3600.0)
}
