//! The page's HTML, rendered on the server: the frame, the prototype panel (with its forms for
//! an operator), and the live part (status, figures, bodies, designs, actors). Every text from
//! a file goes through [`esc`]; no inline script or style (the page's Content-Security-Policy
//! allows only its own `/page.js` and `/page.css`).

use std::fmt::Write as _;

use coadapt_learner::prototype::{self, Prototype, ResetMode, ResetRequest};

use super::session::Session;
use super::status::{Actor, RunFiles, Status};
use crate::plot::Figure;

/// Text for HTML (element content and quoted attribute values alike).
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

fn head(title: &str) -> String {
    format!(
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\
         <title>{}</title><link rel=\"stylesheet\" href=\"/page.css\"><script src=\"/page.js\" defer></script></head>",
        esc(title)
    )
}

/// The login form: a token in a POST body (a password field, never a URL).
pub fn login(title: &str, error: Option<&str>) -> String {
    let error = error.map(|e| format!("<p class=\"flash err\" id=\"flash\">{}</p>", esc(e))).unwrap_or_default();
    format!(
        "{}<body><header><h1>{}</h1></header><main class=\"login\">{error}\
         <form method=\"post\" action=\"/login\"><label for=\"token\">Token (client: view; operator: view and answer)</label>\
         <input type=\"password\" name=\"token\" id=\"token\" autocomplete=\"off\" required autofocus>\
         <button type=\"submit\" id=\"login\">Log in</button></form>\
         <p class=\"note\">The token is checked once and not kept: the session lives in a cookie this page alone can read.</p></main></body></html>",
        head(title),
        esc(title)
    )
}

/// What the page frame needs besides the parts.
pub struct Frame<'a> {
    pub title: &'a str,
    pub session: &'a Session,
    pub login: bool,
    pub flash: Option<(bool, String)>,
}

/// The whole page: frame, prototype panel, live part.
pub fn page(f: &Frame<'_>, prototype: &str, live: &str) -> String {
    let flash = f
        .flash
        .as_ref()
        .map(|(ok, t)| format!("<p class=\"flash {}\" id=\"flash\">{}</p>", if *ok { "ok" } else { "err" }, esc(t)))
        .unwrap_or_default();
    let who = if f.login {
        format!(
            "<form method=\"post\" action=\"/logout\" class=\"who\"><span>{}</span><input type=\"hidden\" name=\"csrf\" value=\"{}\"><button type=\"submit\">Log out</button></form>",
            esc(&format!("{}{}", f.session.role, if f.session.may_act() { "" } else { " (view only)" })),
            esc(&f.session.csrf)
        )
    } else {
        "<span class=\"who\">no tokens on this server: anyone who reaches it may answer</span>".into()
    };
    format!(
        "{}<body><header><h1>{}</h1>{who}</header><main>{flash}{prototype}<div id=\"live\">{live}</div></main></body></html>",
        head(f.title),
        esc(f.title)
    )
}

/// The key that tells the page's script the panel changed (and only then to replace it: an
/// operator typing measured dimensions keeps the fields).
fn panel_key(files: &RunFiles, may_act: bool) -> String {
    let who = if may_act { "act" } else { "view" };
    if let Some(p) = files.awaiting_prototype() {
        format!("prototype-{}-{}-{who}", p.index, p.proposal)
    } else if let Some(r) = files.awaiting_reset() {
        format!("reset-{}-{}-{:?}-{who}", r.design_index, r.episode, r.mode)
    } else {
        "none".into()
    }
}

/// The prototype panel: what the run waits for from an operator, with the forms that answer
/// it for a session that may act.
pub fn panel(files: &RunFiles, s: &Session) -> String {
    let key = panel_key(files, s.may_act());
    let body = if let Some(p) = files.awaiting_prototype() {
        prototype_panel(p, s)
    } else if let Some(r) = files.awaiting_reset() {
        reset_panel(r, s)
    } else {
        "<p class=\"idle\">The run waits for nobody: no prototype or reset to answer.</p>".into()
    };
    format!("<section id=\"prototype\" data-key=\"{}\">{body}</section>", esc(&key))
}

fn since(unix: f64) -> String {
    coadapt_log::duration(prototype::unix_now() - unix)
}

