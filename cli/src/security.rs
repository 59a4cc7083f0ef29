//! The `[security]` flags of the commands that serve or call without a run config; the
//! settings themselves are the fleet's ([`coadapt_fleet::SecurityConfig`]).

use std::path::PathBuf;

use coadapt_fleet::SecurityConfig;

/// `args`' flags over `cfg`.
pub fn with_args(mut cfg: SecurityConfig, a: &SecurityArgs) -> SecurityConfig {
    let set = |field: &mut String, v: &Option<PathBuf>| {
        if let Some(v) = v {
            *field = v.display().to_string();
        }
    };
    set(&mut cfg.tls_cert, &a.tls_cert);
    set(&mut cfg.tls_key, &a.tls_key);
    set(&mut cfg.tls_ca, &a.tls_ca);
    set(&mut cfg.client_cert, &a.client_cert);
    set(&mut cfg.client_key, &a.client_key);
    set(&mut cfg.tokens_file, &a.tokens_file);
    set(&mut cfg.token_file, &a.token_file);
    if let Some(n) = &a.tls_server_name {
        cfg.tls_server_name = n.clone();
    }
    cfg.client_auth |= a.client_auth;
    cfg.insecure |= a.insecure;
    cfg
}

/// TLS and token flags of the commands that serve or call without a run config (`serve`,
/// `env-serve`, `score`, `optimize`, `history`). Paths only: secrets stay in files.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct SecurityArgs {
    /// Serve TLS with this PEM certificate (with --tls-key).
    #[arg(long, value_name = "PEM")]
    pub tls_cert: Option<PathBuf>,
    /// The PEM private key of --tls-cert.
    #[arg(long, value_name = "PEM")]
    pub tls_key: Option<PathBuf>,
    /// The CA certificate that signed the server (a client checks the server with it; a server
    /// with --client-auth checks clients' certificates with it).
    #[arg(long, value_name = "PEM")]
    pub tls_ca: Option<PathBuf>,
    /// The name the server's certificate is issued for (default: the host called).
    #[arg(long, value_name = "NAME")]
    pub tls_server_name: Option<String>,
    /// Mutual TLS: require clients' certificates signed by --tls-ca.
    #[arg(long)]
    pub client_auth: bool,
    /// A client certificate for mutual TLS (PEM, with --client-key).
    #[arg(long, value_name = "PEM")]
    pub client_cert: Option<PathBuf>,
    #[arg(long, value_name = "PEM")]
    pub client_key: Option<PathBuf>,
    /// Serve: accept only the tokens in this file (`ROLE SHA256` lines; `coadapt token new`).
    #[arg(long, value_name = "FILE")]
    pub tokens_file: Option<PathBuf>,
    /// Call with the token in this file (`COADAPT_TOKEN` in the environment wins).
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// Serve plaintext (no TLS) on an address other than loopback: a network you trust only.
    #[arg(long)]
    pub insecure: bool,
}

/// The settings of `args` alone.
pub fn from_args(args: &SecurityArgs) -> SecurityConfig {
    with_args(SecurityConfig::default(), args)
}
