//! `[security]`: TLS and role tokens for every gRPC endpoint a process serves or calls.

use std::net::SocketAddr;

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

/// Refuses to serve plaintext on `addr` unless it is loopback, TLS is configured, or the
/// operator said `insecure`; `key` names the setting in the error.
pub fn check_plaintext_listen(key: &str, addr: SocketAddr, cfg: &SecurityConfig) -> anyhow::Result<()> {
    if addr.ip().is_loopback() || cfg.insecure || !cfg.tls_cert.trim().is_empty() {
        return Ok(());
    }
    anyhow::bail!(
        "{key} = {addr}: not a loopback address, and no TLS is configured (security.tls-cert, security.tls-key): anyone who \
         reaches the port could read and write the run. Configure TLS, listen on 127.0.0.1, or set security.insecure \
         (--insecure) on a network you trust"
    )
}
