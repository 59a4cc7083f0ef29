//! The operator page: a run watched and steered from a browser, served on the design service's
//! listener beside gRPC (same TLS, same connection limits, same tokens: a client token views,
//! an operator token also answers). The learner serves it live during a run
//! (`[design-service] listen`, `coadapt run --serve ADDR`); `coadapt serve RUN_DIR` serves the
//! same page for a finished run.
//!
//! Routes: `GET /` (the page, or the login form), `GET /live` and `GET /panel` (the parts the
//! page's script fetches again every few seconds), `GET /plot/NAME.svg` (a figure drawn now from
//! the run's files; the landscape from the live critic until the run writes its own),
//! `POST /login`, `POST /logout`, `POST /act` (the prototype step: exactly what `coadapt confirm`
//! does, with its validation, and refused when the proposal shown is no longer the one
//! awaiting), `GET /page.js`, `GET /page.css`. Every response forbids caching and framing, and
//! the Content-Security-Policy lets the page load nothing from elsewhere.
//!
//! # Layout
//! - `session`: the login, the session cookie and the CSRF check, and the refusals counted.
//! - `status`: the run directory's files as the page reads them, and the status derived.
//! - `html`: the HTML; `body`: a body drawn as SVG.

mod body;
mod html;
mod session;
mod status;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use axum::extract::rejection::FormRejection;
use axum::extract::{Form, Path as UrlPath, State};
use axum::http::request::Parts;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use coadapt_design_service::ModelSource;
use coadapt_learner::coadapt::ScheduleConfig;
use coadapt_learner::prototype::{self, Answer, ResetMode};

pub use session::COOKIE;
pub use status::Live;

use crate::plot::{Figure, LandscapeDesign, LandscapePoint};

/// Points per side of the landscape the page scores from the live critic (the run's own,
/// written at its end, has `landscape-grid`).
const LIVE_LANDSCAPE_GRID: usize = 24;

/// A live landscape drawn for (weights version, designs trained).
type Drawn = ((u64, usize), Option<String>);

/// Everything the page's handlers share.
#[derive(Debug)]
pub struct Page {
    dir: PathBuf,
    title: String,
    schedule: ScheduleConfig,
    sessions: session::Sessions,
    live: Option<Arc<Live>>,
    model: Option<Arc<dyn ModelSource>>,
    bodies: body::Bodies,
    /// The live landscape, keyed by the weights version and the number of designs.
    landscape: Mutex<Option<Drawn>>,
}

/// What a page is built from.
#[derive(Debug)]
pub struct PageSetup {
    /// The run directory (the learner's, or the one `coadapt serve` reads).
    pub dir: PathBuf,
    pub cfg: crate::RunConfig,
    pub spec: coadapt_core::EnvSpec,
    /// The server's token table (`None`: no tokens asked, anyone on the listener acts).
    pub tokens: Option<Arc<coadapt_auth::TokenTable>>,
    /// The listener speaks TLS: the cookie is marked `Secure`.
    pub tls: bool,
    /// The running learner's signal (`None` for a finished run's files).
    pub live: Option<Arc<Live>>,
    /// The design critic the service serves, for the landscape before the run has its own.
    pub model: Option<Arc<dyn ModelSource>>,
}

