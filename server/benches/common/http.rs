#![allow(dead_code)]

//! A small HTTP/1.1 load generator: kept-alive connections each requesting one path as fast
//! as the server answers.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Requests `path` over one kept-alive connection until `until`; answers the count.
async fn client(addr: SocketAddr, path: &'static str, until: Instant) -> anyhow::Result<u64> {
    let mut stream = TcpStream::connect(addr).await?;
    stream.set_nodelay(true)?;
    let request = format!("GET {path} HTTP/1.1\r\nHost: x\r\n\r\n");
    let mut buf = vec![0u8; 64 * 1024];
    let mut n = 0;
    while Instant::now() < until {
        stream.write_all(request.as_bytes()).await?;
        // Read the head, then the body by its Content-Length.
        let mut have = 0;
        let (head, length) = loop {
            let read = stream.read(&mut buf[have..]).await?;
            anyhow::ensure!(read > 0, "closed");
            have += read;
            if let Some(end) = buf[..have].windows(4).position(|w| w == b"\r\n\r\n") {
                let head = String::from_utf8_lossy(&buf[..end]).to_lowercase();
                anyhow::ensure!(head.starts_with("http/1.1 200"), "{head}");
                let length: usize = head
                    .lines()
                    .find_map(|l| l.strip_prefix("content-length:"))
                    .and_then(|v| v.trim().parse().ok())
                    .ok_or_else(|| anyhow::anyhow!("no content-length: {head}"))?;
                break (end + 4, length);
            }
        };
        while have < head + length {
            let read = stream.read(&mut buf[have..]).await?;
            anyhow::ensure!(read > 0, "closed");
            have += read;
        }
        n += 1;
    }
    Ok(n)
}

/// Requests per second for `path` over `connections` kept-alive connections during `run`.
pub async fn rate(
    addr: SocketAddr,
    path: &'static str,
    connections: usize,
    run: Duration,
) -> anyhow::Result<f64> {
    let until = Instant::now() + run;
    let started = Instant::now();
    let tasks: Vec<_> = (0..connections)
        .map(|_| tokio::spawn(client(addr, path, until)))
        .collect();
    let mut total = 0;
    for t in tasks {
        total += t.await??;
    }
    Ok(total as f64 / started.elapsed().as_secs_f64())
}

/// One GET of `path` on a connection of its own: the status and the whole answer (head
/// and body).
pub async fn get_once(addr: SocketAddr, path: &str) -> anyhow::Result<(u16, Vec<u8>)> {
    let mut stream = TcpStream::connect(addr).await?;
    stream
        .write_all(
            format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n").as_bytes(),
        )
        .await?;
    let mut answer = Vec::new();
    stream.read_to_end(&mut answer).await?;
    let status = std::str::from_utf8(answer.get(9..12).unwrap_or_default())
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(0);
    Ok((status, answer))
}

/// How many devices `GET /api/v1/devices` lists as connected.
pub async fn connected_devices(addr: SocketAddr) -> anyhow::Result<usize> {
    let (_, answer) = get_once(addr, "/api/v1/devices").await?;
    Ok(String::from_utf8_lossy(&answer)
        .matches("\"connected\":true")
        .count())
}

/// One kept-alive HTTP connection sending requests with a JSON body, one at a time.
pub struct Kept {
    stream: TcpStream,
    buf: Vec<u8>,
}

impl Kept {
    pub async fn connect(addr: SocketAddr) -> anyhow::Result<Kept> {
        let stream = TcpStream::connect(addr).await?;
        stream.set_nodelay(true)?;
        Ok(Kept {
            stream,
            buf: vec![0; 64 * 1024],
        })
    }

    /// Sends `method path` with `body`; answers once the whole answer (a 2xx) is read.
    pub async fn send(&mut self, method: &str, path: &str, body: &str) -> anyhow::Result<()> {
        let request = format!(
            "{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
            body.len()
        );
        self.stream.write_all(request.as_bytes()).await?;
        let mut have = 0;
        let (head, length) = loop {
            let read = self.stream.read(&mut self.buf[have..]).await?;
            anyhow::ensure!(read > 0, "closed");
            have += read;
            if let Some(end) = self.buf[..have].windows(4).position(|w| w == b"\r\n\r\n") {
                let head = String::from_utf8_lossy(&self.buf[..end]).to_lowercase();
                anyhow::ensure!(head.starts_with("http/1.1 2"), "{head}");
                let length: usize = head
                    .lines()
                    .find_map(|l| l.strip_prefix("content-length:"))
                    .and_then(|v| v.trim().parse().ok())
                    .unwrap_or(0);
                break (end + 4, length);
            }
        };
        while have < head + length {
            let read = self.stream.read(&mut self.buf[have..]).await?;
            anyhow::ensure!(read > 0, "closed");
            have += read;
        }
        Ok(())
    }
}
