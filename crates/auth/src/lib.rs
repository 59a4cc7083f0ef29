//! Who may talk to coadapt's gRPC endpoints (the fleet, the design service, the inference
//! protocol, environments): TLS with rustls (optionally mutual) and bearer tokens with roles.
//!
//! # Layout
//! - `tokens`: [`Role`]s, [`new_token`], and the server's [`TokenTable`] (a file of
//!   `ROLE SHA256-OF-TOKEN` lines: the server holds no secret that a reader could replay).
//! - `tls`: PEM files into tonic's server and client TLS settings, with errors naming the file.
//! - `generate`: [`Credentials`], a private CA and the server and client certificates it
//!   signs (`coadapt tls new`, and the tests' certificates: nothing made by hand).
//! - `gate`: the interceptors: [`Gate`] on a server (UNAUTHENTICATED for a missing or unknown
//!   token, PERMISSION_DENIED for a role the service does not serve; the caller's [`Role`] put
//!   in the request's extensions for finer checks), [`Bearer`] on a client.
//! - `refusals`: the process's ledger of refused calls and connections by server, reason and
//!   peer (for `/metrics`), logging the first refusal per peer and a summary each minute.
//! - `peers`: [`LimitedIncoming`], a listener that closes connections beyond a limit per remote
//!   host and in all (tonic has no such setting), for every server that faces the network.
//!
//! Tokens travel only inside TLS in a real deployment: a server refuses to listen in plaintext
//! on anything but loopback unless told `insecure` (the binaries check it).

mod gate;
mod generate;
pub mod peers;
pub mod refusals;
mod tls;
mod tokens;

pub use gate::{AuthChannel, Bearer, Gate, GateCounts, caller_role, require};
pub use generate::Credentials;
pub use peers::{LimitedIncoming, LimitedStream, PeerLimits};
pub use tls::{ClientTls, ServerTls, TlsError};
pub use tokens::{Role, Token, TokenError, TokenTable, hash_token, new_token};

/// The peer authentication a server applies.
#[derive(Clone, Debug, Default)]
pub struct ServerAuth {
    /// TLS settings (`None`: plaintext).
    pub tls: Option<ServerTls>,
    /// Accepted tokens (`None`: no token asked for).
    pub tokens: Option<std::sync::Arc<TokenTable>>,
}

impl ServerAuth {
    /// The gate of a service that serves `roles`.
    pub fn gate(&self, roles: &'static [Role]) -> Gate {
        Gate::new(self.tokens.clone(), roles)
    }
}

/// How a client authenticates itself.
#[derive(Clone, Debug, Default)]
pub struct ClientAuth {
    /// TLS settings (`None`: plaintext).
    pub tls: Option<ClientTls>,
    /// The token sent with every call (`None`: none).
    pub token: Option<Token>,
}

impl ClientAuth {
    /// The interceptor that stamps this client's token on every call.
    pub fn bearer(&self) -> Bearer {
        Bearer::new(self.token.as_ref())
    }

    /// The endpoint of `addr` (`host:port`, `http://host:port` or `https://host:port`): with
    /// TLS configured always https (a `http://` address would otherwise silently go out in
    /// plaintext), checked against the server's certificate for the host called (or the
    /// configured server name); without, http (an `https://` address is refused: TLS needs the
    /// CA that signed the server).
    pub fn endpoint(&self, addr: &str) -> Result<tonic::transport::Endpoint, TlsError> {
        let rest = addr.trim();
        let (scheme, hostport) = match rest.split_once("://") {
            Some((s, r)) => (Some(s.to_ascii_lowercase()), r),
            None => (None, rest),
        };
        if let Some(s) = &scheme
            && s != "http"
            && s != "https"
        {
            return Err(TlsError::Config(format!("{addr:?}: the scheme is {s}, not http or https")));
        }
        let url = match (&self.tls, scheme.as_deref()) {
            (Some(_), _) => format!("https://{hostport}"),
            (None, Some("https")) => {
                return Err(TlsError::Config(format!("{addr:?} is https, but no CA is configured to check the server with (tls-ca)")));
            }
            (None, _) => format!("http://{hostport}"),
        };
        let ep = tonic::transport::Endpoint::from_shared(url.clone()).map_err(|e| TlsError::Config(format!("{addr:?}: {e}")))?;
        match &self.tls {
            None => Ok(ep),
            Some(t) => {
                let host = ep.uri().host().unwrap_or_default().trim_matches(['[', ']']).to_string();
                ep.tls_config(t.config(&host)).map_err(|e| TlsError::Config(e.to_string()))
            }
        }
    }
}