fn prototype_panel(p: &Prototype, s: &Session) -> String {
    let mut out = format!(
        "<h2>Build design {} <small>({} {}, proposal {})</small></h2><p>Waiting {} for its prototype.</p>",
        p.index + 1,
        esc(&p.kind),
        esc(&p.method),
        p.proposal,
        since(p.waiting_since_unix)
    );
    let act = s.may_act();
    if act {
        let _ = write!(
            out,
            "<form method=\"post\" action=\"/act\" id=\"prototype-form\"><input type=\"hidden\" name=\"csrf\" value=\"{}\">\
             <input type=\"hidden\" name=\"index\" value=\"{}\"><input type=\"hidden\" name=\"proposal\" value=\"{}\">",
            esc(&s.csrf),
            p.index,
            p.proposal
        );
    }
    out.push_str("<table class=\"dims\"><thead><tr><th>dimension</th><th>requested</th><th>box</th>");
    if act {
        out.push_str("<th>as built (measured)</th>");
    }
    out.push_str("</tr></thead><tbody>");
    for (i, (name, v)) in p.dimensions.iter().enumerate() {
        let (lo, hi) = (p.low.get(i).copied().unwrap_or(f32::NAN), p.high.get(i).copied().unwrap_or(f32::NAN));
        let _ = write!(out, "<tr><td>{}</td><td class=\"num\">{v:.4}</td><td class=\"num\">[{lo:.3}, {hi:.3}]</td>", esc(name));
        if act {
            let _ = write!(
                out,
                "<td><input name=\"as_built\" id=\"as-built-{i}\" value=\"{v}\" inputmode=\"decimal\" aria-label=\"{} as built\"></td>",
                esc(name)
            );
        }
        out.push_str("</tr>");
    }
    out.push_str("</tbody></table>");
    if act {
        out.push_str(
            "<div class=\"buttons\"><button type=\"submit\" name=\"action\" value=\"confirm\" id=\"confirm\">Confirm: built as requested</button>\
             <button type=\"submit\" name=\"action\" value=\"as-built\" id=\"as-built\">As built: the measured dimensions</button>",
        );
        if !p.is_fixed() {
            out.push_str("<button type=\"submit\" name=\"action\" value=\"reject\" id=\"reject\" class=\"danger\">Reject: propose the next-best design</button>");
        }
        out.push_str("</div></form>");
    } else {
        out.push_str(
            "<p class=\"note\">View only: an operator's token answers (or <code>coadapt confirm</code> on the learner's machine).</p>",
        );
    }
    out
}

fn reset_panel(r: &ResetRequest, s: &Session) -> String {
    let what = prototype::reset_name(r.mode, r.episode, r.design_index);
    let mut out = format!("<h2>Reset the robot</h2><p>Before {} (waiting {}).</p>", esc(&what), since(r.waiting_since_unix));
    if s.may_act() {
        let mode = match r.mode {
            ResetMode::Train => "train",
            ResetMode::Eval => "eval",
        };
        let _ = write!(
            out,
            "<form method=\"post\" action=\"/act\" id=\"reset-form\"><input type=\"hidden\" name=\"csrf\" value=\"{}\">\
             <input type=\"hidden\" name=\"design_index\" value=\"{}\"><input type=\"hidden\" name=\"episode\" value=\"{}\">\
             <input type=\"hidden\" name=\"mode\" value=\"{mode}\"><div class=\"buttons\">\
             <button type=\"submit\" name=\"action\" value=\"reset\" id=\"reset\">Reset done: the episode may start</button></div></form>",
            esc(&s.csrf),
            r.design_index,
            r.episode
        );
    } else {
        out.push_str("<p class=\"note\">View only: an operator's token answers.</p>");
    }
    out
}

fn num(v: Option<f32>) -> String {
    v.map_or_else(|| "&ndash;".into(), |v| format!("{v:.1}"))
}

