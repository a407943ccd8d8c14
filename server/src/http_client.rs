//! A small HTTP/1.1 client for the services the gateway asks itself (an arbiter's API):
//! one connection kept open and opened again when it fails, over TLS for `https://`,
//! answers bounded in size.

use std::path::Path;
use std::sync::Arc;

use bytes::Bytes;
use http_body_util::{BodyExt, Full, Limited};
use hyper::client::conn::http1::SendRequest;
use hyper::header::{CONTENT_TYPE, HOST, HeaderName};
use hyper::{Method, Request, Uri};
use hyper_util::rt::TokioIo;
use tokio::io::{AsyncRead, AsyncWrite};

/// The largest answer read (an arbiter's record is a few hundred bytes).
const ANSWER_MAX: usize = 1 << 20;

/// One server, asked request by request on a connection kept open.
pub(crate) struct HttpClient {
    url: String,
    uri: Uri,
    tls: Option<tokio_rustls::TlsConnector>,
    sender: Option<SendRequest<Full<Bytes>>>,
}

impl HttpClient {
    /// A client of `url`: `http://`, or `https://` trusting the certificates of `ca`.
    pub(crate) fn new(url: &str, ca: Option<&Path>) -> Result<HttpClient, String> {
        let uri: Uri = url
            .parse()
            .map_err(|e| format!("{}: not a URL: {e}", crate::text::quote(url)))?;
        let tls = match (uri.scheme_str(), ca) {
            (Some("http"), _) => None,
            (Some("https"), Some(ca)) => Some(trusting(ca)?),
            (Some("https"), None) => {
                return Err(format!(
                    "{url}: https needs the CA that signs its certificate (ca:)"
                ));
            }
            _ => return Err(format!("{url}: the URL starts with http:// or https://")),
        };
        Ok(HttpClient {
            url: url.trim_end_matches('/').to_owned(),
            uri,
            tls,
            sender: None,
        })
    }

    pub(crate) fn url(&self) -> &str {
        &self.url
    }

    /// The status and body of one request; `body` is sent as JSON when not empty.
    pub(crate) async fn call(
        &mut self,
        method: Method,
        path: &str,
        headers: &[(HeaderName, String)],
        body: Vec<u8>,
    ) -> Result<(u16, Bytes), String> {
        let mut request = Request::builder().method(method).uri(path).header(
            HOST,
            self.uri
                .authority()
                .map_or_else(String::new, ToString::to_string),
        );
        for (name, value) in headers {
            request = request.header(name, value);
        }
        if !body.is_empty() {
            request = request.header(CONTENT_TYPE, "application/json");
        }
        let request = request
            .body(Full::new(Bytes::from(body)))
            .map_err(|e| e.to_string())?;
        let sender = match self.sender.take().filter(|s| !s.is_closed()) {
            Some(s) => s,
            None => self.connect().await?,
        };
        let mut sender = sender;
        sender.ready().await.map_err(|e| e.to_string())?;
        let response = sender
            .send_request(request)
            .await
            .map_err(|e| e.to_string())?;
        let status = response.status().as_u16();
        let body = Limited::new(response.into_body(), ANSWER_MAX)
            .collect()
            .await
            .map_err(|e| format!("the answer: {e}"))?
            .to_bytes();
        self.sender = Some(sender);
        Ok((status, body))
    }

    async fn connect(&self) -> Result<SendRequest<Full<Bytes>>, String> {
        let host = self.uri.host().unwrap_or_default();
        let host = host.trim_start_matches('[').trim_end_matches(']');
        let port = self
            .uri
            .port_u16()
            .unwrap_or(if self.tls.is_some() { 443 } else { 80 });
        let tcp = tokio::net::TcpStream::connect((host, port))
            .await
            .map_err(|e| format!("cannot connect: {e}"))?;
        let _ = tcp.set_nodelay(true);
        match &self.tls {
            None => handshake(tcp).await,
            Some(connector) => {
                let name = rustls::pki_types::ServerName::try_from(host.to_owned())
                    .map_err(|e| format!("`{host}` is not a server name: {e}"))?;
                let stream = connector
                    .connect(name, tcp)
                    .await
                    .map_err(|e| format!("TLS: {e}"))?;
                handshake(stream).await
            }
        }
    }
}

async fn handshake<S>(io: S) -> Result<SendRequest<Full<Bytes>>, String>
where
    S: AsyncRead + AsyncWrite + Unpin + Send + 'static,
{
    let (sender, connection) = hyper::client::conn::http1::handshake(TokioIo::new(io))
        .await
        .map_err(|e| e.to_string())?;
    // The connection ends when the sender is dropped, or the server closes it.
    tokio::spawn(async move {
        let _ = connection.await;
    });
    Ok(sender)
}

/// A TLS connector trusting the certificates of the PEM file `ca`.
pub(crate) fn trusting(ca: &Path) -> Result<tokio_rustls::TlsConnector, String> {
    let mut roots = rustls::RootCertStore::empty();
    for cert in crate::tls::read_certs(ca).map_err(|e| e.to_string())? {
        roots
            .add(cert)
            .map_err(|e| format!("{}: {e}", ca.display()))?;
    }
    let config = crate::tls::client_builder()
        .map_err(|e| e.to_string())?
        .with_root_certificates(roots)
        .with_no_client_auth();
    Ok(tokio_rustls::TlsConnector::from(Arc::new(config)))
}
