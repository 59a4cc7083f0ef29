//! A private CA and the certificates it signs, for `coadapt tls new` and tests.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use rcgen::{BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair, KeyUsagePurpose};

/// PEM texts of a CA, a server certificate and a client certificate it signed.
#[derive(Clone)]
pub struct Credentials {
    pub ca: String,
    pub ca_key: String,
    pub server: String,
    pub server_key: String,
    pub client: String,
    pub client_key: String,
}

impl std::fmt::Debug for Credentials {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Credentials(<redacted keys>)")
    }
}

impl Credentials {
    /// A new CA (valid from an hour ago for `days`) and, signed by it, a server certificate for
    /// `hosts` (names or IP addresses; the server-auth usage) and a client certificate (the
    /// client-auth usage), each with a fresh key.
    pub fn generate(hosts: &[String], days: u32) -> Result<Self, rcgen::Error> {
        let since = SystemTime::now().duration_since(UNIX_EPOCH).unwrap_or_default();
        let not_before = rcgen::date_time_ymd(1970, 1, 1) + Duration::from_secs(since.as_secs().saturating_sub(3600));
        let not_after = not_before + Duration::from_secs(u64::from(days.max(1)) * 86_400);
        let dated = |mut p: CertificateParams, cn: &str| {
            p.not_before = not_before;
            p.not_after = not_after;
            p.distinguished_name.push(DnType::CommonName, cn);
            p
        };
        let ca_key = KeyPair::generate()?;
        let mut ca = dated(CertificateParams::new(Vec::<String>::new())?, "coadapt CA");
        ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
        ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign, KeyUsagePurpose::DigitalSignature];
        let ca_cert = ca.self_signed(&ca_key)?;
        let issuer = Issuer::new(ca, &ca_key);
        let mut server = dated(CertificateParams::new(hosts.to_vec())?, "coadapt server");
        server.extended_key_usages = vec![ExtendedKeyUsagePurpose::ServerAuth];
        let server_key = KeyPair::generate()?;
        let server_cert = server.signed_by(&server_key, &issuer)?;
        let mut client = dated(CertificateParams::new(Vec::<String>::new())?, "coadapt client");
        client.extended_key_usages = vec![ExtendedKeyUsagePurpose::ClientAuth];
        let client_key = KeyPair::generate()?;
        let client_cert = client.signed_by(&client_key, &issuer)?;
        Ok(Self {
            ca: ca_cert.pem(),
            ca_key: ca_key.serialize_pem(),
            server: server_cert.pem(),
            server_key: server_key.serialize_pem(),
            client: client_cert.pem(),
            client_key: client_key.serialize_pem(),
        })
    }

    /// Writes `ca.pem`, `ca-key.pem`, `server.pem`, `server-key.pem`, `client.pem` and
    /// `client-key.pem` into `dir` (keys readable by their owner only); an existing file is
    /// never replaced.
    pub fn write(&self, dir: &std::path::Path) -> std::io::Result<()> {
        use std::io::Write;
        std::fs::create_dir_all(dir)?;
        for (name, text, private) in [
            ("ca.pem", &self.ca, false),
            ("ca-key.pem", &self.ca_key, true),
            ("server.pem", &self.server, false),
            ("server-key.pem", &self.server_key, true),
            ("client.pem", &self.client, false),
            ("client-key.pem", &self.client_key, true),
        ] {
            let path = dir.join(name);
            let mut o = std::fs::OpenOptions::new();
            o.write(true).create_new(true);
            #[cfg(unix)]
            {
                use std::os::unix::fs::OpenOptionsExt;
                o.mode(if private { 0o600 } else { 0o644 });
            }
            let mut f = o.open(&path).map_err(|e| std::io::Error::new(e.kind(), format!("{}: {e}", path.display())))?;
            f.write_all(text.as_bytes())?;
            f.sync_all()?;
        }
        Ok(())
    }
}
