//! A gateway in a process of its own, for tests that kill it: reads the config file given
//! as its argument (adjusted as the in-process test gateway is: loopback listeners on free
//! ports, the repository's profiles), prints `http <address>` once it serves, and runs
//! until SIGTERM or SIGKILL. With `--file` before it, the config file is the gateway's own,
//! as `iogate serve` reads it (its listeners as it says, reloads from it).

use std::io::Write;
use std::path::PathBuf;

/// The shipped binary's allocator (`server/src/main.rs`), so that what the benchmarks and
/// the soak measure of this process is what `iogate serve` would do.
#[global_allocator]
static ALLOCATOR: tikv_jemallocator::Jemalloc = tikv_jemallocator::Jemalloc;

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let mut args: Vec<std::ffi::OsString> = std::env::args_os().skip(1).collect();
    let as_is = args.first().is_some_and(|a| a == "--file");
    if as_is {
        args.remove(0);
    }
    let path: PathBuf = args
        .first()
        .cloned()
        .ok_or_else(|| anyhow::anyhow!("usage: gateway [--file] CONFIG"))?
        .into();
    let setup = if as_is {
        iogate::app::Setup::from_file(&path).map_err(|p| anyhow::anyhow!("{p}"))?
    } else {
        iogate_tests::test_setup(&std::fs::read_to_string(&path)?)?
    };
    let mut terminate = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let running = iogate::app::start(setup).await?;
    let mut out = std::io::stdout();
    writeln!(out, "http {}", running.http_addr)?;
    out.flush()?;
    terminate.recv().await;
    running.shutdown().await;
    Ok(())
}
