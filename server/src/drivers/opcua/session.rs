//! An open OPC UA link: one session on the server, its event loop driven by a task of the
//! link's own. The library's own reconnecting is off: a lost connection ends the session
//! (`Connection::lost`), and the link's task opens a new one with its back-off, so every
//! link reconnects the same way. Any publish response (data or keep-alive) and every
//! answered keep-alive counts as the link making progress.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use futures_util::StreamExt;
use opcua::client::{ClientBuilder, IdentityToken, Session, SessionPollResult};
use opcua::crypto::CertificateStore;
use opcua::types::{MessageSecurityMode, StatusCode};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::config::{self, Settings, User};
use crate::cache::{Link, Progress};
use crate::link::LinkFault;

/// How long one request to the server may take.
pub(crate) const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);
/// The size of the chunks the client takes (the library's).
const CHUNK: usize = 65_535;
/// How long a session lives on the server without a request.
const SESSION_TIMEOUT_MS: u32 = 60_000;

/// Every session opened gets the next number, so a device's plan knows whether its
/// subscription belongs to the session it is read in.
static OPENED: AtomicU64 = AtomicU64::new(1);

/// An open session and the task that drives it.
pub(crate) struct Connection {
    pub(crate) session: Arc<Session>,
    /// Which session this is.
    pub(crate) generation: u64,
    /// The server's namespace array as read when the session opened.
    pub(crate) namespaces: Vec<String>,
    pub(crate) settings: Settings,
    pub(crate) progress: Arc<Progress>,
    /// Set once the connection is lost, with why.
    lost: watch::Receiver<Option<String>>,
    /// How many times the server answered a publish request saying it has no subscription
    /// of the session (it deleted them): every subscription made before is gone.
    pub(crate) dropped: Arc<AtomicU64>,
    /// How many items one request of each service carries in this session.
    pub(crate) limits: super::limits::Limits,
    /// Whether the session was closed on the server already ([`Connection::close`]).
    pub(crate) closed: bool,
    pump: JoinHandle<()>,
}

impl Drop for Connection {
    /// Closes the session on the server (bounded), then stops its task.
    fn drop(&mut self) {
        let session = self.session.clone();
        let pump = self.pump.abort_handle();
        if self.closed {
            pump.abort();
            return;
        }
        match tokio::runtime::Handle::try_current() {
            Ok(runtime) => {
                runtime.spawn(async move {
                    let _ =
                        tokio::time::timeout(Duration::from_secs(1), session.disconnect()).await;
                    pump.abort();
                });
            }
            Err(_) => pump.abort(),
        }
    }
}

fn failed(endpoint: &str, reason: impl std::fmt::Display) -> LinkFault {
    LinkFault::connect_failed(endpoint, super::UaError::Open(reason.to_string()))
}

/// Who the gateway is, from the user settings.
fn identity(user: &User) -> Result<IdentityToken, String> {
    Ok(match user {
        User::Anonymous => IdentityToken::Anonymous,
        User::Password { username, file } => {
            IdentityToken::new_user_name(username.clone(), config::password(file)?)
        }
        User::Certificate { certificate, key } => {
            IdentityToken::new_x509_path(certificate, key).map_err(|e| e.to_string())?
        }
    })
}

