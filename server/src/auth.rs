//! Who may do what: bearer tokens with roles `read` < `write` < `admin`, loaded from
//! `security.tokens_file` (and the `IOGATE_TOKENS` environment variable), one `ROLE TOKEN`
//! per line. Tokens never appear in logs or messages. Without tokens every request is
//! allowed, and the listeners must be on loopback (or `security.insecure: true`).

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, RwLock};

/// What a token allows; each role includes the ones before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(crate) enum Role {
    /// Read values, diagnostics, events, profiles, the map.
    Read,
    /// Also write outputs, set simulated inputs, run transactions.
    Write,
    /// Also declare (and remove) links, devices and transactions.
    Admin,
}

impl Role {
    pub(crate) fn parse(text: &str) -> Option<Role> {
        match text {
            "read" => Some(Role::Read),
            "write" => Some(Role::Write),
            "admin" => Some(Role::Admin),
            _ => None,
        }
    }

    pub(crate) fn name(self) -> &'static str {
        match self {
            Role::Read => "read",
            Role::Write => "write",
            Role::Admin => "admin",
        }
    }
}

/// Why a request is refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Denied {
    /// No token, or one that is not known (401 / UNAUTHENTICATED).
    Unauthenticated,
    /// A known token whose role is too low (403 / PERMISSION_DENIED).
    Forbidden { needed: Role },
}

/// A problem of the tokens, and where it is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) enum TokensProblem {
    /// A bad line of the tokens file (1-based).
    Line { line: u64, message: String },
    /// The tokens file cannot be read; `line` when a byte of it is not UTF-8.
    File { line: Option<u64>, message: String },
    /// A bad entry of `IOGATE_TOKENS` (1-based).
    Env { entry: u64, message: String },
}

/// Tokens as read, each with its (1-based) line and its role.
type Entries = HashMap<String, (u64, Role)>;

/// The known tokens.
#[derive(Clone, Default)]
pub struct Tokens(HashMap<String, Role>);

impl std::fmt::Debug for Tokens {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never the tokens themselves.
        write!(f, "Tokens({} configured)", self.0.len())
    }
}

impl Tokens {
    /// Parses `ROLE TOKEN` lines (blank lines and `#` comments skipped): the tokens, or
    /// every bad line (1-based) with what is wrong, never the token itself.
    pub(crate) fn parse(text: &str) -> Result<Tokens, Vec<(u64, String)>> {
        let entries = Tokens::entries(text)?;
        Ok(Tokens(
            entries
                .into_iter()
                .map(|(token, (_, role))| (token, role))
                .collect(),
        ))
    }

    /// [`Tokens::parse`]'s work: each token with its line and role.
    fn entries(text: &str) -> Result<Entries, Vec<(u64, String)>> {
        let mut lines = Entries::new();
        let mut bad = Vec::new();
        for (n, line) in text.lines().enumerate() {
            let n = n as u64 + 1;
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let mut parts = line.split_whitespace();
            let (Some(role), Some(token), None) = (parts.next(), parts.next(), parts.next()) else {
                bad.push((
                    n,
                    "expected `ROLE TOKEN` (ROLE is read, write or admin)".to_owned(),
                ));
                continue;
            };
            let Some(role) = Role::parse(role) else {
                bad.push((
                    n,
                    format!(
                        "unknown role `{}` (expected read, write or admin)",
                        crate::text::quote(role)
                    ),
                ));
                continue;
            };
            if token.len() < 16 {
                bad.push((
                    n,
                    "the token is too short (at least 16 characters)".to_owned(),
                ));
                continue;
            }
            match lines.get(token) {
                Some(&(first, first_role)) => bad.push((
                    n,
                    format!(
                        "this token is given on line {first} already (as {}): a token has one role",
                        first_role.name()
                    ),
                )),
                None => {
                    lines.insert(token.to_owned(), (n, role));
                }
            }
        }
        if bad.is_empty() { Ok(lines) } else { Err(bad) }
    }

    /// The tokens of `file` and of the `IOGATE_TOKENS` environment variable (lines, or
    /// entries separated by `;`), or every problem with where it is.
    pub(crate) fn load(file: Option<&Path>) -> Result<Tokens, Vec<TokensProblem>> {
        let mut all = Tokens::default();
        let mut problems = Vec::new();
        if let Some(path) = file {
            match crate::text::read_file(path) {
                Ok(text) => match Tokens::parse(&text) {
                    Ok(t) => all.0.extend(t.0),
                    Err(bad) => problems.extend(
                        bad.into_iter()
                            .map(|(line, message)| TokensProblem::Line { line, message }),
                    ),
                },
                Err(e) => problems.push(TokensProblem::File {
                    line: e.line(),
                    message: format!("the tokens file {}: {e}", path.display()),
                }),
            }
        }
        if let Ok(env) = std::env::var("IOGATE_TOKENS") {
            match Tokens::entries(&env.replace(';', "\n")) {
                Ok(entries) => {
                    let mut twice = Vec::new();
                    for (token, (entry, role)) in entries {
                        match all.0.get(&token) {
                            Some(first) => twice.push((entry, first.name())),
                            None => {
                                all.0.insert(token, role);
                            }
                        }
                    }
                    twice.sort_unstable();
                    problems.extend(twice.into_iter().map(|(entry, first)| TokensProblem::Env {
                        entry,
                        message: format!(
                            "this token is in the tokens file already (as {first}): a token has one role"
                        ),
                    }));
                }
                Err(bad) => problems.extend(
                    bad.into_iter()
                        .map(|(entry, message)| TokensProblem::Env { entry, message }),
                ),
            }
        }
        if problems.is_empty() {
            Ok(all)
        } else {
            Err(problems)
        }
    }

