//! TLS for the HTTP and gRPC listeners (`security.tls`): the server certificate chain and
//! key from PEM files, and optionally a CA whose client certificates are then required.
//! The files are read again when they change or on SIGHUP; a new connection gets the newest
//! good set, connections already open keep theirs, and a set that does not load is
//! reported and the previous one kept.

use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};
use std::time::Duration;

use rustls::ServerConfig;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use tokio_util::sync::CancellationToken;

/// How often the files are compared with what was loaded.
pub(crate) const WATCH_EVERY: Duration = Duration::from_secs(1);

/// The files of `security.tls`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsFiles {
    /// The server's certificate chain, leaf first.
    pub(crate) cert: PathBuf,
    /// The server's private key (PKCS#8, PKCS#1 or SEC1).
    pub(crate) key: PathBuf,
    /// When set, clients must present a certificate this CA signed.
    pub(crate) client_ca: Option<PathBuf>,
}

/// Why a set of files cannot serve TLS. The key's content is never in the message.
#[derive(Debug, thiserror::Error)]
pub(crate) enum TlsError {
    #[error("cannot read {}: {reason}", path.display())]
    Read {
        path: PathBuf,
        reason: std::io::Error,
    },
    #[error("{} holds no PEM certificate", .0.display())]
    NoCertificate(PathBuf),
    #[error("{}: {reason}", path.display())]
    Pem { path: PathBuf, reason: String },
    #[error("the certificate and key do not make a server identity: {0}")]
    Identity(rustls::Error),
    #[error("client_ca {}: {reason}", path.display())]
    ClientCa { path: PathBuf, reason: String },
}

/// The contents a configuration was built from, to notice a change.
type Contents = Vec<Vec<u8>>;

/// The listeners' TLS configuration, replaced as a whole when its files change.
pub(crate) struct Tls {
    files: RwLock<TlsFiles>,
    current: RwLock<(Arc<ServerConfig>, Contents)>,
}

impl std::fmt::Debug for Tls {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tls").field("files", &self.files()).finish()
    }
}

impl Tls {
    /// Loads the files; an error names the file and what is wrong with it.
    pub(crate) fn load(files: TlsFiles) -> Result<Tls, TlsError> {
        let contents = read_all(&files)?;
        let config = build(&files, &contents)?;
        Ok(Tls {
            files: RwLock::new(files),
            current: RwLock::new((config, contents)),
        })
    }

    fn files(&self) -> TlsFiles {
        match self.files.read() {
            Ok(files) => files.clone(),
            Err(poisoned) => poisoned.into_inner().clone(),
        }
    }

    /// Serves the next connections with `other`'s files and configuration (a reload
    /// named other files); open connections keep theirs.
    pub(crate) fn replace(&self, other: &Tls) {
        let files = other.files();
        let current = match other.current.read() {
            Ok(c) => c.clone(),
            Err(poisoned) => poisoned.into_inner().clone(),
        };
        match self.files.write() {
            Ok(mut f) => *f = files,
            Err(poisoned) => *poisoned.into_inner() = files,
        }
        match self.current.write() {
            Ok(mut c) => *c = current,
            Err(poisoned) => *poisoned.into_inner() = current,
        }
    }

    /// Whether clients must present a certificate.
    pub(crate) fn requires_client_certificates(&self) -> bool {
        self.files().client_ca.is_some()
    }

    /// The configuration new connections are served with.
    pub(crate) fn acceptor(&self) -> tokio_rustls::TlsAcceptor {
        let config = match self.current.read() {
            Ok(current) => current.0.clone(),
            Err(poisoned) => poisoned.into_inner().0.clone(),
        };
        tokio_rustls::TlsAcceptor::from(config)
    }

