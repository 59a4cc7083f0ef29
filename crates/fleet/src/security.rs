//! `[security]`: TLS and role tokens for every gRPC endpoint a process serves or calls.

use std::net::SocketAddr;
use std::sync::Arc;

use coadapt_auth::{ClientAuth, ClientTls, ServerAuth, ServerTls, Token, TokenTable};

use crate::SetupError;
use serde::{Deserialize, Serialize};

/// `[security]`: who may talk to the fleet's endpoints. Paths only: keys and tokens are read
/// from files (or `COADAPT_TOKEN`), never taken from arguments, and never logged.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, rename_all = "kebab-case", deny_unknown_fields)]
pub struct SecurityConfig {
    /// PEM certificate (chain) this process serves with; with `tls-key`, every endpoint it
    /// serves speaks TLS only. Empty: plaintext.
    pub tls_cert: String,
    /// PEM private key of `tls-cert` (a file readable only by its owner).
    pub tls_key: String,
    /// PEM certificate of the CA that signed the servers' certificates: a client verifies the
    /// server with it (and, with `client-auth`, a server verifies clients' certificates).
    /// Empty: clients speak plaintext.
    pub tls_ca: String,
    /// The name the servers' certificates are issued for, checked by clients (empty: the
    /// host of the address called).
    pub tls_server_name: String,
    /// Mutual TLS: a server with `tls-ca` requires a client certificate signed by it.
    pub client_auth: bool,
    /// A client's certificate and key for mutual TLS (PEM; empty: none).
    pub client_cert: String,
    pub client_key: String,
    /// Server: the accepted tokens, one `ROLE SHA256-OF-TOKEN` per line (`coadapt token new`
    /// appends). Empty: no token is asked for (loopback and trusted networks only).
    pub tokens_file: String,
    /// Client: a file holding this process's token (`COADAPT_TOKEN` in the environment wins).
    pub token_file: String,
    /// Serve plaintext and without tokens on an address other than loopback (a network you
    /// trust).
    pub insecure: bool,
}

/// Refuses to serve on `addr` unless it is loopback, or TLS **and** role tokens are configured,
/// or the operator said `insecure`; `key` names the setting in the error. TLS alone is not
/// enough: without a tokens file every caller would pass the gate as an operator, so anyone
/// who reaches the port could register as a role and read the run's networks.
pub fn check_listen(key: &str, addr: SocketAddr, cfg: &SecurityConfig) -> Result<(), SetupError> {
    let (tls, tokens) = (!cfg.tls_cert.trim().is_empty(), !cfg.tokens_file.trim().is_empty());
    if addr.ip().is_loopback() || cfg.insecure || tls && tokens {
        return Ok(());
    }
    let missing = match (tls, tokens) {
        (false, false) => "no TLS (security.tls-cert, security.tls-key) and no role tokens (security.tokens-file)",
        (false, true) => "no TLS (security.tls-cert, security.tls-key)",
        _ => "no role tokens (security.tokens-file; `coadapt token new` makes one)",
    };
    Err(SetupError::Config(format!(
        "{key} = {addr}: not a loopback address, and {missing}: anyone who reaches the port could read and write the \
         run. Off loopback a server needs TLS and tokens; listen on 127.0.0.1, or set security.insecure (--insecure) \
         on a network you trust"
    )))
}

fn path(p: &str) -> Option<&std::path::Path> {
    let p = p.trim();
    (!p.is_empty()).then(|| std::path::Path::new(p))
}

/// Warns when a file holding a secret can be read by others than its owner.
fn warn_if_shared(key: &str, p: &std::path::Path) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        if let Ok(m) = std::fs::metadata(p)
            && m.permissions().mode() & 0o077 != 0
        {
            coadapt_log::logln!("warning: {key} = {}: readable by others than its owner (chmod 600 it)", p.display());
        }
    }
}

impl SecurityConfig {
    /// What a server applies: TLS when `tls-cert` is set (with `client-auth`, client
    /// certificates signed by `tls-ca` are required), tokens when `tokens-file` is set.
    pub fn server_auth(&self) -> Result<ServerAuth, SetupError> {
        let tls = match (path(&self.tls_cert), path(&self.tls_key)) {
            (None, None) => None,
            (Some(_), None) => return Err(SetupError::Config("security.tls-key: missing; security.tls-cert needs its private key".into())),
            (None, Some(_)) => {
                return Err(SetupError::Config("security.tls-cert: missing; security.tls-key is set without its certificate".into()));
            }
            (Some(c), Some(k)) => {
                warn_if_shared("security.tls-key", k);
                let ca = if self.client_auth {
                    Some(path(&self.tls_ca).ok_or_else(|| {
                        SetupError::Config("security.tls-ca: client-auth needs the CA that signs the clients' certificates".into())
                    })?)
                } else {
                    None
                };
                Some(
                    ServerTls::load(c, k, ca, ("security.tls-cert", "security.tls-key", "security.tls-ca"))
                        .map_err(|e| SetupError::Config(e.to_string()))?,
                )
            }
        };
        let tokens = match path(&self.tokens_file) {
            None => None,
            Some(p) => {
                let t = TokenTable::load(p).map_err(|e| SetupError::Config(format!("security.tokens-file: {e}")))?;
                if t.is_empty() {
                    return Err(SetupError::Config(format!(
                        "security.tokens-file = {}: no tokens: every call would be refused (coadapt token new adds one)",
                        p.display()
                    )));
                }
                Some(Arc::new(t))
            }
        };
        Ok(ServerAuth { tls, tokens })
    }

    /// What a client presents: TLS when `tls-ca` is set (its own certificate with
    /// `client-cert`), the token of `COADAPT_TOKEN` or `token-file`.
    pub fn client_auth(&self) -> Result<ClientAuth, SetupError> {
        let identity = match (path(&self.client_cert), path(&self.client_key)) {
            (None, None) => None,
            (Some(c), Some(k)) => {
                warn_if_shared("security.client-key", k);
                Some((c, k))
            }
            _ => return Err(SetupError::Config("security.client-cert and security.client-key: set both or neither".into())),
        };
        let tls = match path(&self.tls_ca) {
            None if identity.is_some() => {
                return Err(SetupError::Config("security.tls-ca: a client certificate is of no use without TLS (set tls-ca)".into()));
            }
            None => None,
            Some(ca) => Some(
                ClientTls::load(ca, &self.tls_server_name, identity, ("security.tls-ca", "security.client-cert", "security.client-key"))
                    .map_err(|e| SetupError::Config(e.to_string()))?,
            ),
        };
        let token = match (std::env::var("COADAPT_TOKEN").ok().filter(|t| !t.trim().is_empty()), path(&self.token_file)) {
            (Some(t), _) => Some(Token::new(&t).map_err(|e| SetupError::Config(format!("COADAPT_TOKEN: {e}")))?),
            (None, Some(p)) => {
                warn_if_shared("security.token-file", p);
                let text = std::fs::read_to_string(p).map_err(SetupError::io(format!("security.token-file = {}", p.display())))?;
                Some(Token::new(&text).map_err(|e| SetupError::Config(format!("security.token-file = {}: {e}", p.display())))?)
            }
            (None, None) => None,
        };
        Ok(ClientAuth { tls, token })
    }
}
