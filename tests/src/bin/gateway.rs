//! A gateway in a process of its own, for tests that kill it: reads the config file given
//! as its argument (adjusted as the in-process test gateway is: loopback listeners on free
//! ports, the repository's profiles), prints `http <address>` once it serves, and runs
//! until SIGTERM or SIGKILL.

use std::io::Write;
use std::path::PathBuf;

#[tokio::main]
async fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let path: PathBuf = std::env::args_os()
        .nth(1)
        .ok_or_else(|| anyhow::anyhow!("usage: gateway CONFIG"))?
        .into();
    let text = std::fs::read_to_string(&path)?;
    let setup = iogate_tests::test_setup(&text)?;
    let mut terminate = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let running = iogate::app::start(setup).await?;
    let mut out = std::io::stdout();
    writeln!(out, "http {}", running.http_addr)?;
    out.flush()?;
    terminate.recv().await;
    running.shutdown().await;
    Ok(())
}