impl Page {
    pub fn new(s: PageSetup) -> Arc<Self> {
        // Drawing a body builds the robot; one served elsewhere (hardware) is not reached for it.
        let env = if s.cfg.env.contains("://") { None } else { s.cfg.make_env().ok() };
        let name = s.dir.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| s.dir.display().to_string());
        Arc::new(Self {
            title: format!("coadapt · {} · {name}", s.spec.name),
            dir: s.dir,
            schedule: s.cfg.schedule.clone(),
            sessions: session::Sessions::new(s.tokens, s.tls),
            live: s.live,
            model: s.model,
            bodies: body::Bodies::new(env),
            landscape: Mutex::new(None),
        })
    }

    /// The page's routes, to go beside gRPC ([`coadapt_design_service::ServeConfig::pages`]).
    pub fn router(self: &Arc<Self>) -> axum::Router {
        axum::Router::new()
            .route("/", get(index))
            .route("/live", get(live))
            .route("/panel", get(panel))
            .route("/plot/{file}", get(plot))
            .route("/login", post(login))
            .route("/logout", post(logout))
            .route("/act", post(act))
            .route("/page.js", get(|| async { asset("text/javascript; charset=utf-8", include_str!("page.js")) }))
            .route("/page.css", get(|| async { asset("text/css; charset=utf-8", include_str!("page.css")) }))
            .with_state(self.clone())
    }

    fn status(&self, files: &status::RunFiles) -> status::Status {
        status::status(files, &self.schedule, self.live.as_deref())
    }

    /// The run's files, with the design in training added.
    fn files(&self) -> status::RunFiles {
        let mut files = status::RunFiles::read(&self.dir);
        files.add_current(self.live.as_ref().and_then(|l| l.current()));
        files
    }

    fn live_html(&self) -> String {
        let files = self.files();
        let st = self.status(&files);
        let actors = status::actors(&files.episodes);
        let trained: Vec<_> = files.trained().collect();
        let mut bodies = Vec::new();
        if let Some(d) = trained.last().filter(|d| !d.design.is_empty()) {
            bodies.push((format!("design {} ({}), the current one", d.index + 1, d.kind), self.bodies.svg(&d.design, 320, 180)));
        }
        let best = trained
            .iter()
            .filter(|d| d.best_eval_return.is_some())
            .max_by(|a, b| a.best_eval_return.partial_cmp(&b.best_eval_return).unwrap_or(std::cmp::Ordering::Equal));
        if let Some(d) = best {
            let r = d.best_eval_return.unwrap_or_default();
            bodies.push((
                format!("design {} ({}), the best so far: evaluation return {r:.1}", d.index + 1, d.kind),
                self.bodies.svg(&d.design, 320, 180),
            ));
        }
        html::live(&st, &files, &actors, &bodies)
    }

    /// The landscape scored now by the served critic over the designs trained so far.
    fn live_landscape(&self) -> crate::Result<Option<String>> {
        let Some(model) = self.model.as_ref().and_then(|m| m.model()) else { return Ok(None) };
        let files = status::RunFiles::read(&self.dir);
        let trained: Vec<_> = files.trained().collect();
        let key = (model.weights_version, trained.len());
        if let Some((k, svg)) = self.landscape.lock().unwrap_or_else(|e| e.into_inner()).as_ref()
            && *k == key
        {
            return Ok(svg.clone());
        }
        let dim = model.design_dim();
        let designs: Vec<f32> = trained.iter().filter(|d| d.design.len() == dim).flat_map(|d| d.design.clone()).collect();
        if designs.is_empty() {
            return Ok(None);
        }
        use coadapt_design_optimizer::landscape;
        let pca = landscape::Pca2::fit(&designs, dim).map_err(crate::AppError::library)?;
        let grid = landscape::grid(&pca, &designs, &model.bounds, LIVE_LANDSCAPE_GRID).map_err(crate::AppError::library)?;
        let n = grid.pc.len();
        let (mut mean, mut spread) = (vec![0.0; n], vec![0.0; n]);
        model.score(&grid.designs, &mut mean, &mut spread, &mut Default::default());
        let points: Vec<LandscapePoint> = grid
            .pc
            .iter()
            .zip(&mean)
            .map(|(pc, &m)| LandscapePoint { pc: [f64::from(pc[0]), f64::from(pc[1])], objective: m.is_finite().then_some(f64::from(m)) })
            .collect();
        let tried: Vec<LandscapeDesign> = trained
            .iter()
            .filter(|d| d.design.len() == dim)
            .map(|d| {
                let p = pca.project(&d.design);
                LandscapeDesign { index: d.index, kind: d.kind.clone(), pc: [f64::from(p[0]), f64::from(p[1])] }
            })
            .collect();
        let svg = crate::plot::landscape_svg(&points, &tried)?;
        *self.landscape.lock().unwrap_or_else(|e| e.into_inner()) = Some((key, svg.clone()));
        Ok(svg)
    }
}

