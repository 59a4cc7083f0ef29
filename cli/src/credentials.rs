//! `coadapt token new` and `coadapt tls new`: the credentials of a deployment, made by the
//! project itself (no openssl, no hand-written files).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};
use coadapt_auth::{Role, hash_token, new_token};

/// Role tokens.
#[derive(Debug, Subcommand)]
pub enum TokenCommand {
    /// Make a new random token (256 bits) for one role: the token goes to --out (created
    /// readable by its owner only; never printed), its SHA-256 to the server's --tokens-file.
    New(TokenNewArgs),
}

#[derive(Debug, Args)]
pub struct TokenNewArgs {
    /// actor (its own experience, assignments, acting weights, environments), optimizer
    /// (design requests, population weights), client (design queries, read only) or operator
    /// (everything).
    #[arg(long)]
    pub role: String,
    /// The file the token is written to (mode 600; refused if it exists). Give it to the peer:
    /// `security.token-file`, `--token-file`, or `COADAPT_TOKEN`.
    #[arg(long)]
    pub out: PathBuf,
    /// The server's table of accepted tokens (`security.tokens-file`): a `ROLE SHA256` line is
    /// appended (the file is created if missing). It holds no secret.
    #[arg(long)]
    pub tokens_file: Option<PathBuf>,
}

/// Creates `path` for writing, readable by its owner only; refuses to replace a file.
fn create_private(path: &Path) -> anyhow::Result<std::fs::File> {
    let mut o = std::fs::OpenOptions::new();
    o.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.mode(0o600);
    }
    o.open(path).with_context(|| format!("creating {} (an existing file is never replaced)", path.display()))
}

pub fn token(cmd: TokenCommand) -> anyhow::Result<()> {
    let TokenCommand::New(a) = cmd;
    let role: Role = a.role.parse().map_err(|e| anyhow::anyhow!("--role: {e}"))?;
    let token = new_token();
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut f = create_private(&a.out)?;
    writeln!(f, "{}", token.expose()).and_then(|()| f.sync_all()).with_context(|| format!("writing {}", a.out.display()))?;
    coadapt_log::logln!("token: a new {role} token in {} (mode 600)", a.out.display());
    if let Some(t) = &a.tokens_file {
        let mut f = std::fs::OpenOptions::new().create(true).append(true).open(t).with_context(|| format!("opening {}", t.display()))?;
        writeln!(f, "{role} {}", hash_token(token.expose()))
            .and_then(|()| f.sync_all())
            .with_context(|| format!("writing {}", t.display()))?;
        coadapt_log::logln!("token: its SHA-256 added to {} (the server's accepted tokens)", t.display());
    }
    Ok(())
}

/// TLS certificates.
#[derive(Debug, Subcommand)]
pub enum TlsCommand {
    /// Make a private CA and, signed by it, a server certificate and a client certificate (for
    /// mutual TLS): ca.pem, ca-key.pem, server.pem, server-key.pem, client.pem, client-key.pem
    /// in --out (keys mode 600). Servers take server*.pem and --tls-ca ca.pem for client-auth;
    /// clients take ca.pem (and client*.pem). Keep ca-key.pem off the fleet's machines.
    New(TlsNewArgs),
}

#[derive(Debug, Args)]
pub struct TlsNewArgs {
    /// The directory to write (created; existing files are never replaced).
    #[arg(long)]
    pub out: PathBuf,
    /// Names and addresses the server certificate is valid for (repeatable; localhost and
    /// 127.0.0.1 are always included).
    #[arg(long = "host")]
    pub hosts: Vec<String>,
    /// Days the certificates are valid.
    #[arg(long, default_value_t = 365)]
    pub days: u32,
}

pub fn tls(cmd: TlsCommand) -> anyhow::Result<()> {
    let TlsCommand::New(a) = cmd;
    if a.days == 0 {
        anyhow::bail!("--days: 0 would make certificates that are never valid");
    }
    let mut hosts = vec!["localhost".to_string(), "127.0.0.1".to_string()];
    for h in a.hosts.iter().map(|h| h.trim()).filter(|h| !h.is_empty()) {
        if !hosts.iter().any(|x| x == h) {
            hosts.push(h.to_string());
        }
    }
    let c = coadapt_auth::Credentials::generate(&hosts, a.days).context("making the certificates")?;
    c.write(&a.out).with_context(|| format!("writing the certificates to {}", a.out.display()))?;
    coadapt_log::logln!(
        "tls: a CA, a server certificate for {} and a client certificate in {} ({} days)",
        hosts.join(", "),
        a.out.display(),
        a.days
    );
    Ok(())
}