    /// Reads the files again; when they changed and load, they serve the next connections.
    /// `Ok(true)` when the configuration was replaced.
    pub(crate) fn reload(&self) -> Result<bool, TlsError> {
        let files = self.files();
        let contents = read_all(&files)?;
        let unchanged = match self.current.read() {
            Ok(current) => current.1 == contents,
            Err(poisoned) => poisoned.into_inner().1 == contents,
        };
        if unchanged {
            return Ok(false);
        }
        let config = build(&files, &contents)?;
        let mut current = match self.current.write() {
            Ok(current) => current,
            Err(poisoned) => poisoned.into_inner(),
        };
        *current = (config, contents);
        Ok(true)
    }

    /// Reloads on a change of the files (checked every [`WATCH_EVERY`]) and on SIGHUP,
    /// until `token` is cancelled.
    pub(crate) async fn watch(self: Arc<Self>, token: CancellationToken) {
        let mut hangup = hangup();
        let mut tick = tokio::time::interval(WATCH_EVERY);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut last_error = None;
        loop {
            let on_signal = tokio::select! {
                _ = token.cancelled() => return,
                _ = tick.tick() => false,
                _ = next_hangup(&mut hangup) => true,
            };
            match self.reload() {
                Ok(true) => {
                    tracing::info!(cert = %self.files().cert.display(), "TLS certificate reloaded");
                    last_error = None;
                }
                Ok(false) if on_signal => {
                    tracing::info!("SIGHUP: TLS files unchanged");
                }
                Ok(false) => {}
                Err(e) => {
                    // Said once per distinct problem, not every second.
                    let text = e.to_string();
                    if on_signal || last_error.as_deref() != Some(text.as_str()) {
                        tracing::error!(error = %text, "TLS files not reloaded; the previous certificate is still served");
                    }
                    last_error = Some(text);
                }
            }
        }
    }
}

#[cfg(unix)]
type Hangup = Option<tokio::signal::unix::Signal>;
#[cfg(not(unix))]
type Hangup = Option<()>;

fn hangup() -> Hangup {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        match signal(SignalKind::hangup()) {
            Ok(s) => Some(s),
            Err(e) => {
                tracing::warn!(error = %e, "cannot listen for SIGHUP; TLS files are still reloaded when they change");
                None
            }
        }
    }
    #[cfg(not(unix))]
    None
}

async fn next_hangup(hangup: &mut Hangup) {
    #[cfg(unix)]
    if let Some(signal) = hangup
        && signal.recv().await.is_some()
    {
        return;
    }
    let _ = hangup;
    std::future::pending::<()>().await;
}

fn read(path: &Path) -> Result<Vec<u8>, TlsError> {
    std::fs::read(path).map_err(|reason| TlsError::Read {
        path: path.to_owned(),
        reason,
    })
}

fn read_all(files: &TlsFiles) -> Result<Contents, TlsError> {
    let mut contents = vec![read(&files.cert)?, read(&files.key)?];
    if let Some(ca) = &files.client_ca {
        contents.push(read(ca)?);
    }
    Ok(contents)
}

fn certificates(path: &Path, pem: &[u8]) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    let certs = CertificateDer::pem_slice_iter(pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| TlsError::Pem {
            path: path.to_owned(),
            reason: format!("not a PEM certificate: {e}"),
        })?;
    if certs.is_empty() {
        return Err(TlsError::NoCertificate(path.to_owned()));
    }
    Ok(certs)
}

/// The certificates of a PEM file (a client's trust anchors or its own chain).
pub(crate) fn read_certs(path: &Path) -> Result<Vec<CertificateDer<'static>>, TlsError> {
    certificates(path, &read(path)?)
}

/// The private key of a PEM file.
pub(crate) fn read_key(path: &Path) -> Result<PrivateKeyDer<'static>, TlsError> {
    PrivateKeyDer::from_pem_slice(&read(path)?).map_err(|e| TlsError::Pem {
        path: path.to_owned(),
        reason: format!("no PEM private key (PKCS#8, PKCS#1 or SEC1): {e}"),
    })
}