    pub(crate) fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The role of `token` (a password given by an OPC UA client), compared in full
    /// against every known token.
    pub(crate) fn role_of(&self, token: &str) -> Option<Role> {
        self.0
            .iter()
            .filter(|(t, _)| constant_eq(t.as_bytes(), token.as_bytes()))
            .map(|(_, r)| *r)
            .max()
    }

    /// Whether a request with `authorization` (the header's value) may do `operation`.
    /// Without tokens configured everything is allowed.
    fn check(&self, authorization: Option<&str>, operation: Operation) -> Result<(), Denied> {
        if self.0.is_empty() {
            return Ok(());
        }
        let token = authorization
            .and_then(|v| {
                v.strip_prefix("Bearer ")
                    .or_else(|| v.strip_prefix("bearer "))
            })
            .map(str::trim)
            .ok_or(Denied::Unauthenticated)?;
        // Compare every known token in full (no early exit on the first byte).
        let role = self.role_of(token).ok_or(Denied::Unauthenticated)?;
        operation.allowed_to(role)
    }
}

fn constant_eq(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Everything a client can ask of the gateway, whatever the front-end: each front-end names
/// the operation a request is (a REST route, a gRPC method), and the role it needs is
/// declared here, once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Operation {
    /// Values, diagnostics, links, devices, profiles, write outcomes, the map, memory,
    /// standing transactions' states, plans, the OpenAPI document.
    Read,
    /// A stream of changes (SSE, gRPC Subscribe).
    Subscribe,
    /// Writing outputs (REST PUT/PATCH, gRPC Write, the map, a scan-cycle exchange).
    WriteOutputs,
    /// Setting a simulated device's input.
    Simulate,
    /// A raw transaction on a link.
    Transact,
    /// Switching, triggering or setting the values of a standing transaction.
    SwitchTransaction,
    /// Declaring a link, device or standing transaction.
    Declare,
    /// Removing what was declared.
    Remove,
    /// Loading the configuration again and applying what changed.
    Reload,
    /// Scanning a link for devices (probes every slave id between polls).
    Scan,
}

impl Operation {
    /// Whether a client whose role is `role` may do it: the one rule of every front-end (a
    /// bearer token's role over REST and gRPC, an OPC UA session's, the MQTT front-end's
    /// own from `mqtt.writes`).
    pub(crate) fn allowed_to(self, role: Role) -> Result<(), Denied> {
        let needed = self.role();
        if role >= needed {
            Ok(())
        } else {
            Err(Denied::Forbidden { needed })
        }
    }

    /// The role the operation needs.
    pub(crate) const fn role(self) -> Role {
        match self {
            Operation::Read | Operation::Subscribe => Role::Read,
            Operation::WriteOutputs
            | Operation::Simulate
            | Operation::Transact
            | Operation::SwitchTransaction => Role::Write,
            Operation::Declare | Operation::Remove | Operation::Reload | Operation::Scan => {
                Role::Admin
            }
        }
    }
}

/// The tokens in force: every clone sees the same table, which a configuration reload
/// replaces whole (a request is checked against the old table or the new, never a mix).
#[derive(Clone, Default)]
pub struct TokenTable(Arc<RwLock<Arc<Tokens>>>);

impl std::fmt::Debug for TokenTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.current().fmt(f)
    }
}

