//! The interceptors: a server's gate and a client's bearer token.

use std::net::IpAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use tonic::metadata::{AsciiMetadataValue, MetadataValue};
use tonic::service::Interceptor;
use tonic::service::interceptor::InterceptedService;
use tonic::transport::Channel;
use tonic::{Request, Status};

use crate::tokens::{Role, Token, TokenTable};

/// A server's check of every call: a token the table knows, of a role the service serves.
/// Without a table every call passes as an operator (loopback and trusted networks).
#[derive(Clone, Debug)]
pub struct Gate {
    tokens: Option<Arc<TokenTable>>,
    roles: &'static [Role],
    counts: Arc<GateCounts>,
    /// The server's name in the refusal ledger and its log lines (`fleet`, `design_service`).
    server: &'static str,
}

/// Calls a gate refused.
#[derive(Debug, Default)]
pub struct GateCounts {
    /// No token, or one the server does not know: UNAUTHENTICATED.
    pub unauthenticated: AtomicU64,
    /// A known token of a role the service does not serve: PERMISSION_DENIED.
    pub permission_denied: AtomicU64,
}

impl Gate {
    pub fn new(tokens: Option<Arc<TokenTable>>, roles: &'static [Role]) -> Self {
        Self { tokens, roles, counts: Arc::default(), server: "grpc" }
    }

    /// Names the server in the refusal ledger (see [`crate::refusals`]).
    pub fn server(mut self, name: &'static str) -> Self {
        self.server = name;
        self
    }

    /// Shares `counts` (several services of one server counting together).
    pub fn counting(mut self, counts: Arc<GateCounts>) -> Self {
        self.counts = counts;
        self
    }

    /// The calls refused so far.
    pub fn counts(&self) -> &Arc<GateCounts> {
        &self.counts
    }

    /// The role of a call's metadata, or the status that refuses it.
    pub fn check(&self, metadata: &tonic::metadata::MetadataMap) -> Result<Role, Status> {
        self.check_from(metadata, None)
    }

    /// [`Gate::check`] of a call from `peer`: a refusal is counted here and in the process's
    /// refusal ledger, by reason and peer (the first one from a peer is logged; the message
    /// names what is wrong with the `authorization` header, never its value).
    pub fn check_from(&self, metadata: &tonic::metadata::MetadataMap, peer: Option<IpAddr>) -> Result<Role, Status> {
        let r = self.check_uncounted(metadata);
        if let Err(s) = &r {
            let (c, reason) = if s.code() == tonic::Code::PermissionDenied {
                (&self.counts.permission_denied, "permission_denied")
            } else {
                (&self.counts.unauthenticated, "unauthenticated")
            };
            c.fetch_add(1, Ordering::Relaxed);
            crate::refusals::record(self.server, reason, peer, s.message(), crate::refusals::Notice::Log);
        }
        r
    }

    fn check_uncounted(&self, metadata: &tonic::metadata::MetadataMap) -> Result<Role, Status> {
        let Some(table) = &self.tokens else { return Ok(Role::Operator) };
        let Some(value) = metadata.get("authorization") else {
            return Err(Status::unauthenticated("authorization: missing; send `authorization: Bearer <token>`"));
        };
        let token = value.to_str().ok().and_then(bearer_token);
        let Some(token) = token else {
            return Err(Status::unauthenticated("authorization: not `Bearer <token>`"));
        };
        let Some(role) = table.role_of(token) else {
            return Err(Status::unauthenticated("authorization: this token is not accepted here"));
        };
        if !self.roles.contains(&role) && role != Role::Operator {
            let may: Vec<&str> = self.roles.iter().map(|r| r.name()).collect();
            return Err(Status::permission_denied(format!("role {role} may not call this service (it serves {})", may.join(", "))));
        }
        Ok(role)
    }
}

/// The token of an `authorization` value `Bearer <token>`; the scheme name is matched without
/// regard to case (RFC 6750 section 2.1 via RFC 7235: `bearer`, `BEARER` are the same scheme).
pub fn bearer_token(value: &str) -> Option<&str> {
    let (scheme, rest) = value.trim_start().split_once(' ')?;
    if !scheme.eq_ignore_ascii_case("bearer") {
        return None;
    }
    let token = rest.trim();
    (!token.is_empty()).then_some(token)
}

impl Interceptor for Gate {
    fn call(&mut self, mut req: Request<()>) -> Result<Request<()>, Status> {
        let peer = req.remote_addr().map(|a| a.ip());
        let role = self.check_from(req.metadata(), peer)?;
        req.extensions_mut().insert(role);
        Ok(req)
    }
}

/// The caller's role, as the gate put it (a service served without a gate: operator).
pub fn caller_role<T>(req: &Request<T>) -> Role {
    req.extensions().get::<Role>().copied().unwrap_or(Role::Operator)
}

/// PERMISSION_DENIED unless the caller is one of `roles` (or an operator); `what` names the
/// call in the error.
pub fn require<T>(req: &Request<T>, roles: &[Role], what: &str) -> Result<Role, Status> {
    let role = caller_role(req);
    if role == Role::Operator || roles.contains(&role) {
        Ok(role)
    } else {
        let may: Vec<&str> = roles.iter().map(|r| r.name()).collect();
        Err(Status::permission_denied(format!("role {role} may not {what} (only {})", may.join(", "))))
    }
}

/// A client's interceptor: its token on every call (nothing without one).
#[derive(Clone)]
pub struct Bearer {
    header: Option<AsciiMetadataValue>,
}

impl std::fmt::Debug for Bearer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.header.is_some() { "Bearer(<redacted>)" } else { "Bearer(none)" })
    }
}

impl Bearer {
    pub fn new(token: Option<&Token>) -> Self {
        // Token::new admits printable ASCII only: always a valid header value.
        let header = token.and_then(|t| MetadataValue::try_from(format!("Bearer {}", t.expose())).ok()).map(|mut v| {
            v.set_sensitive(true);
            v
        });
        Self { header }
    }
}

impl Interceptor for Bearer {
    fn call(&mut self, mut req: Request<()>) -> Result<Request<()>, Status> {
        if let Some(h) = &self.header {
            req.metadata_mut().insert("authorization", h.clone());
        }
        Ok(req)
    }
}

/// A client channel that stamps its token on every call.
pub type AuthChannel = InterceptedService<Channel, Bearer>;
