//! `iogate check --diff`: the report a reload would give, with nothing applied. Against the
//! running gateway, its own dry run is asked for (`POST /api/v1/config/reload?dry_run=true`
//! on the config's HTTP listener, or `--server`); against another file (`--against`), the
//! two are compared here, with the same loading, checks and comparison as a reload.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use axum::body::Bytes;
use http_body_util::{BodyExt, Empty};
use hyper::{Method, Request, Uri};
use hyper_util::rt::TokioIo;
use tokio::io::{AsyncRead, AsyncWrite};

use crate::service::{Report, Trigger};
use crate::setup::Setup;

/// How long the gateway may take to answer, connection included.
const ASK_TIMEOUT: Duration = Duration::from_secs(30);

/// Why there is no report.
#[derive(Debug)]
pub enum DiffError {
    /// The files have problems, `file:line: message` each (what a reload would answer).
    Invalid(Vec<String>),
    /// The gateway could not be asked, or did not answer with a report.
    Failed(String),
}

impl std::fmt::Display for DiffError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DiffError::Invalid(problems) => f.write_str(&problems.join("\n")),
            DiffError::Failed(message) => f.write_str(message),
        }
    }
}

fn invalid(problems: crate::yaml::Problems) -> DiffError {
    DiffError::Invalid(problems.0.iter().map(ToString::to_string).collect())
}

/// The report of a reload from the configuration in `running` to the one in `new`: both
/// loaded and checked as a reload loads them.
pub fn against_file(running: &Path, new: &Path) -> Result<Report, DiffError> {
    let started = Instant::now();
    let old = super::load(running, None).map_err(invalid)?;
    let next = super::load(new, old.setup.map.as_ref()).map_err(invalid)?;
    let diff = super::diff::diff(&old.setup, &old.tokens, &next.setup, &next.tokens);
    Ok(Report {
        trigger: Trigger::Check,
        dry_run: true,
        changes: diff.items,
        reopened: diff.links.changed,
        took_ms: (started.elapsed().as_secs_f64() * 1e6).round() / 1000.0,
        config_hash: next.hash,
        at_unix_ms: super::unix_ms(SystemTime::now()),
    })
}

/// Where the gateway of `setup` answers HTTP: its `listen.http` (a wildcard address asked
/// on loopback), `https` when it serves TLS.
pub fn gateway_url(setup: &Setup) -> String {
    let config = &setup.config;
    let scheme = if config.security.tls.is_some() {
        "https"
    } else {
        "http"
    };
    let mut addr = config.http;
    if addr.ip().is_unspecified() {
        addr.set_ip(match addr {
            std::net::SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
            std::net::SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
        });
    }
    format!("{scheme}://{addr}")
}

/// The running gateway's dry run of a reload. `config` is the file the gateway must run
/// (it reloads its own file: another one is refused, see `--against`); `setup` is that
/// file loaded, for the TLS certificate the gateway presents.
pub async fn against_gateway(
    setup: &Setup,
    config: &Path,
    url: &str,
    token: Option<&str>,
) -> Result<Report, DiffError> {
    let gateway = Gateway::new(setup, url, token)?;
    let (status, body) = gateway.ask(Method::GET, "/api/v1/config").await?;
    if status != 200 {
        return Err(gateway.refused(status, &body));
    }
    let running = body["file"].as_str().unwrap_or_default();
    if !same_file(Path::new(running), config) {
        return Err(DiffError::Failed(format!(
            "the gateway at {url} runs `{running}`, not `{}`: a reload loads the file it runs; compare two files with --against",
            config.display()
        )));
    }
    let (status, body) = gateway
        .ask(Method::POST, "/api/v1/config/reload?dry_run=true")
        .await?;
    match status {
        200 => serde_json::from_value(body["report"].clone()).map_err(|e| {
            DiffError::Failed(format!("the gateway at {url} answered no report: {e}"))
        }),
        400 => {
            let problems = body["error"]["problems"]
                .as_array()
                .map(|problems| {
                    problems
                        .iter()
                        .map(|p| {
                            format!(
                                "{}:{}: {}",
                                p["file"].as_str().unwrap_or_default(),
                                p["line"],
                                p["message"].as_str().unwrap_or_default()
                            )
                        })
                        .collect()
                })
                .unwrap_or_default();
            Err(DiffError::Invalid(problems))
        }
        _ => Err(gateway.refused(status, &body)),
    }
}

fn same_file(a: &Path, b: &Path) -> bool {
    let canonical = |p: &Path| std::fs::canonicalize(p).unwrap_or_else(|_| PathBuf::from(p));
    canonical(a) == canonical(b)
}

