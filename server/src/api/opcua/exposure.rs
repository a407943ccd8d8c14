//! The OPC UA section as one of the front-ends' sections: the address `serve --opcua`
//! moves, and the rules of serving it beyond loopback (as for HTTP: neither the `none`
//! endpoint nor sessions nobody signs in to, unless `security.insecure: true`).

use std::net::SocketAddr;

use super::config::{Anonymous, Endpoint, OpcUaConfig};
use crate::config::{Exposure, Section};
use crate::yaml::Report;

impl Section for OpcUaConfig {
    fn line(&self) -> u64 {
        self.line
    }

    fn listen_mut(&mut self) -> Option<&mut SocketAddr> {
        Some(&mut self.listen)
    }

    fn check_exposure(&self, exposure: &Exposure, report: &mut Report) {
        let opcua = self;
        let addr = opcua.listen;
        if addr.ip().is_loopback() || exposure.insecure {
            return;
        }
        if opcua.security.contains(&Endpoint::None) {
            report.push(
                opcua.line,
                "opcua.security",
                format!(
                    "{addr} is not a loopback address: the `none` endpoint would send everything unsigned and in clear; remove it, or set security.insecure: true"
                ),
            );
        }
        if opcua.trust_client_certs {
            report.push(
                opcua.line,
                "opcua.trust_client_certs",
                format!(
                    "{addr} is not a loopback address: trusting every client certificate gives anyone who reaches it a secure channel; trust certificates one by one (pki_dir/trusted), or set security.insecure: true"
                ),
            );
        }
        if let Some(Anonymous::Role(role)) = opcua.anonymous
            && role > crate::auth::Role::Read
        {
            report.push(
                opcua.line,
                "opcua.anonymous",
                format!(
                    "{addr} is not a loopback address: anonymous sessions with the {} role let anyone who reaches it change the plant; give anonymous `read` or `false` and sign in with tokens, or set security.insecure: true",
                    role.name()
                ),
            );
        }
        let anonymous_allowed = match opcua.anonymous {
            Some(Anonymous::Refused) => false,
            Some(Anonymous::Role(_)) => true,
            None => exposure.no_tokens,
        };
        if exposure.no_tokens && anonymous_allowed {
            report.push(
                opcua.line,
                "opcua.listen",
                format!(
                    "{addr} is not a loopback address and no tokens are configured: set security.tokens_file (or IOGATE_TOKENS), or security.insecure: true to serve it unauthenticated"
                ),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::config::check_security;

    fn problems(text: &str) -> String {
        let mut config = crate::config::parse("iogate.yaml", text).expect("parses");
        let mut report = crate::yaml::Report::new("iogate.yaml");
        let node = config
            .sections
            .written()
            .find(|(key, _, _)| *key == "opcua")
            .map(|(_, _, node)| node.clone())
            .expect("an opcua section");
        let section = super::super::config::read(&node, &mut report).expect("reads");
        config.sections.set("opcua", Box::new(section));
        match check_security(&config) {
            Ok(_) => String::new(),
            Err(p) => p.to_string(),
        }
    }

    #[test]
    fn off_loopback_opc_ua_needs_tokens_and_no_clear_endpoint() {
        assert_eq!(problems("opcua: { listen: 127.0.0.1:4840 }\n"), "");
        let wide = problems("opcua: { listen: 0.0.0.0:4840, security: [none] }\n");
        assert!(
            wide.contains("the `none` endpoint would send everything"),
            "{wide}"
        );
        assert!(wide.contains("no tokens are configured"), "{wide}");
        // Anonymous refused: nobody signs in without a token, so no tokens means no
        // sessions, which is allowed.
        assert_eq!(
            problems("opcua: { listen: 0.0.0.0:4840, anonymous: false }\n"),
            ""
        );
        assert_eq!(
            problems(
                "opcua: { listen: 0.0.0.0:4840, security: [none] }\nsecurity: { insecure: true }\n"
            ),
            ""
        );
    }

    #[test]
    fn off_loopback_anonymous_may_not_write_and_no_certificate_is_trusted_blindly() {
        let tokens =
            std::env::temp_dir().join(format!("iogate-check-tokens-{}", std::process::id()));
        std::fs::write(&tokens, "admin admin-0123456789abcdef\n").expect("tokens");
        let wide = problems(&format!(
            "opcua: {{ listen: 0.0.0.0:4840, security: [basic256sha256_sign_encrypt], anonymous: admin, trust_client_certs: true }}\nsecurity: {{ tokens_file: {} }}\n",
            tokens.display()
        ));
        assert!(
            wide.contains("anonymous sessions with the admin role"),
            "{wide}"
        );
        assert!(wide.contains("trusting every client certificate"), "{wide}");
        let reader = problems(&format!(
            "opcua: {{ listen: 0.0.0.0:4840, security: [basic256sha256_sign_encrypt], anonymous: read }}\nsecurity: {{ tokens_file: {} }}\n",
            tokens.display()
        ));
        assert_eq!(reader, "");
        std::fs::remove_file(&tokens).expect("cleanup");
    }
}