impl TokenTable {
    pub(crate) fn current(&self) -> Arc<Tokens> {
        self.0.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// Puts `tokens` in force for every request from now on.
    pub(crate) fn replace(&self, tokens: Tokens) {
        *self.0.write().unwrap_or_else(|e| e.into_inner()) = Arc::new(tokens);
    }

    /// Whether a request with `authorization` (the header's value) may do `operation`.
    pub(crate) fn allows(
        &self,
        authorization: Option<&str>,
        operation: Operation,
    ) -> Result<(), Denied> {
        self.current().allows(authorization, operation)
    }
}

impl Tokens {
    /// What changed from `self` to `new`, never naming a token: how many were added and
    /// removed and whose role changed, by role.
    pub(crate) fn changes_to(&self, new: &Tokens) -> Vec<String> {
        let mut changes = Vec::new();
        let count = |f: &dyn Fn(&String, &Role) -> bool, map: &HashMap<String, Role>| {
            let mut by_role: Vec<(Role, usize)> = Vec::new();
            for (token, role) in map {
                if f(token, role) {
                    match by_role.iter_mut().find(|(r, _)| r == role) {
                        Some((_, n)) => *n += 1,
                        None => by_role.push((*role, 1)),
                    }
                }
            }
            by_role.sort();
            by_role
                .into_iter()
                .map(|(r, n)| format!("{n} {}", r.name()))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let added = count(&|t, _| !self.0.contains_key(t), &new.0);
        let removed = count(&|t, _| !new.0.contains_key(t), &self.0);
        let role = count(&|t, r| self.0.get(t).is_some_and(|old| old != r), &new.0);
        for (what, list) in [
            ("added", added),
            ("removed", removed),
            ("given another role", role),
        ] {
            if !list.is_empty() {
                changes.push(format!("tokens {what}: {list}"));
            }
        }
        changes
    }

    /// Whether a request with `authorization` (the header's value) may do `operation`.
    pub(crate) fn allows(
        &self,
        authorization: Option<&str>,
        operation: Operation,
    ) -> Result<(), Denied> {
        self.check(authorization, operation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const READ: &str = "reader-0123456789abcdef";
    const WRITE: &str = "writer-0123456789abcdef";
    const ADMIN: &str = "admin-0123456789abcdefg";

    fn tokens() -> Tokens {
        Tokens::parse(&format!(
            "# roles\nread {READ}\n\nwrite {WRITE}\nadmin {ADMIN}\n"
        ))
        .expect("tokens")
    }

    #[test]
    fn roles_include_the_ones_below() {
        let t = tokens();
        let bearer = |tok: &str| format!("Bearer {tok}");
        let (read, write, admin) = (Operation::Read, Operation::WriteOutputs, Operation::Declare);
        assert_eq!(t.allows(None, read), Err(Denied::Unauthenticated));
        assert_eq!(
            t.allows(Some("Bearer nope-nope-nope-nope"), read),
            Err(Denied::Unauthenticated)
        );
        assert_eq!(t.allows(Some(&bearer(READ)), read), Ok(()));
        assert_eq!(
            t.allows(Some(&bearer(READ)), write),
            Err(Denied::Forbidden {
                needed: Role::Write
            })
        );
        assert_eq!(t.allows(Some(&bearer(WRITE)), write), Ok(()));
        assert_eq!(t.allows(Some(&bearer(ADMIN)), admin), Ok(()));
        assert_eq!(Tokens::default().allows(None, admin), Ok(()));
    }

    #[test]
    fn a_token_given_twice_is_refused_naming_both_lines() {
        let e = Tokens::parse(
            "read s3cret-s3cret-s3cret\nwrite other-token-0000000\nadmin s3cret-s3cret-s3cret\n",
        )
        .expect_err("the same token twice");
        assert_eq!(e.len(), 1, "{e:?}");
        assert_eq!(e[0].0, 3);
        assert_eq!(
            e[0].1,
            "this token is given on line 1 already (as read): a token has one role"
        );
    }

    #[test]
    fn bad_token_files_name_every_line_never_the_token() {
        let e = Tokens::parse("root s3cret-s3cret-s3cret\n# fine\nread short\nwrite\n")
            .expect_err("bad lines");
        let lines: Vec<u64> = e.iter().map(|(l, _)| *l).collect();
        assert_eq!(lines, [1, 3, 4], "{e:?}");
        assert!(e[0].1.contains("unknown role `root`"), "{e:?}");
        assert!(e[1].1.contains("too short"), "{e:?}");
        assert!(!format!("{e:?}").contains("s3cret"), "{e:?}");
        assert!(format!("{:?}", tokens()).contains("3 configured"));
    }

    #[test]
    fn each_operation_needs_its_role() {
        let bearer = |tok: &str| format!("Bearer {tok}");
        assert_eq!(Operation::Read.role(), Role::Read);
        assert_eq!(Operation::Subscribe.role(), Role::Read);
        assert_eq!(Operation::WriteOutputs.role(), Role::Write);
        assert_eq!(Operation::Transact.role(), Role::Write);
        assert_eq!(Operation::Declare.role(), Role::Admin);
        assert_eq!(Operation::Remove.role(), Role::Admin);
        assert_eq!(Operation::Scan.role(), Role::Admin);
        let t = tokens();
        assert_eq!(
            t.allows(Some(&bearer(READ)), Operation::WriteOutputs),
            Err(Denied::Forbidden {
                needed: Role::Write
            })
        );
        assert_eq!(t.allows(Some(&bearer(ADMIN)), Operation::Remove), Ok(()));
    }
}
