//! `coadapt bench page`: the operator page of a run the size of the thesis's reference protocol
//! (50 designs, 6,000 episodes, a 40 x 40 landscape), served on loopback as a learner serves it,
//! fetched over HTTP/1.1 as a browser fetches it: the HTML, its stylesheet and script, the three
//! figures; milliseconds of each and of the whole page, median and 90th percentile over rounds.
//! The run directory is synthetic (random returns and designs in HalfCheetah's box), written
//! before anything is timed.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use coadapt_coadaptation::RunConfig;
use coadapt_coadaptation::page::{Page, PageSetup};
use coadapt_core::rng;
use coadapt_fleet::app::{AppError, Context};
use rand::Rng;

use crate::figure::{emit, percentile};

#[derive(Debug, Clone)]
#[cfg_attr(feature = "clap", derive(clap::Args))]
pub struct PageOptions {
    /// Designs in the synthetic run.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 50))]
    pub designs: usize,
    /// Episodes in the synthetic run.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 6000))]
    pub episodes: usize,
    /// Fetches of the whole page.
    #[cfg_attr(feature = "clap", arg(long, default_value_t = 20))]
    pub rounds: usize,
    /// Where the synthetic run directory goes (removed afterwards).
    #[cfg_attr(feature = "clap", arg(long, default_value = "target/bench-page"))]
    pub dir: PathBuf,
}

/// The synthetic run's files: designs.csv, episodes.csv, landscape.csv and landscape_designs.csv.
fn write_run(dir: &std::path::Path, designs: usize, episodes: usize, low: &[f32], high: &[f32]) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let mut r = rng(7, 0);
    let per = episodes.div_ceil(designs.max(1));
    let mut d =
        String::from("index,kind,design,episodes,best_eval_return,last_eval_return,predicted_objective,design_rollouts,method,prototype\n");
    let mut e = String::from("design,episode,global_episode,steps,return,eval_return,weights_version,seconds,actor,policy_lag\n");
    let mut l = String::from("index,kind,pc1,pc2\n");
    let mut g = 0usize;
    for i in 0..designs {
        let x: Vec<String> = low.iter().zip(high).map(|(&lo, &hi)| r.random_range(lo..hi).to_string()).collect();
        let kind = if i < 5 {
            "initial"
        } else if i % 2 == 1 {
            "exploit"
        } else {
            "explore"
        };
        let n = per.min(episodes - g);
        let best: f32 = r.random_range(0.0..400.0);
        d.push_str(&format!("{i},{kind},{},{n},{best},{best},{},0,pso-q,\n", x.join(";"), r.random_range(0.0f32..20.0)));
        l.push_str(&format!("{i},{kind},{},{}\n", r.random_range(-1.0f32..1.0), r.random_range(-1.0f32..1.0)));
        for k in 0..n {
            let eval = if k % 5 == 4 { format!("{}", r.random_range(0.0f32..400.0)) } else { String::new() };
            e.push_str(&format!(
                "{i},{k},{g},{},{},{eval},{g},{:.3},{},0\n",
                (g + 1) * 1000,
                r.random_range(0.0f32..400.0),
                g as f64 * 6.0,
                g % 4
            ));
            g += 1;
        }
    }
    let mut land = String::from("pc1,pc2,objective\n");
    for a in 0..40 {
        for b in 0..40 {
            land.push_str(&format!("{},{},{}\n", a as f32 / 20.0 - 1.0, b as f32 / 20.0 - 1.0, r.random_range(0.0f32..20.0)));
        }
    }
    std::fs::write(dir.join("designs.csv"), d)?;
    std::fs::write(dir.join("episodes.csv"), e)?;
    std::fs::write(dir.join("landscape.csv"), land)?;
    std::fs::write(dir.join("landscape_designs.csv"), l)
}

/// One GET on a fresh connection (as a browser opening the page's resources one after the
/// other); returns the bytes of the body, failing on any status but 200.
fn get(addr: SocketAddr, path: &str, cookie: &str) -> Result<(usize, String), AppError> {
    let mut s = TcpStream::connect(addr).context("connecting to the page")?;
    s.set_read_timeout(Some(Duration::from_secs(30)))?;
    write!(s, "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nCookie: {cookie}\r\n\r\n")?;
    let mut text = Vec::new();
    s.read_to_end(&mut text)?;
    let text = String::from_utf8_lossy(&text);
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    if !head.starts_with("HTTP/1.1 200") {
        return Err(AppError::failed(format!("GET {path}: {}", head.lines().next().unwrap_or(""))));
    }
    let cookie = head.lines().find_map(|l| l.strip_prefix("set-cookie: ")).and_then(|c| c.split(';').next()).unwrap_or(cookie).to_string();
    Ok((body.len(), cookie))
}

pub fn run(a: &PageOptions) -> Result<(), AppError> {
    if a.designs == 0 || a.episodes < a.designs || a.rounds == 0 {
        return Err(AppError::Config("--designs, --rounds at least 1, --episodes at least --designs".into()));
    }
    let cfg = RunConfig::default();
    let spec = cfg.make_env()?.spec().clone();
    let _ = std::fs::remove_dir_all(&a.dir);
    write_run(&a.dir, a.designs, a.episodes, &spec.design.low, &spec.design.high)
        .with_context(|| format!("writing {}", a.dir.display()))?;
    let page = Page::new(PageSetup { dir: a.dir.clone(), cfg, spec, tokens: None, tls: false, live: None, model: None });
    let serve = coadapt_design_service::ServeConfig { pages: Some(page.router()), ..Default::default() };
    let source = Arc::new(coadapt_design_service::LiveSource::new(Vec::new()));
    let server = coadapt_design_service::serve("127.0.0.1:0".parse().map_err(AppError::failed)?, serve, source)?;
    let addr = server.local_addr();
    let (_, cookie) = get(addr, "/", "")?;
    let parts = ["/", "/page.css", "/page.js", "/plot/learning_curves.svg", "/plot/best_return.svg", "/plot/landscape.svg"];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); parts.len() + 1];
    let mut bytes = vec![0usize; parts.len()];
    for _ in 0..a.rounds + 2 {
        let whole = Instant::now();
        let mut these = Vec::new();
        for (i, p) in parts.iter().enumerate() {
            let t = Instant::now();
            bytes[i] = get(addr, p, &cookie)?.0;
            these.push(t.elapsed().as_secs_f64() * 1e3);
        }
        these.push(whole.elapsed().as_secs_f64() * 1e3);
        for (t, v) in times.iter_mut().zip(these) {
            t.push(v);
        }
    }
    let config = format!("{} designs, {} episodes", a.designs, a.episodes);
    for (i, t) in times.iter_mut().enumerate() {
        // The first two rounds warm the caches (the body drawings, the file system).
        let mut t = t.split_off(2);
        t.sort_by(f64::total_cmp);
        let name = if i < parts.len() {
            format!("page GET {} ({} bytes)", parts[i], bytes[i])
        } else {
            "page load (all six, one after another)".into()
        };
        emit(&name, &config, percentile(&t, 0.5), "ms (median)");
        emit(&name, &config, percentile(&t, 0.9), "ms (p90)");
    }
    drop(server);
    let _ = std::fs::remove_dir_all(&a.dir);
    Ok(())
}