/// One gateway, asked over HTTP/1.1 or HTTPS.
struct Gateway {
    url: String,
    uri: Uri,
    token: Option<String>,
    tls: Option<tokio_rustls::TlsConnector>,
}

impl Gateway {
    fn new(setup: &Setup, url: &str, token: Option<&str>) -> Result<Gateway, DiffError> {
        let uri: Uri = url
            .parse()
            .map_err(|e| DiffError::Failed(format!("`{url}` is not a URL: {e}")))?;
        let tls = match uri.scheme_str() {
            Some("http") => None,
            Some("https") => Some(connector(setup)?),
            _ => {
                return Err(DiffError::Failed(format!(
                    "`{url}`: the gateway's URL starts with http:// or https://"
                )));
            }
        };
        Ok(Gateway {
            url: url.trim_end_matches('/').to_owned(),
            uri,
            token: token.map(str::to_owned),
            tls,
        })
    }

    /// The status and JSON body of one request.
    async fn ask(&self, method: Method, path: &str) -> Result<(u16, serde_json::Value), DiffError> {
        let failed = |e: String| DiffError::Failed(format!("{} {}{path}: {e}", method, self.url));
        let asked = tokio::time::timeout(ASK_TIMEOUT, self.exchange(method.clone(), path)).await;
        match asked {
            Ok(Ok(answer)) => Ok(answer),
            Ok(Err(e)) => Err(failed(e)),
            Err(_) => Err(failed(format!(
                "no answer within {}s",
                ASK_TIMEOUT.as_secs()
            ))),
        }
    }

    async fn exchange(
        &self,
        method: Method,
        path: &str,
    ) -> Result<(u16, serde_json::Value), String> {
        let host = self.uri.host().unwrap_or_default();
        let host = host.trim_start_matches('[').trim_end_matches(']');
        let default_port = if self.tls.is_some() { 443 } else { 80 };
        let port = self.uri.port_u16().unwrap_or(default_port);
        let tcp = tokio::net::TcpStream::connect((host, port))
            .await
            .map_err(|e| format!("cannot connect: {e}"))?;
        match &self.tls {
            None => self.send(tcp, method, path).await,
            Some(connector) => {
                let name = rustls::pki_types::ServerName::try_from(host.to_owned())
                    .map_err(|e| format!("`{host}` is not a server name: {e}"))?;
                let stream = connector.connect(name, tcp).await.map_err(|e| {
                    format!("TLS: {e} (the gateway's certificate must name `{host}`; or give --server https://NAME:PORT)")
                })?;
                self.send(stream, method, path).await
            }
        }
    }

    async fn send<S>(
        &self,
        io: S,
        method: Method,
        path: &str,
    ) -> Result<(u16, serde_json::Value), String>
    where
        S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    {
        let (mut sender, connection) = hyper::client::conn::http1::handshake(TokioIo::new(io))
            .await
            .map_err(|e| e.to_string())?;
        let driven = tokio::spawn(connection);
        let authority = self
            .uri
            .authority()
            .map_or_else(String::new, ToString::to_string);
        let mut request = Request::builder()
            .method(method)
            .uri(path)
            .header(hyper::header::HOST, authority);
        if let Some(token) = &self.token {
            request = request.header(hyper::header::AUTHORIZATION, format!("Bearer {token}"));
        }
        let request = request
            .body(Empty::<Bytes>::new())
            .map_err(|e| e.to_string())?;
        let response = sender
            .send_request(request)
            .await
            .map_err(|e| e.to_string())?;
        let status = response.status().as_u16();
        let body = response
            .into_body()
            .collect()
            .await
            .map_err(|e| e.to_string())?
            .to_bytes();
        driven.abort();
        let json = serde_json::from_slice(&body).unwrap_or(serde_json::Value::Null);
        Ok((status, json))
    }

    fn refused(&self, status: u16, body: &serde_json::Value) -> DiffError {
        let message = body["error"]["message"]
            .as_str()
            .unwrap_or("no error message");
        let hint = match status {
            401 | 403 => " (give an admin token in IOGATE_TOKEN or --token)",
            _ => "",
        };
        DiffError::Failed(format!(
            "the gateway at {} answered {status}: {message}{hint}",
            self.url
        ))
    }
}

/// Trusts the certificate the gateway presents (the config's `security.tls.cert`).
fn connector(setup: &Setup) -> Result<tokio_rustls::TlsConnector, DiffError> {
    let Some(files) = &setup.config.security.tls else {
        return Err(DiffError::Failed(
            "https: the config has no security.tls certificate to trust".to_owned(),
        ));
    };
    crate::http_client::trusting(&files.cert).map_err(DiffError::Failed)
}