/// The client, its certificate made (or read) in the PKI directory and the trusted server
/// certificates put in its `trusted` folder.
fn client(settings: &Settings) -> Result<opcua::client::Client, String> {
    // Links sharing a PKI directory make its key pair once, not each a half of one.
    static MAKING: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _making = MAKING
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let trusted_dir = settings.pki_dir.join("trusted");
    if !settings.trusted.is_empty() {
        std::fs::create_dir_all(&trusted_dir)
            .map_err(|e| format!("pki_dir {}: {e}", trusted_dir.display()))?;
    }
    for file in &settings.trusted {
        // Under the name the certificate store looks it up by (its subject and thumbprint).
        let cert = CertificateStore::read_cert(file)
            .map_err(|e| format!("trusted {}: {e}", file.display()))?;
        let der = cert
            .to_der()
            .map_err(|e| format!("trusted {}: {e}", file.display()))?;
        let path = trusted_dir.join(CertificateStore::cert_file_name(&cert));
        std::fs::write(&path, der).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    let secure = settings.policy != "None" || matches!(settings.user, User::Certificate { .. });
    // Made once in the PKI directory (own/cert.der, private/private.pem), then read.
    let made = (
        settings.pki_dir.join("own/cert.der"),
        settings.pki_dir.join("private/private.pem"),
    );
    let given = match (&settings.certificate, &settings.private_key) {
        (Some(c), Some(k)) => Some((c.clone(), k.clone())),
        _ if made.0.exists() && made.1.exists() => Some(made),
        _ => None,
    };
    // A key that cannot be read is named here, not met by the secure channel.
    if let Some((_, key)) = given.as_ref().filter(|_| secure) {
        CertificateStore::read_pkey(key)
            .map_err(|e| format!("the application's private key {}: {e}", key.display()))?;
    }
    let mut builder = ClientBuilder::new()
        .application_name("iogate")
        .application_uri("urn:iogate:client")
        .product_uri("urn:iogate")
        .session_name("iogate")
        .pki_dir(&settings.pki_dir)
        .create_sample_keypair(secure && given.is_none())
        .trust_server_certs(false)
        .session_retry_limit(0)
        .session_timeout(SESSION_TIMEOUT_MS)
        .request_timeout(REQUEST_TIMEOUT)
        .recreate_subscriptions(false)
        .max_message_size(settings.limits.message)
        .max_chunk_count(settings.limits.message.div_ceil(CHUNK) + 1)
        .max_string_length(settings.limits.string)
        .max_byte_string_length(settings.limits.string)
        .max_array_length(settings.limits.array);
    if let Some((c, k)) = given {
        builder = builder.certificate_path(c).private_key_path(k);
    }
    // Without security the client needs no certificate of its own: the library's errors
    // about the missing one (and about a config without endpoints, which the gateway does
    // not use) would be said at every connection.
    let client = match secure {
        true => builder.client(),
        false => {
            tracing::subscriber::with_default(tracing::subscriber::NoSubscriber::default(), || {
                builder.client()
            })
        }
    }
    .map_err(|errors| errors.join("; "))?;
    if settings.accept_host_mismatch {
        client.certificate_store().write().set_check_hostname(false);
    }
    Ok(client)
}

/// The server's endpoint of the configured security, dialled at the configured URL: a
/// server behind a port mapping, NAT or a proxy advertises an address of its own network
/// (matched by security policy and mode, as UaExpert and Prosys's clients do). An endpoint
/// that does not take the configured user says so.
async fn endpoint(
    client: &opcua::client::Client,
    settings: &Settings,
    mode: MessageSecurityMode,
    identity: &IdentityToken,
) -> Result<opcua::types::EndpointDescription, String> {
    use opcua::crypto::SecurityPolicy;
    use opcua::types::UserTokenType;
    let policy: SecurityPolicy = settings.policy.parse().unwrap_or(SecurityPolicy::Unknown);
    let offered = client
        .get_server_endpoints_from_url(settings.url.as_str())
        .await
        .map_err(|e| format!("asking for its endpoints: {e}"))?;
    let Some(mut endpoint) = offered
        .iter()
        .find(|e| {
            e.security_mode == mode
                && SecurityPolicy::from_uri(e.security_policy_uri.as_ref()) == policy
        })
        .cloned()
    else {
        let list: Vec<String> = offered
            .iter()
            .map(|e| {
                let uri = e.security_policy_uri.as_ref();
                format!(
                    "{} {:?}",
                    uri.rsplit('#').next().unwrap_or(uri),
                    e.security_mode
                )
            })
            .collect();
        return Err(format!(
            "the server has no endpoint with security {} {:?} (it offers: {})",
            settings.policy,
            mode,
            list.join(", ")
        ));
    };
    let (wanted, who) = match identity {
        IdentityToken::Anonymous => (UserTokenType::Anonymous, "anonymous users"),
        IdentityToken::UserName(..) => (UserTokenType::UserName, "user names"),
        IdentityToken::X509(..) => (UserTokenType::Certificate, "user certificates"),
        IdentityToken::IssuedToken(..) => (UserTokenType::IssuedToken, "issued tokens"),
    };
    let tokens = endpoint.user_identity_tokens.clone().unwrap_or_default();
    if !tokens.iter().any(|t| t.token_type == wanted) {
        let takes: Vec<String> = tokens
            .iter()
            .map(|t| format!("{:?}", t.token_type))
            .collect();
        let takes = match takes.is_empty() {
            true => "no user at all there: choose another security_policy".to_owned(),
            false => format!(
                "{}: set the link's `user` (`username` and `password_file`, or `certificate` and `private_key`)",
                takes.join(", ")
            ),
        };
        return Err(format!(
            "the server does not take {who} on its endpoint of security {} {mode:?} (it takes {takes})",
            settings.policy
        ));
    }
    endpoint.endpoint_url = settings.url.as_str().into();
    Ok(endpoint)
}

/// Opens a session on the link's server and reads its namespace array.
pub(crate) async fn open(settings: Settings, link: &Arc<Link>) -> Result<Connection, LinkFault> {
    connect(settings, link.progress.clone()).await
}

/// Opens a session on a server, telling `progress` of every answer.
pub(crate) async fn connect(
    settings: Settings,
    progress: Arc<Progress>,
) -> Result<Connection, LinkFault> {
    let url = settings.url.clone();
    let identity = identity(&settings.user).map_err(|e| failed(&url, e))?;
    let made = settings.clone();
    // Making a key pair the first time takes a while: not on the runtime's threads.
    let mut client = tokio::task::spawn_blocking(move || client(&made))
        .await
        .map_err(|e| failed(&url, e))?
        .map_err(|e| failed(&url, e))?;
    let mode = match settings.mode {
        "Sign" => MessageSecurityMode::Sign,
        "SignAndEncrypt" => MessageSecurityMode::SignAndEncrypt,
        _ => MessageSecurityMode::None,
    };
    let endpoint = endpoint(&client, &settings, mode, &identity)
        .await
        .map_err(|e| failed(&url, e))?;
    let (session, event_loop) = client
        .connect_to_endpoint_directly(endpoint, identity)
        .map_err(|e| failed(&url, e))?;
    session.disable_reconnects();
    let (tell, lost) = watch::channel(None);
    let dropped = Arc::new(AtomicU64::new(0));
    let pump = tokio::spawn(drive(event_loop, tell, progress.clone(), dropped.clone()));
    let mut conn = Connection {
        session,
        generation: OPENED.fetch_add(1, Ordering::Relaxed),
        namespaces: Vec::new(),
        settings,
        progress,
        lost,
        dropped,
        limits: Default::default(),
        closed: false,
        pump,
    };
    let session = conn.session.clone();
    let connected = tokio::select! {
        ok = session.wait_for_connection() => ok,
        why = conn.lost_now() => return Err(failed(&url, why)),
    };
    if !connected {
        return Err(failed(&url, "the session did not open"));
    }
    let namespaces = conn
        .session
        .read_namespace_array()
        .await
        .map_err(|e| failed(&url, format!("reading the namespace array: {e}")))?;
    let mut uris: Vec<(u16, String)> = namespaces
        .known_namespaces()
        .iter()
        .map(|(uri, i)| (*i, uri.clone()))
        .collect();
    uris.sort();
    conn.namespaces = uris.into_iter().map(|(_, uri)| uri).collect();
    conn.limits = super::limits::read(&conn.session).await;
    tracing::debug!(%url, "items per request: {}", conn.limits.says());
    Ok(conn)
}

/// Drives the session's event loop until the connection is lost, telling why; counts the
/// publish answers that say the server has no subscription of the session in `dropped`.
async fn drive(
    event_loop: opcua::client::SessionEventLoop<opcua::client::transport::TcpConnector>,
    tell: watch::Sender<Option<String>>,
    progress: Arc<Progress>,
    dropped: Arc<AtomicU64>,
) {
    use opcua::client::{SessionActivity, SubscriptionActivity};
    let stream = event_loop.enter();
    tokio::pin!(stream);
    let why = loop {
        match stream.next().await {
            None => break "the session closed".to_owned(),
            Some(Err(code)) => break format!("the session ended: {code}"),
            Some(Ok(event)) => match event {
                SessionPollResult::Subscription(SubscriptionActivity::Publish)
                | SessionPollResult::SessionActivity(SessionActivity::KeepAliveSucceeded) => {
                    progress.ended();
                }
                SessionPollResult::ConnectionLost(code) => {
                    break format!("connection lost: {code}");
                }
                SessionPollResult::ReconnectFailed(code) => {
                    break format!("cannot connect: {code}");
                }
                SessionPollResult::Subscription(SubscriptionActivity::FatalFailure(code)) => {
                    break format!("publishing failed: {code}");
                }
                SessionPollResult::Subscription(SubscriptionActivity::PublishFailed(code))
                    if subscriptions_gone(code) =>
                {
                    progress.ended();
                    dropped.fetch_add(1, Ordering::Relaxed);
                }
                _ => {}
            },
        }
    };
    tell.send_replace(Some(why));
}

/// Whether a publish answer says the server holds no (or not that) subscription of the
/// session: it deleted them.
fn subscriptions_gone(code: StatusCode) -> bool {
    [
        StatusCode::BadNoSubscription,
        StatusCode::BadSubscriptionIdInvalid,
    ]
    .iter()
    .any(|c| c.sub_code() == code.sub_code())
}

impl Connection {
    /// Resolves when the connection is lost, with why.
    pub(crate) async fn lost_now(&mut self) -> String {
        match self.lost.wait_for(Option::is_some).await {
            Ok(why) => why.clone().unwrap_or_default(),
            Err(_) => "the session's task ended".to_owned(),
        }
    }

    /// A service call's failure as the link's: a status that says the session or its
    /// connection is gone ends the link; anything else is the request's own.
    pub(crate) fn fault(&self, e: &opcua::types::Error) -> Option<LinkFault> {
        let code = e.status();
        let gone = [
            StatusCode::BadTimeout,
            StatusCode::BadConnectionClosed,
            StatusCode::BadNotConnected,
            StatusCode::BadSessionIdInvalid,
            StatusCode::BadSessionClosed,
            StatusCode::BadSessionNotActivated,
            StatusCode::BadSecureChannelClosed,
            StatusCode::BadSecureChannelIdInvalid,
            StatusCode::BadCommunicationError,
            StatusCode::BadServerHalted,
            StatusCode::BadShutdown,
            StatusCode::BadRequestTimeout,
        ];
        gone.iter()
            .any(|g| g.sub_code() == code.sub_code())
            .then(|| LinkFault::lost(super::UaError::Ended(e.to_string())))
    }

    /// Marks a request to the server in progress, for the watchdog.
    pub(crate) fn started(&self) {
        self.progress
            .started(tokio::time::Instant::now() + REQUEST_TIMEOUT);
    }

    pub(crate) fn ended(&self) {
        self.progress.ended();
    }
}
