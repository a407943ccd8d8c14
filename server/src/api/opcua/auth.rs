//! Who an OPC UA session is: anonymous (when allowed) or user `token` with one of the
//! gateway's bearer tokens as password, whose role (read, write, admin) decides what the
//! session may do: a read role sees outputs without write access, so a write answers
//! `Bad_UserAccessDenied` before it reaches the service.

use std::sync::Arc;

use opcua::server::ServerEndpoint;
use opcua::server::address_space::AccessLevel;
use opcua::server::authenticator::{
    AuthManager, Password, UserToken, user_pass_security_policy_id,
};
use opcua::types::{Error, NodeId, StatusCode, UAString, UserTokenPolicy, UserTokenType};

use crate::api::opcua::config::Anonymous;
use crate::auth::{Operation, Role};
use crate::service::Service;

/// The user name whose password is a bearer token.
pub(crate) const TOKEN_USER: &str = "token";
/// The anonymous policy's id, as the OPC UA library checks it.
const POLICY_ID_ANONYMOUS: &str = "anonymous";

/// The gateway's sessions' identities, checked against the service's tokens as they are
/// now (a reload that changes tokens applies to the next session).
pub(crate) struct Authenticator {
    service: Arc<Service>,
    anonymous: Option<Anonymous>,
}

impl Authenticator {
    pub(crate) fn new(service: Arc<Service>, anonymous: Option<Anonymous>) -> Self {
        Authenticator { service, anonymous }
    }

    /// What an anonymous session may do, if anything: as configured, else everything
    /// while no tokens are configured (as REST), nothing once there are.
    fn anonymous_role(&self) -> Option<Role> {
        match self.anonymous {
            Some(Anonymous::Refused) => None,
            Some(Anonymous::Role(role)) => Some(role),
            None => self
                .service
                .tokens
                .current()
                .is_empty()
                .then_some(Role::Admin),
        }
    }
}

/// The role a session's user token stands for.
pub(crate) fn role_of(token: &UserToken, anonymous: Option<Role>) -> Option<Role> {
    if token.is_anonymous() {
        return anonymous;
    }
    Role::parse(&token.0)
}

#[async_trait::async_trait]
impl AuthManager for Authenticator {
    async fn authenticate_anonymous_token(&self, _endpoint: &ServerEndpoint) -> Result<(), Error> {
        match self.anonymous_role() {
            Some(_) => Ok(()),
            None => Err(Error::new(
                StatusCode::BadIdentityTokenRejected,
                "anonymous sessions are not allowed: sign in as user `token` with a bearer token as password",
            )),
        }
    }

    async fn authenticate_username_identity_token(
        &self,
        _endpoint: &ServerEndpoint,
        username: &str,
        password: &Password,
    ) -> Result<UserToken, Error> {
        let tokens = self.service.tokens.current();
        let role = if username == TOKEN_USER {
            tokens.role_of(password.get())
        } else {
            None
        };
        match role {
            Some(role) => Ok(UserToken(role.name().to_owned())),
            None if tokens.is_empty() => Err(Error::new(
                StatusCode::BadIdentityTokenRejected,
                "no tokens are configured: connect anonymously",
            )),
            None => Err(Error::new(
                StatusCode::BadUserAccessDenied,
                "unknown user or token (user `token`, a bearer token as password)",
            )),
        }
    }

    fn effective_user_access_level(
        &self,
        token: &UserToken,
        user_access_level: AccessLevel,
        _node_id: &NodeId,
    ) -> AccessLevel {
        match role_of(token, self.anonymous_role()) {
            Some(role) if Operation::WriteOutputs.allowed_to(role).is_ok() => user_access_level,
            Some(_) => user_access_level - AccessLevel::CURRENT_WRITE,
            None => AccessLevel::empty(),
        }
    }

    fn user_token_policies(&self, endpoint: &ServerEndpoint) -> Vec<UserTokenPolicy> {
        let mut policies = Vec::with_capacity(2);
        if self.anonymous_role().is_some() {
            policies.push(UserTokenPolicy {
                policy_id: UAString::from(POLICY_ID_ANONYMOUS),
                token_type: UserTokenType::Anonymous,
                issued_token_type: UAString::null(),
                issuer_endpoint_url: UAString::null(),
                security_policy_uri: UAString::null(),
            });
        }
        policies.push(UserTokenPolicy {
            policy_id: user_pass_security_policy_id(endpoint),
            token_type: UserTokenType::UserName,
            issued_token_type: UAString::null(),
            issuer_endpoint_url: UAString::null(),
            security_policy_uri: UAString::null(),
        });
        policies
    }
}