/// Headers every page response carries.
fn hardened(mut r: Response) -> Response {
    let h = r.headers_mut();
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(header::X_CONTENT_TYPE_OPTIONS, HeaderValue::from_static("nosniff"));
    h.insert(header::REFERRER_POLICY, HeaderValue::from_static("no-referrer"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(
            "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; form-action 'self'; frame-ancestors 'none'; base-uri 'none'",
        ),
    );
    r
}

fn html(status: StatusCode, body: String) -> Response {
    hardened((status, [(header::CONTENT_TYPE, "text/html; charset=utf-8")], body).into_response())
}

fn asset(kind: &'static str, body: &'static str) -> Response {
    hardened(([(header::CONTENT_TYPE, kind)], body).into_response())
}

fn text(status: StatusCode, body: String) -> Response {
    hardened((status, [(header::CONTENT_TYPE, "text/plain; charset=utf-8")], body + "\n").into_response())
}

fn see_other(cookie: Option<String>) -> Response {
    let mut r = (StatusCode::SEE_OTHER, [(header::LOCATION, "/")]).into_response();
    if let Some(c) = cookie.and_then(|c| HeaderValue::from_str(&c).ok()) {
        r.headers_mut().insert(header::SET_COOKIE, c);
    }
    hardened(r)
}

type Shared = State<Arc<Page>>;

async fn index(State(p): Shared, parts: Parts) -> Response {
    let (id, s, cookie) = match p.sessions.get(&parts.headers) {
        Some((id, s)) => (id, s, None),
        None => match p.sessions.open_without_login() {
            Some(id) => match p.sessions.get_by_id(&id) {
                Some(s) => (id.clone(), s, Some(p.sessions.set_cookie(&id))),
                None => return text(StatusCode::INTERNAL_SERVER_ERROR, "the session was not kept".into()),
            },
            None => return html(StatusCode::OK, html::login(&p.title, None)),
        },
    };
    let flash = p.sessions.take_flash(&id);
    let mut r = off_the_runtime(move || {
        let files = status::RunFiles::read(&p.dir);
        let panel = html::panel(&files, &s);
        let frame = html::Frame { title: &p.title, session: &s, login: p.sessions.needs_login(), flash };
        html(StatusCode::OK, html::page(&frame, &panel, &p.live_html()))
    })
    .await;
    if let Some(c) = cookie.and_then(|c| HeaderValue::from_str(&c).ok()) {
        r.headers_mut().insert(header::SET_COOKIE, c);
    }
    r
}

/// A response made from the run's files, off the async runtime: the reads grow with the run
/// (episodes.csv has a row per episode), and a slow disk would stall every other request.
async fn off_the_runtime(f: impl FnOnce() -> Response + Send + 'static) -> Response {
    tokio::task::spawn_blocking(f).await.unwrap_or_else(|e| text(StatusCode::INTERNAL_SERVER_ERROR, format!("the page failed: {e}")))
}

/// The session of a request for a part of the page, or the 401 to answer (the page's script
/// then reloads the page, which shows the login form).
fn viewer(p: &Page, parts: &Parts) -> Result<session::Session, Box<Response>> {
    p.sessions.get(&parts.headers).map(|(_, s)| s).ok_or_else(|| {
        let peer = coadapt_design_service::peer_ip(&parts.extensions);
        let r = session::Refusal::NoSession;
        r.record(peer);
        Box::new(text(StatusCode::UNAUTHORIZED, r.message()))
    })
}

async fn live(State(p): Shared, parts: Parts) -> Response {
    match viewer(&p, &parts) {
        Ok(_) => off_the_runtime(move || html(StatusCode::OK, p.live_html())).await,
        Err(r) => *r,
    }
}

async fn panel(State(p): Shared, parts: Parts) -> Response {
    match viewer(&p, &parts) {
        Ok(s) => off_the_runtime(move || html(StatusCode::OK, html::panel(&status::RunFiles::read(&p.dir), &s))).await,
        Err(r) => *r,
    }
}

async fn plot(State(p): Shared, UrlPath(file): UrlPath<String>, parts: Parts) -> Response {
    if let Err(r) = viewer(&p, &parts) {
        return *r;
    }
    let Some(fig) = Figure::ALL.into_iter().find(|f| file == format!("{}.svg", f.name())) else {
        return text(StatusCode::NOT_FOUND, format!("no figure {file:?} (learning_curves.svg, best_return.svg, landscape.svg)"));
    };
    // Drawing reads files and, for the live landscape, scores the critic: off the runtime.
    let page = p.clone();
    let drawn = tokio::task::spawn_blocking(move || match crate::plot::figure_svg(&page.dir, fig)? {
        None if fig == Figure::Landscape => page.live_landscape(),
        drawn => Ok(drawn),
    })
    .await;
    match drawn {
        Ok(Ok(Some(svg))) => hardened(([(header::CONTENT_TYPE, "image/svg+xml")], svg).into_response()),
        Ok(Ok(None)) => hardened(([(header::CONTENT_TYPE, "image/svg+xml")], placeholder(fig)).into_response()),
        Ok(Err(e)) => text(StatusCode::INTERNAL_SERVER_ERROR, format!("{file}: {e:#}")),
        Err(e) => text(StatusCode::INTERNAL_SERVER_ERROR, format!("{file}: {e}")),
    }
}

/// A figure without data yet.
fn placeholder(fig: Figure) -> String {
    format!(
        r##"<svg xmlns="http://www.w3.org/2000/svg" width="450" height="120"><text x="12" y="60" font-family="sans-serif" font-size="14" fill="#666">{}: no data yet</text></svg>"##,
        fig.name()
    )
}

#[derive(serde::Deserialize)]
struct LoginForm {
    token: String,
}

async fn login(State(p): Shared, parts: Parts, form: Result<Form<LoginForm>, FormRejection>) -> Response {
    let peer = coadapt_design_service::peer_ip(&parts.extensions);
    let Ok(Form(f)) = form else {
        return html(StatusCode::BAD_REQUEST, html::login(&p.title, Some("the form has no token field")));
    };
    match p.sessions.login(&f.token) {
        Ok(id) => see_other(Some(p.sessions.set_cookie(&id))),
        Err(r) => {
            r.record(peer);
            html(StatusCode::UNAUTHORIZED, html::login(&p.title, Some(&r.message())))
        }
    }
}

async fn logout(State(p): Shared, parts: Parts, form: Result<Form<Vec<(String, String)>>, FormRejection>) -> Response {
    let csrf = form.as_ref().ok().and_then(|Form(f)| field(f, "csrf"));
    match p.sessions.get(&parts.headers) {
        Some((id, s)) if csrf.is_some_and(|c| c == s.csrf) => {
            p.sessions.close(&id);
            see_other(Some(p.sessions.clear_cookie()))
        }
        _ => see_other(None),
    }
}

fn field<'a>(f: &'a [(String, String)], name: &str) -> Option<&'a str> {
    f.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
}