/// The live part: status, figures, bodies, designs, actors.
pub fn live(st: &Status, files: &RunFiles, actors: &[Actor], bodies: &[(String, Option<String>)]) -> String {
    let mut out = String::from("<section id=\"status\"><h2>Status</h2><table class=\"kv\">");
    let design = match &st.design {
        Some((i, kind, method)) => format!(
            "{} of {} <small>({} {})</small>, episode {} of {}",
            i + 1,
            st.designs_total,
            esc(kind),
            esc(method),
            st.design_episodes.0,
            st.design_episodes.1
        ),
        None => format!("none yet of {}", st.designs_total),
    };
    let eta = match (st.finished, st.eta_secs) {
        (true, _) => "&ndash;".into(),
        (false, Some(s)) => coadapt_log::duration(s),
        (false, None) => "not known yet".into(),
    };
    let _ = write!(
        out,
        "<tr><th>design</th><td id=\"st-design\">{design}</td></tr><tr><th>episodes</th><td id=\"st-episodes\">{} of {}</td></tr>\
         <tr><th>run time</th><td>{}</td></tr><tr><th>ETA</th><td id=\"st-eta\">{eta}</td></tr>\
         <tr><th>waiting for</th><td id=\"st-waiting\">{}</td></tr><tr><th>source</th><td>{}</td></tr></table>",
        st.episodes_done,
        st.episodes_total,
        coadapt_log::duration(st.run_secs),
        esc(&st.waiting_for),
        if st.live { "the running learner (updates every few seconds)" } else { "the run directory's files (coadapt serve)" }
    );
    for p in &files.problems {
        let _ = write!(out, "<p class=\"flash err\">{}</p>", esc(p));
    }
    out.push_str("</section>");

    out.push_str("<section id=\"figures\"><h2>Learning</h2><div class=\"figs\">");
    for f in Figure::ALL {
        // The version makes the browser fetch a figure again when the run has moved on.
        let _ = write!(
            out,
            "<figure><img src=\"/plot/{0}.svg?v={1}-{2}\" alt=\"{0}\" width=\"450\" loading=\"lazy\"><figcaption>{3}</figcaption></figure>",
            f.name(),
            st.episodes_done,
            files.designs.len(),
            match f {
                Figure::LearningCurves => "training (line) and evaluation (dots) returns by episode",
                Figure::BestReturn => "best evaluation return by design, and the best so far",
                Figure::Landscape => "the design objective over the designs' two principal components (thesis Fig. 5.9)",
            }
        );
    }
    out.push_str("</div></section>");

    out.push_str("<section id=\"bodies\"><h2>Bodies</h2><div class=\"figs\">");
    for (caption, svg) in bodies {
        let _ = write!(
            out,
            "<figure>{}<figcaption>{}</figcaption></figure>",
            svg.as_deref().unwrap_or("<p class=\"note\">(this robot is not drawn here)</p>"),
            esc(caption)
        );
    }
    out.push_str("</div></section>");

    out.push_str(
        "<section id=\"designs\"><h2>Designs</h2><table class=\"rows\"><thead><tr><th>#</th><th>kind</th><th>method</th>\
         <th>design</th><th>episodes</th><th>best eval</th><th>predicted</th><th>prototype</th></tr></thead><tbody>",
    );
    for d in &files.designs {
        let design: Vec<String> = d.design.iter().map(|v| format!("{v:.3}")).collect();
        let _ = write!(
            out,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td class=\"design\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td></tr>",
            d.index + 1,
            esc(&d.kind),
            esc(&d.method),
            esc(&design.join(" ")),
            d.episodes,
            num(d.best_eval_return),
            d.predicted_objective.map_or_else(|| "&ndash;".into(), |v| format!("{v:.3}")),
            esc(&d.prototype)
        );
    }
    out.push_str("</tbody></table></section>");

    out.push_str(
        "<section id=\"actors\"><h2>Actors</h2><table class=\"rows\"><thead><tr><th>actor</th><th>episodes</th><th>last episode</th>\
         <th>policy lag (last / max)</th><th>health</th></tr></thead><tbody>",
    );
    for a in actors {
        let _ = write!(
            out,
            "<tr><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{} / {}</td><td class=\"{}\">{}</td></tr>",
            a.id,
            a.episodes,
            a.last_global + 1,
            a.last_lag,
            a.max_lag,
            if a.recent { "ok" } else { "warn" },
            if a.recent { "sending" } else { "quiet lately" }
        );
    }
    if actors.is_empty() {
        out.push_str("<tr><td colspan=\"5\">no episode yet</td></tr>");
    }
    out.push_str("</tbody></table></section>");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_from_files_is_escaped() {
        assert_eq!(esc("<a href=\"x\">'&'</a>"), "&lt;a href=&quot;x&quot;&gt;&#39;&amp;&#39;&lt;/a&gt;");
    }
}
