//! What the MQTT front-end takes from its `mqtt:` section: the files it names, read once at
//! start; its role; what a reload's report says of a changed section.

use super::*;

/// What the front-end needs from the files its section names, read once at start.
pub(crate) struct Prepared {
    pub(super) config: MqttConfig,
    pub(super) password: Option<Vec<u8>>,
    pub(super) tls: Option<TlsSetup>,
}

impl Prepared {
    /// Whether the front-end may do `operation`, by the one role rule: its role is `write`
    /// with `mqtt.writes: true`, else `read`.
    pub(super) fn may(&self, operation: Operation) -> bool {
        let role = match self.config.writes {
            true => Role::Write,
            false => Role::Read,
        };
        operation.allowed_to(role).is_ok()
    }
}

/// What differs between two `mqtt:` sections, key by key, in a reload report's words (a
/// change restarts the front-end).
pub(crate) fn changed_keys(x: &MqttConfig, y: &MqttConfig) -> Vec<Option<String>> {
    use crate::service::{changed, changed_text, duration};
    vec![
        changed_text("url", &x.url, &y.url),
        changed_text("client_id", &x.client_id, &y.client_id),
        changed("username", &x.username, &y.username),
        (x.password != y.password).then(|| "password changed".to_owned()),
        (x.tls != y.tls).then(|| "tls changed".to_owned()),
        changed("version", &x.version, &y.version),
        changed_text("keep_alive", duration(x.keep_alive), duration(y.keep_alive)),
        changed_text("clean_start", x.clean_start, y.clean_start),
        (x.sparkplug != y.sparkplug).then(|| "sparkplug changed".to_owned()),
        (x.json != y.json).then(|| "json changed".to_owned()),
        (x.report != y.report).then(|| "report changed".to_owned()),
        (x.buffer != y.buffer).then(|| "buffer changed".to_owned()),
        changed_text("writes", x.writes, y.writes),
    ]
}

/// Reads the password and TLS files; a problem is named with its file.
pub(crate) fn prepare(config: &MqttConfig, base: &std::path::Path) -> Result<Prepared, String> {
    let password = match &config.password {
        None => None,
        Some(Password::File(path)) => {
            let path = base.join(path);
            let text = std::fs::read(&path)
                .map_err(|e| format!("mqtt.password_file {}: {e}", path.display()))?;
            // A trailing newline is the file's, not the password's.
            let end = text
                .iter()
                .rposition(|&b| b != b'\n' && b != b'\r')
                .map_or(0, |i| i + 1);
            Some(text[..end].to_vec())
        }
        Some(Password::Env(name)) => Some(
            std::env::var_os(name)
                .ok_or_else(|| format!("mqtt.password_env: the environment has no `{name}`"))?
                .into_encoded_bytes(),
        ),
    };
    let tls = if config.url.tls {
        let mut c = config.clone();
        c.tls.ca = c.tls.ca.map(|p| base.join(p));
        c.tls.cert = c.tls.cert.map(|p| base.join(p));
        c.tls.key = c.tls.key.map(|p| base.join(p));
        Some(TlsSetup::load(&c)?)
    } else {
        None
    };
    let mut config = config.clone();
    config.buffer.dir = config.buffer.dir.map(|d| base.join(d));
    Ok(Prepared {
        config,
        password,
        tls,
    })
}