/// A form field that must be a whole number; the error names it.
fn index_field(f: &[(String, String)], name: &str) -> Result<usize, String> {
    let v = field(f, name).ok_or_else(|| format!("the form has no {name} field"))?;
    v.trim().parse().map_err(|_| format!("{name}: {v:?} is not a whole number"))
}

/// What the form asks, checked: the answer and the proposal (or reset) it was given to.
enum Asked {
    Prototype { seen: (usize, usize), answer: Answer },
    Reset { seen: (usize, usize, ResetMode) },
}

fn parse_act(f: &[(String, String)]) -> Result<Asked, String> {
    let action = field(f, "action").ok_or("the form has no action (confirm, as-built, reject or reset)")?;
    if action == "reset" {
        let mode = match field(f, "mode") {
            Some("train") => ResetMode::Train,
            Some("eval") => ResetMode::Eval,
            other => return Err(format!("mode: {other:?} is not train or eval")),
        };
        return Ok(Asked::Reset { seen: (index_field(f, "design_index")?, index_field(f, "episode")?, mode) });
    }
    let seen = (index_field(f, "index")?, index_field(f, "proposal")?);
    let answer = match action {
        "confirm" => Answer::Confirm,
        "reject" => Answer::Reject,
        "as-built" => {
            let values = f
                .iter()
                .filter(|(k, _)| k == "as_built")
                .enumerate()
                .map(|(i, (_, v))| v.trim().parse::<f32>().map_err(|_| format!("as built, entry {}: {v:?} is not a number", i + 1)));
            Answer::AsBuilt(values.collect::<Result<_, _>>()?)
        }
        other => return Err(format!("action: {other:?} is not confirm, as-built, reject or reset")),
    };
    Ok(Asked::Prototype { seen, answer })
}

async fn act(State(p): Shared, parts: Parts, form: Result<Form<Vec<(String, String)>>, FormRejection>) -> Response {
    let peer = coadapt_design_service::peer_ip(&parts.extensions);
    let fields = form.map(|Form(f)| f).unwrap_or_default();
    let id = match p.sessions.check_act(&parts.headers, field(&fields, "csrf")) {
        Ok((id, _)) => id,
        Err(r) => {
            r.record(peer);
            return text(StatusCode::FORBIDDEN, format!("refused: {}", r.message()));
        }
    };
    let said = match parse_act(&fields) {
        Err(e) => Err(e),
        Ok(Asked::Prototype { seen, answer }) => {
            prototype::confirm_prototype_of(&p.dir, Some(seen), &answer).map_err(|e| e.to_string()).map(|c| {
                let what = format!("design {} (proposal {})", c.prototype.index + 1, c.prototype.proposal);
                match (&answer, &c.decision.as_built) {
                    (Answer::Reject, _) => format!("{what} rejected: the optimiser proposes its next-best design"),
                    (_, Some(v)) => format!(
                        "{what} built as {}",
                        prototype::describe(&prototype::named_dimensions(
                            &c.prototype.dimensions.iter().map(|d| d.0.clone()).collect::<Vec<_>>(),
                            v
                        ))
                    ),
                    _ => format!("{what} confirmed as built: {}", prototype::describe(&c.prototype.dimensions)),
                }
            })
        }
        Ok(Asked::Reset { seen }) => prototype::confirm_reset_of(&p.dir, Some(seen))
            .map(|(r, _)| format!("reset confirmed: {} may start", prototype::reset_name(r.mode, r.episode, r.design_index)))
            .map_err(|e| e.to_string()),
    };
    match said {
        Ok(t) => {
            coadapt_log::logln!("operator page: {t}");
            p.sessions.flash(&id, true, format!("{t}. The run goes on within schedule.confirm-poll-secs."));
        }
        Err(e) => p.sessions.flash(&id, false, format!("not answered: {e}")),
    }
    see_other(None)
}
