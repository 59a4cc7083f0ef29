//! Who is looking at the page, and what they may do: a login form takes a token once (in a POST
//! body, never a URL), checks it against the server's token table, and opens a session named by
//! a random id in an `HttpOnly; SameSite=Strict` cookie. The token itself is forgotten at once.
//! Every form that acts carries the session's CSRF token as well: a POST from another site has
//! neither the cookie (SameSite) nor the field, and is refused and counted.
//!
//! Without a token table (a loopback server without tokens, as the gRPC services then accept
//! anyone) the first visit opens an operator session by itself; the CSRF check stays.

use std::collections::HashMap;
use std::net::IpAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::http::HeaderMap;
use coadapt_auth::{Role, TokenTable};
use rand::Rng;

/// The name of the session cookie.
pub const COOKIE: &str = "coadapt_session";
/// How long a session lasts without being used.
const IDLE: Duration = Duration::from_secs(12 * 3600);
/// Sessions kept at most (the oldest is dropped first): a flood of logins cannot grow memory.
const MAX_SESSIONS: usize = 1024;
/// The name refusals are counted under in `/metrics` (`coadapt_refusals_total{server=...}`).
pub const SERVER: &str = "operator_page";

/// One browser's session.
#[derive(Clone, Debug)]
pub struct Session {
    pub role: Role,
    /// Sent in every form that acts, compared on every POST.
    pub csrf: String,
    /// What the last action said, shown once on the next page.
    pub flash: Option<(bool, String)>,
    used: Instant,
    /// The sessions' use counter at its last use: the least recently used goes first.
    tick: u64,
}

impl Session {
    /// May this session answer the run (confirm, as built, reject, reset)?
    pub fn may_act(&self) -> bool {
        self.role == Role::Operator
    }
}

/// The sessions of one server.
#[derive(Debug)]
pub struct Sessions {
    tokens: Option<Arc<TokenTable>>,
    /// Mark the cookie `Secure` (the server speaks TLS).
    secure: bool,
    open: Mutex<Open>,
}

#[derive(Debug, Default)]
struct Open {
    by_id: HashMap<String, Session>,
    ticks: u64,
}

/// Why a request was refused; said to the browser and counted.
#[derive(Debug, PartialEq, Eq)]
pub enum Refusal {
    /// No session (or an expired one): log in first.
    NoSession,
    /// The form's CSRF field is missing or wrong.
    Csrf,
    /// The session's role may not do this.
    Role(Role),
    /// The token is not in the table, or the role may not view the page.
    Login(&'static str),
}

impl Refusal {
    pub fn message(&self) -> String {
        match self {
            Refusal::NoSession => "no session: log in on the page first".into(),
            Refusal::Csrf => "the form's csrf field is missing or does not match the session: reload the page and try again".into(),
            Refusal::Role(r) => format!("role {r} may view the run but not answer it (an operator token can)"),
            Refusal::Login(why) => (*why).into(),
        }
    }

    fn reason(&self) -> &'static str {
        match self {
            Refusal::NoSession | Refusal::Login(_) => "unauthenticated",
            Refusal::Csrf => "csrf",
            Refusal::Role(_) => "permission_denied",
        }
    }

    /// Counts the refusal in the process's ledger (`/metrics`; the first one from a peer is
    /// logged). The message never holds what was sent.
    pub fn record(&self, peer: Option<IpAddr>) {
        coadapt_auth::refusals::record(SERVER, self.reason(), peer, &self.message(), coadapt_auth::refusals::Notice::Log);
    }
}

