//! An RS-485 line of independent slaves on pseudo-terminals: the master's end at a path
//! (a symlink), each slave on a pty of its own, and a task between them that does what the
//! wire does: a slave hears the master only when the master's port runs at the slave's baud
//! rate (read from the pty's settings), and what any slave sends reaches the master, so two
//! slaves on one id answer twice.
//!
//! A pty carries no parity (the kernel clears it), so only the baud rate is told apart.
//! pymodbus 3.16 answers ids it does not serve with exception 04 instead of keeping quiet, so
//! the line passes each slave only the frames for its id (and broadcasts), as the address
//! filter of a real slave's firmware would.

use std::path::{Path, PathBuf};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_serial::{SerialPort, SerialStream};

/// The frames a master sent, each with when it came.
pub type Sent = std::sync::Arc<std::sync::Mutex<Vec<(std::time::Instant, Vec<u8>)>>>;

/// A slave's end of the line.
pub struct SlaveEnd {
    /// The path the slave opens.
    pub path: PathBuf,
    pub unit: u8,
    pub baud: u32,
}

/// The line: its task ends when dropped.
pub struct Line {
    pub slaves: Vec<SlaveEnd>,
    /// Frames the master sent, in order, each with when it came.
    pub sent: Sent,
    task: JoinHandle<()>,
    _holders: Vec<SerialStream>,
}

impl Drop for Line {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// A line whose master end is at `master_path`, with a slave end for each `(unit, baud)`,
/// each at `dir/slaveN`.
pub fn line(dir: &Path, master_path: &Path, slaves: &[(u8, u32)]) -> anyhow::Result<Line> {
    let (mut master, master_holder) = crate::devices::pty_at(master_path)?;
    let mut holders = vec![master_holder];
    let mut ends = Vec::new();
    let mut streams = Vec::new();
    for (i, &(unit, baud)) in slaves.iter().enumerate() {
        let path = dir.join(format!("slave{i}"));
        let (stream, holder) = crate::devices::pty_at(&path)?;
        holders.push(holder);
        streams.push(stream);
        ends.push(SlaveEnd { path, unit, baud });
    }
    let sent: Sent = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let record = sent.clone();
    let routes: Vec<(u8, u32)> = slaves.to_vec();
    let task = tokio::spawn(async move {
        // Each slave's bytes come in on one channel with the slave's index.
        let (tx, mut rx) = mpsc::channel::<(usize, Vec<u8>)>(64);
        let mut writers = Vec::new();
        for (i, stream) in streams.into_iter().enumerate() {
            let (mut reader, writer) = tokio::io::split(stream);
            writers.push(writer);
            let tx = tx.clone();
            tokio::spawn(async move {
                let mut buf = [0u8; 512];
                while let Ok(n) = reader.read(&mut buf).await {
                    if n == 0 || tx.send((i, buf[..n].to_vec())).await.is_err() {
                        break;
                    }
                }
            });
        }
        let mut buf = [0u8; 512];
        loop {
            tokio::select! {
                read = master.read(&mut buf) => {
                    let Ok(n) = read else { break };
                    if n == 0 { break; }
                    let frame = buf[..n].to_vec();
                    let baud = master.baud_rate().unwrap_or(0);
                    if let Ok(mut sent) = record.lock() {
                        sent.push((std::time::Instant::now(), frame.clone()));
                    }
                    for (i, (unit, at)) in routes.iter().enumerate() {
                        if *at == baud && (frame[0] == *unit || frame[0] == 0) {
                            let _ = writers[i].write_all(&frame).await;
                        }
                    }
                }
                Some((i, bytes)) = rx.recv() => {
                    let baud = master.baud_rate().unwrap_or(0);
                    if routes[i].1 == baud {
                        let _ = master.write_all(&bytes).await;
                    }
                }
            }
        }
    });
    Ok(Line {
        slaves: ends,
        sent,
        task,
        _holders: holders,
    })
}