/// A TLS client configuration with the gateway's crypto provider.
pub(crate) fn client_builder()
-> Result<rustls::ConfigBuilder<rustls::ClientConfig, rustls::WantsVerifier>, TlsError> {
    rustls::ClientConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .map_err(TlsError::Identity)
}

fn provider() -> Arc<rustls::crypto::CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// Builds a server configuration from the files' contents (cert, key, client CA).
fn build(files: &TlsFiles, contents: &[Vec<u8>]) -> Result<Arc<ServerConfig>, TlsError> {
    let (cert, key) = match contents {
        [cert, key, ..] => (cert, key),
        _ => return Err(TlsError::NoCertificate(files.cert.clone())),
    };
    let chain = certificates(&files.cert, cert)?;
    let key = PrivateKeyDer::from_pem_slice(key).map_err(|e| TlsError::Pem {
        path: files.key.clone(),
        reason: format!("no PEM private key (PKCS#8, PKCS#1 or SEC1): {e}"),
    })?;
    let builder = ServerConfig::builder_with_provider(provider())
        .with_safe_default_protocol_versions()
        .map_err(TlsError::Identity)?;
    let builder = match (&files.client_ca, contents.get(2)) {
        (Some(path), Some(pem)) => {
            let mut roots = rustls::RootCertStore::empty();
            for ca in certificates(path, pem)? {
                roots.add(ca).map_err(|e| TlsError::ClientCa {
                    path: path.clone(),
                    reason: e.to_string(),
                })?;
            }
            let verifier = rustls::server::WebPkiClientVerifier::builder_with_provider(
                Arc::new(roots),
                provider(),
            )
            .build()
            .map_err(|e| TlsError::ClientCa {
                path: path.clone(),
                reason: e.to_string(),
            })?;
            builder.with_client_cert_verifier(verifier)
        }
        _ => builder.with_no_client_auth(),
    };
    let mut config = builder
        .with_single_cert(chain, key)
        .map_err(TlsError::Identity)?;
    config.alpn_protocols = vec![b"h2".to_vec(), b"http/1.1".to_vec()];
    Ok(Arc::new(config))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pair(name: &str) -> (String, String) {
        let key = rcgen::KeyPair::generate().expect("key");
        let params = rcgen::CertificateParams::new(vec![name.to_owned()]).expect("params");
        let cert = params.self_signed(&key).expect("cert");
        (cert.pem(), key.serialize_pem())
    }

    fn served_cert(tls: &Tls) -> Vec<u8> {
        tls.current.read().expect("lock").1[0].clone()
    }

    #[test]
    fn a_changed_pair_is_taken_and_a_broken_one_is_not() {
        let dir = std::env::temp_dir().join(format!("iogate-tls-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let files = TlsFiles {
            cert: dir.join("c.pem"),
            key: dir.join("k.pem"),
            client_ca: None,
        };
        let (cert, key) = pair("first");
        std::fs::write(&files.cert, &cert).expect("cert");
        std::fs::write(&files.key, &key).expect("key");
        let tls = Tls::load(files.clone()).expect("loads");
        assert!(!tls.reload().expect("same files"), "nothing changed");

        std::fs::write(&files.cert, "-----BEGIN CERTIFICATE-----\nnot base64\n").expect("w");
        let error = tls.reload().expect_err("broken").to_string();
        assert!(error.contains("c.pem"), "{error}");
        assert_eq!(
            served_cert(&tls),
            cert.as_bytes(),
            "the first is still served"
        );
        let (second_cert, second_key) = pair("second");
        std::fs::write(&files.cert, &second_cert).expect("cert");
        let error = tls.reload().expect_err("key of the first").to_string();
        assert!(error.contains("do not make a server identity"), "{error}");
        assert_eq!(
            served_cert(&tls),
            cert.as_bytes(),
            "the first is still served"
        );
        std::fs::write(&files.key, &second_key).expect("key");
        assert!(tls.reload().expect("second pair"), "replaced");
        assert_eq!(served_cert(&tls), second_cert.as_bytes());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
