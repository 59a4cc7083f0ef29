//! Roles, tokens and the server's table of accepted tokens.

use std::collections::HashMap;
use std::fmt;
use std::path::Path;

use rand::Rng;
use sha2::{Digest, Sha256};

/// What a peer may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Role {
    /// A rollout actor: sends its own experience, takes assignments and acting weights, steps
    /// environments.
    Actor,
    /// The design optimiser: takes design requests and population weights, sends designs.
    Optimizer,
    /// A design client: Info, Score, Optimize, Landscape, History, Watch, ModelInfer (read
    /// only, within the server's budgets).
    Client,
    /// An operator: everything.
    Operator,
}

impl Role {
    pub const ALL: [Role; 4] = [Role::Actor, Role::Optimizer, Role::Client, Role::Operator];

    pub fn name(self) -> &'static str {
        match self {
            Role::Actor => "actor",
            Role::Optimizer => "optimizer",
            Role::Client => "client",
            Role::Operator => "operator",
        }
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Role {
    type Err = TokenError;
    fn from_str(s: &str) -> Result<Self, TokenError> {
        Role::ALL.into_iter().find(|r| r.name() == s).ok_or_else(|| TokenError::Role(s.to_string()))
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    #[error("{0:?} is not a role: actor, optimizer, client or operator")]
    Role(String),
    #[error("{path}: {why}")]
    File { path: String, why: String },
    #[error("{path} line {line}: {why}")]
    Line { path: String, line: usize, why: String },
    /// A token's text is shorter than 16 characters (trimmed); the length it has.
    #[error("a token is at least 16 characters, this one {0}")]
    TooShort(usize),
    /// A token's text holds a space or a byte that is not printable ASCII (it could not travel
    /// as an HTTP header value).
    #[error("a token is printable ASCII without spaces")]
    NotPrintable,
}

/// A secret token. Its `Debug` and `Display` never show it.
#[derive(Clone, PartialEq, Eq)]
pub struct Token(String);

impl Token {
    /// A token from its text (a file's content, trimmed). Refuses what could not travel as an
    /// HTTP header value.
    pub fn new(text: &str) -> Result<Self, TokenError> {
        let t = text.trim();
        if t.len() < 16 {
            return Err(TokenError::TooShort(t.len()));
        }
        if !t.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(TokenError::NotPrintable);
        }
        Ok(Self(t.to_string()))
    }

    /// The secret, for the one place that sends it (an `authorization` header).
    pub fn expose(&self) -> &str {
        &self.0
    }
}

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("Token(<redacted>)")
    }
}

/// A new random token: 256 bits from the operating system's generator, as 64 hex digits after
/// a `coadapt-` prefix (so a leaked one is recognisable in a scan).
pub fn new_token() -> Token {
    let mut bytes = [0u8; 32];
    rand::rng().fill(&mut bytes);
    Token(format!("coadapt-{}", hex(&bytes)))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// SHA-256 of a token, in hex: what the server's token file holds.
pub fn hash_token(token: &str) -> String {
    hex(&Sha256::digest(token.as_bytes()))
}

/// The tokens a server accepts, by hash.
#[derive(Clone, Debug, Default)]
pub struct TokenTable {
    roles: HashMap<String, Role>,
}

impl TokenTable {
    /// Reads `path`: one `ROLE SHA256-HEX` per line; `#` starts a comment; blank lines are
    /// skipped. Errors name the file and line.
    pub fn load(path: &Path) -> Result<Self, TokenError> {
        let p = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| TokenError::File { path: p.clone(), why: e.to_string() })?;
        Self::parse(&text, &p)
    }

    /// [`TokenTable::load`] from text; `path` names it in errors.
    pub fn parse(text: &str, path: &str) -> Result<Self, TokenError> {
        let mut roles = HashMap::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or_default().trim();
            if line.is_empty() {
                continue;
            }
            let bad = |why: String| TokenError::Line { path: path.to_string(), line: i + 1, why };
            let mut f = line.split_whitespace();
            let (Some(role), Some(hash), None) = (f.next(), f.next(), f.next()) else {
                return Err(bad("expected `ROLE SHA256-HEX` (coadapt token new writes these lines)".into()));
            };
            let role: Role = role.parse().map_err(|e: TokenError| bad(e.to_string()))?;
            if hash.len() != 64 || !hash.bytes().all(|b| b.is_ascii_hexdigit()) {
                return Err(bad("the hash is not 64 hex digits (a SHA-256): the file holds hashes of tokens, never tokens".into()));
            }
            roles.insert(hash.to_ascii_lowercase(), role);
        }
        Ok(Self { roles })
    }

    /// Adds a token's hash with its role.
    pub fn insert(&mut self, token: &Token, role: Role) {
        self.roles.insert(hash_token(token.expose()), role);
    }

    /// The role of `token`, if accepted.
    pub fn role_of(&self, token: &str) -> Option<Role> {
        self.roles.get(&hash_token(token)).copied()
    }

    pub fn len(&self) -> usize {
        self.roles.len()
    }

    pub fn is_empty(&self) -> bool {
        self.roles.is_empty()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn a_table_accepts_its_tokens_by_hash_and_names_bad_lines() {
        let (a, b) = (new_token(), new_token());
        assert_ne!(a, b);
        assert_eq!(format!("{a:?}"), "Token(<redacted>)");
        let text = format!("# fleet tokens\nactor {}\n\nclient {}  # dashboards\n", hash_token(a.expose()), hash_token(b.expose()));
        let t = TokenTable::parse(&text, "tokens").unwrap();
        assert_eq!(t.role_of(a.expose()), Some(Role::Actor));
        assert_eq!(t.role_of(b.expose()), Some(Role::Client));
        assert_eq!(t.role_of("coadapt-0000000000000000"), None);
        // SHA-256 of "abc" (FIPS 180-2 test vector).
        assert_eq!(hash_token("abc"), "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
        let e = TokenTable::parse("actor 1234\n", "tokens").unwrap_err().to_string();
        assert!(e.contains("tokens line 1") && e.contains("64 hex digits"), "{e}");
        let e = TokenTable::parse(&format!("\nadmin {}\n", hash_token("x")), "tokens").unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("\"admin\" is not a role"), "{e}");
        assert!(matches!(Token::new("short"), Err(TokenError::TooShort(5))));
        assert!(matches!(Token::new("has a space in it ok"), Err(TokenError::NotPrintable)));
    }
}
