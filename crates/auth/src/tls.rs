//! PEM files into tonic's (rustls) TLS settings.

use std::path::{Path, PathBuf};

use tonic::transport::{Certificate, ClientTlsConfig, Identity, ServerTlsConfig};

#[derive(Debug, thiserror::Error)]
pub enum TlsError {
    #[error("{key} = {path}: {why}")]
    File { key: &'static str, path: PathBuf, why: String },
    #[error("TLS: {0}")]
    Config(String),
}

fn read_pem(key: &'static str, path: &Path, what: &str) -> Result<Vec<u8>, TlsError> {
    let bytes = std::fs::read(path).map_err(|e| TlsError::File { key, path: path.to_path_buf(), why: e.to_string() })?;
    if !String::from_utf8_lossy(&bytes).contains("-----BEGIN ") {
        return Err(TlsError::File { key, path: path.to_path_buf(), why: format!("not a PEM file (expected {what})") });
    }
    Ok(bytes)
}

/// A server's TLS: its certificate and key, and with `client_ca` the CA its clients'
/// certificates must be signed by (mutual TLS).
#[derive(Clone, Debug)]
pub struct ServerTls {
    identity: Identity,
    client_ca: Option<Certificate>,
}

impl ServerTls {
    /// Reads the PEM files; `keys` names the settings in errors (`(cert, key, ca)`).
    pub fn load(
        cert: &Path,
        key: &Path,
        client_ca: Option<&Path>,
        keys: (&'static str, &'static str, &'static str),
    ) -> Result<Self, TlsError> {
        let c = read_pem(keys.0, cert, "a certificate")?;
        let k = read_pem(keys.1, key, "a private key")?;
        let client_ca = client_ca.map(|p| read_pem(keys.2, p, "a CA certificate").map(Certificate::from_pem)).transpose()?;
        Ok(Self { identity: Identity::from_pem(c, k), client_ca })
    }

    /// Whether clients must present a certificate.
    pub fn mutual(&self) -> bool {
        self.client_ca.is_some()
    }

    pub fn config(&self) -> ServerTlsConfig {
        let mut c = ServerTlsConfig::new().identity(self.identity.clone());
        if let Some(ca) = &self.client_ca {
            c = c.client_ca_root(ca.clone());
        }
        c
    }
}

/// A client's TLS: the CA that signed the servers, the name to check (empty: the host called),
/// and its own certificate for mutual TLS.
#[derive(Clone, Debug)]
pub struct ClientTls {
    ca: Certificate,
    server_name: String,
    identity: Option<Identity>,
}

impl ClientTls {
    pub fn load(
        ca: &Path,
        server_name: &str,
        identity: Option<(&Path, &Path)>,
        keys: (&'static str, &'static str, &'static str),
    ) -> Result<Self, TlsError> {
        let ca = Certificate::from_pem(read_pem(keys.0, ca, "a CA certificate")?);
        let identity = identity
            .map(|(c, k)| {
                Ok::<_, TlsError>(Identity::from_pem(read_pem(keys.1, c, "a certificate")?, read_pem(keys.2, k, "a private key")?))
            })
            .transpose()?;
        Ok(Self { ca, server_name: server_name.trim().to_string(), identity })
    }

    /// The settings for a call to `host` (checked against the server's certificate unless a
    /// server name is configured).
    pub fn config(&self, host: &str) -> ClientTlsConfig {
        let name = if self.server_name.is_empty() { host } else { &self.server_name };
        let mut c = ClientTlsConfig::new().ca_certificate(self.ca.clone()).domain_name(name.to_string());
        if let Some(id) = &self.identity {
            c = c.identity(id.clone());
        }
        c
    }
}