fn random_hex() -> String {
    let mut bytes = [0u8; 32];
    rand::rng().fill(&mut bytes);
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Equal strings, in time that does not depend on where they differ.
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

impl Sessions {
    pub fn new(tokens: Option<Arc<TokenTable>>, secure: bool) -> Self {
        Self { tokens, secure, open: Mutex::new(Open::default()) }
    }

    /// Whether the page asks for a token (the server has a token table).
    pub fn needs_login(&self) -> bool {
        self.tokens.is_some()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Open> {
        self.open.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The session of the request's cookie, if it is open (its idle clock restarts).
    pub fn get(&self, headers: &HeaderMap) -> Option<(String, Session)> {
        let id = cookie(headers, COOKIE)?;
        let mut open = self.lock();
        open.ticks += 1;
        let tick = open.ticks;
        let s = open.by_id.get_mut(id)?;
        if s.used.elapsed() > IDLE {
            open.by_id.remove(id);
            return None;
        }
        (s.used, s.tick) = (Instant::now(), tick);
        Some((id.to_string(), s.clone()))
    }

    /// The session `id` (just opened by [`Sessions::open_without_login`]).
    pub fn get_by_id(&self, id: &str) -> Option<Session> {
        self.lock().by_id.get(id).cloned()
    }

    /// Takes the session's flash message (shown once).
    pub fn take_flash(&self, id: &str) -> Option<(bool, String)> {
        self.lock().by_id.get_mut(id).and_then(|s| s.flash.take())
    }

    /// Sets the session's flash message: `ok` false for an error.
    pub fn flash(&self, id: &str, ok: bool, text: String) {
        if let Some(s) = self.lock().by_id.get_mut(id) {
            s.flash = Some((ok, text));
        }
    }

    /// Opens a session for `role`; returns its id.
    pub fn open(&self, role: Role) -> String {
        let id = random_hex();
        let mut open = self.lock();
        open.by_id.retain(|_, s| s.used.elapsed() <= IDLE);
        if open.by_id.len() >= MAX_SESSIONS
            && let Some(oldest) = open.by_id.iter().min_by_key(|(_, s)| s.tick).map(|(k, _)| k.clone())
        {
            open.by_id.remove(&oldest);
        }
        open.ticks += 1;
        let tick = open.ticks;
        open.by_id.insert(id.clone(), Session { role, csrf: random_hex(), flash: None, used: Instant::now(), tick });
        id
    }

    /// Without a token table, the operator session a first visit gets.
    pub fn open_without_login(&self) -> Option<String> {
        self.tokens.is_none().then(|| self.open(Role::Operator))
    }

    /// Checks `token` (from the login form): opens a session for its role if that role may
    /// view the page (client: view; operator: view and act).
    pub fn login(&self, token: &str) -> Result<String, Refusal> {
        let Some(table) = &self.tokens else { return Ok(self.open(Role::Operator)) };
        match table.role_of(token.trim()) {
            None => Err(Refusal::Login("this token is not accepted here")),
            Some(role @ (Role::Client | Role::Operator)) => Ok(self.open(role)),
            Some(_) => Err(Refusal::Login(
                "this token's role (an actor's or an optimiser's) may not view the page: use a client or operator token",
            )),
        }
    }

    /// Ends a session.
    pub fn close(&self, id: &str) {
        self.lock().by_id.remove(id);
    }

    /// The session of a POST that acts: open, with the form's `csrf`, and allowed to act.
    pub fn check_act(&self, headers: &HeaderMap, csrf: Option<&str>) -> Result<(String, Session), Refusal> {
        let (id, s) = self.get(headers).ok_or(Refusal::NoSession)?;
        if !csrf.is_some_and(|c| same(c, &s.csrf)) {
            return Err(Refusal::Csrf);
        }
        if !s.may_act() {
            return Err(Refusal::Role(s.role));
        }
        Ok((id, s))
    }

    /// The `Set-Cookie` value that hands a browser session `id`.
    pub fn set_cookie(&self, id: &str) -> String {
        let secure = if self.secure { "; Secure" } else { "" };
        format!("{COOKIE}={id}; Path=/; HttpOnly; SameSite=Strict; Max-Age={}{secure}", IDLE.as_secs())
    }

    /// The `Set-Cookie` value that ends it in the browser.
    pub fn clear_cookie(&self) -> String {
        let secure = if self.secure { "; Secure" } else { "" };
        format!("{COOKIE}=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0{secure}")
    }
}

/// The value of cookie `name` in the request's `Cookie` headers.
fn cookie<'a>(headers: &'a HeaderMap, name: &str) -> Option<&'a str> {
    headers
        .get_all(axum::http::header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .find(|(k, _)| *k == name)
        .map(|(_, v)| v)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(cookie: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(axum::http::header::COOKIE, cookie.parse().expect("a header value"));
        h
    }

    #[test]
    fn a_client_views_an_operator_acts_and_a_wrong_csrf_is_refused() {
        let (client, operator, actor) = (coadapt_auth::new_token(), coadapt_auth::new_token(), coadapt_auth::new_token());
        let mut table = TokenTable::default();
        table.insert(&client, Role::Client);
        table.insert(&operator, Role::Operator);
        table.insert(&actor, Role::Actor);
        let s = Sessions::new(Some(Arc::new(table)), true);
        assert!(s.needs_login() && s.open_without_login().is_none());
        assert_eq!(s.login("coadapt-nope"), Err(Refusal::Login("this token is not accepted here")));
        assert!(matches!(s.login(actor.expose()), Err(Refusal::Login(_))));

        let id = s.login(client.expose()).expect("a client may view");
        let h = headers(&format!("other=1; {COOKIE}={id}"));
        let (_, sess) = s.get(&h).expect("the session");
        assert_eq!(sess.role, Role::Client);
        assert_eq!(s.check_act(&h, Some(&sess.csrf)).map(|_| ()), Err(Refusal::Role(Role::Client)));

        let id = s.login(operator.expose()).expect("an operator may act");
        let h = headers(&format!("{COOKIE}={id}"));
        let csrf = s.get(&h).expect("the session").1.csrf;
        assert!(s.check_act(&h, Some(&csrf)).is_ok());
        assert_eq!(s.check_act(&h, None).map(|_| ()), Err(Refusal::Csrf));
        assert_eq!(s.check_act(&h, Some(&csrf[1..])).map(|_| ()), Err(Refusal::Csrf));
        assert_eq!(s.check_act(&headers("coadapt_session=forged"), Some(&csrf)).map(|_| ()), Err(Refusal::NoSession));
        s.close(&id);
        assert!(s.get(&h).is_none());
        assert!(s.set_cookie("x").contains("HttpOnly; SameSite=Strict") && s.set_cookie("x").ends_with("; Secure"));
    }

    #[test]
    fn sessions_are_bounded() {
        let s = Sessions::new(None, false);
        let first = s.open_without_login().expect("no login without a table");
        for _ in 0..MAX_SESSIONS {
            s.open(Role::Client);
        }
        assert_eq!(s.lock().by_id.len(), MAX_SESSIONS);
        assert!(s.get(&headers(&format!("{COOKIE}={first}"))).is_none(), "the oldest went first");
    }
}
