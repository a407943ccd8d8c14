//! For the crash tests: a test of this binary run in a process of its own and killed
//! (`kill -9`) at a moment that differs each time.

use std::io::BufRead;
use std::sync::mpsc;
use std::time::Duration;

/// A random-enough sequence of kill moments: seeded by the clock, moved on each life.
pub(crate) struct Moments(u64);

impl Moments {
    pub(crate) fn new() -> Moments {
        Moments(
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(1, |d| d.as_nanos() as u64),
        )
    }

    /// The next wait, between `least` and `least + spread`.
    fn next(&mut self, least: Duration, spread: Duration) -> Duration {
        self.0 = self
            .0
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        let spread = spread.as_micros().max(1) as u64;
        least + Duration::from_micros((self.0 >> 33) % spread)
    }
}

/// Runs the ignored test `name` (its whole path) with `var` set to `value`, lets it print
/// its first line (so it has written something), kills it after a wait from `moments` (`least` plus up to `spread`), and
/// answers every line it printed.
pub(crate) fn run_and_kill(
    name: &str,
    (var, value): (&str, &std::path::Path),
    moments: &mut Moments,
    (least, spread): (Duration, Duration),
) -> Vec<String> {
    let exe = std::env::current_exe().expect("the test binary");
    let mut child = std::process::Command::new(exe)
        .args([
            "--exact",
            name,
            "--ignored",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(var, value)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("the writer starts");
    let out = child.stdout.take().expect("its output");
    let (tx, rx) = mpsc::channel();
    let reader = std::thread::spawn(move || {
        for line in std::io::BufReader::new(out).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let wait = moments.next(least, spread);
    // The test's own first line (the harness prints a blank line and "running 1 test"
    // before it runs the test).
    let mut lines = Vec::new();
    while let Ok(line) = rx.recv_timeout(Duration::from_secs(10)) {
        let harness = line.is_empty() || line.starts_with("running ");
        lines.push(line);
        if !harness {
            break;
        }
    }
    std::thread::sleep(wait);
    let _ = child.kill();
    let _ = child.wait();
    let _ = reader.join();
    lines.extend(rx.try_iter());
    lines
}
