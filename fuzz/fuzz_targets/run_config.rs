//! The run config loader: TOML text -> `RunConfig` (`toml::from_str`, as `coadapt run`
//! reads `--config`), the initial designs filled in and `run::check` against the HalfCheetah
//! spec, and `SnapshotConfig::validate`. A config that passes `check` is what the learner
//! writes to the run directory's `config.toml` and what `--resume` reads back, so it must
//! serialise, parse back and be compatible with itself.
//!
//! Each input is used twice: as TOML text (when it is UTF-8), and as instructions to mutate
//! `configs/half-cheetah-tiny.toml` key by key (set a known key to a value of its type or of
//! another, remove it, add an unknown one), which reaches `check` far more often than text
//! mutations do.

#![no_main]

use std::sync::OnceLock;

use coadapt_coadaptation::config::{RunConfig, check, resolve_initial_designs};
use coadapt_core::EnvSpec;
use libfuzzer_sys::arbitrary::{Result, Unstructured};
use libfuzzer_sys::fuzz_target;
use toml::{Table, Value};

const TINY: &str = include_str!("../../configs/half-cheetah-tiny.toml");

/// Keys that serialise to nothing by default (`Option`s), so they are named by hand.
const OPTIONAL_KEYS: &[&str] =
    &["optimizer.cmaes.population", "optimizer.sim-cmaes.population", "optimizer.cmaes-es.population", "learner.sac.target-entropy"];

/// Enum spellings and robot names, so string values hit the accepted ones often.
const WORDS: &[&str] = &[
    "pso-q",
    "cmaes-q",
    "sim-pso",
    "sim-cmaes",
    "openai-es",
    "cmaes-es",
    "random",
    "novelty",
    "lock-step",
    "async",
    "shm",
    "grpc",
    "in-process",
    "q1",
    "min-of-twin",
    "pessimistic",
    "periodic",
    "hold",
    "clamp",
    "fresh",
    "fixed",
    "best-seen",
    "generation-best",
    "half-cheetah",
    "walker",
    "hopper",
    "daisy",
    "pendulum",
    "dm-env-rpc://127.0.0.1:1",
    "",
    "0.0.0.0:0",
    "http://[::1]:1",
];

const INTS: &[i64] = &[0, 1, 2, -1, 3, 7, 255, 256, 1 << 31, (1 << 32) - 1, 1 << 32, 1 << 53, i64::MAX, i64::MIN, 1_000_000_000];
const FLOATS: &[f64] = &[
    0.0,
    -0.0,
    1.0,
    -1.0,
    0.5,
    1e-9,
    f64::MIN_POSITIVE,
    5e-324,
    1e9,
    1.8e19,
    1e300,
    f64::MAX,
    f64::INFINITY,
    f64::NEG_INFINITY,
    f64::NAN,
    3.5e38,
    f32::MAX as f64,
];

struct Fixed {
    spec: EnvSpec,
    base: Table,
    /// Every key of a run config (dotted paths to leaves) and its default value.
    keys: Vec<(Vec<String>, Value)>,
}

fn leaves(prefix: &mut Vec<String>, t: &Table, out: &mut Vec<(Vec<String>, Value)>) {
    for (k, v) in t {
        prefix.push(k.clone());
        match v {
            Value::Table(t) => leaves(prefix, t, out),
            v => out.push((prefix.clone(), v.clone())),
        }
        prefix.pop();
    }
}

fn fixed() -> &'static Fixed {
    static F: OnceLock<Fixed> = OnceLock::new();
    F.get_or_init(|| {
        let spec = coadapt_robots::make("half-cheetah").expect("half-cheetah").spec().clone();
        let base: Table = toml::from_str(TINY).expect("the tiny config parses");
        let defaults = Table::try_from(RunConfig::default()).expect("the default config serialises");
        let mut keys = Vec::new();
        leaves(&mut Vec::new(), &defaults, &mut keys);
        leaves(&mut Vec::new(), &base, &mut keys);
        for k in OPTIONAL_KEYS {
            keys.push((k.split('.').map(String::from).collect(), Value::Integer(1)));
        }
        Fixed { spec, base, keys }
    })
}

fn float(u: &mut Unstructured) -> Result<f64> {
    Ok(if u.arbitrary()? { *u.choose(FLOATS)? } else { u.arbitrary()? })
}

fn int(u: &mut Unstructured) -> Result<i64> {
    Ok(if u.arbitrary()? { *u.choose(INTS)? } else { u.arbitrary()? })
}

fn floats(u: &mut Unstructured) -> Result<Value> {
    let n = u.int_in_range(0..=8)?;
    Ok(Value::Array((0..n).map(|_| float(u).map(Value::Float)).collect::<Result<_>>()?))
}

/// A value like `like` (same type, new contents), or, sometimes, of any type.
fn value(u: &mut Unstructured, like: &Value) -> Result<Value> {
    let kind = if u.ratio(3, 4)? {
        match like {
            Value::String(_) => 0,
            Value::Integer(_) => 1,
            Value::Float(_) => 2,
            Value::Boolean(_) => 3,
            Value::Array(a) if matches!(a.first(), Some(Value::Array(_))) => 5,
            Value::Array(_) => 4,
            _ => 6,
        }
    } else {
        u.int_in_range(0..=7)?
    };
    Ok(match kind {
        0 => Value::String(if u.arbitrary()? { (*u.choose(WORDS)?).to_string() } else { u.arbitrary()? }),
        1 => Value::Integer(int(u)?),
        2 => Value::Float(float(u)?),
        3 => Value::Boolean(u.arbitrary()?),
        4 => floats(u)?,
        5 => {
            let n = u.int_in_range(0..=4)?;
            Value::Array((0..n).map(|_| floats(u)).collect::<Result<_>>()?)
        }
        6 => Value::Table(Table::new()),
        _ => Value::Array((0..u.int_in_range(0..=3)?).map(|_| int(u).map(Value::Integer)).collect::<Result<_>>()?),
    })
}

fn set(t: &mut Table, path: &[String], v: Option<Value>) {
    let (last, parents) = path.split_last().expect("keys are not empty");
    let mut t = t;
    for p in parents {
        let e = t.entry(p.clone()).or_insert_with(|| Value::Table(Table::new()));
        if !e.is_table() {
            *e = Value::Table(Table::new());
        }
        t = e.as_table_mut().expect("just made a table");
    }
    match v {
        Some(v) => {
            t.insert(last.clone(), v);
        }
        None => {
            t.remove(last);
        }
    }
}

/// The tiny config with up to 8 mutations, as TOML text.
fn mutated(u: &mut Unstructured) -> Result<String> {
    let f = fixed();
    let mut t = f.base.clone();
    for _ in 0..u.int_in_range(1..=8)? {
        let (path, like) = u.choose(&f.keys)?;
        match u.int_in_range(0..=9)? {
            0 => set(&mut t, path, None),
            1 => {
                let mut p = path.clone();
                *p.last_mut().expect("keys are not empty") = u.arbitrary()?;
                set(&mut t, &p, Some(value(u, like)?));
            }
            _ => set(&mut t, path, Some(value(u, like)?)),
        }
    }
    Ok(toml::to_string(&t).unwrap_or_default())
}

fn load(text: &str) {
    let f = fixed();
    let Ok(mut cfg) = toml::from_str::<RunConfig>(text) else { return };
    resolve_initial_designs(&mut cfg, &f.spec);
    let snapshot_ok = cfg.snapshot.validate().is_ok();
    if check(&cfg, &f.spec).is_err() || !snapshot_ok {
        return;
    }
    // The learner writes this as the run directory's config.toml; --resume reads it back.
    let written = toml::to_string(&cfg).expect("an accepted config serialises");
    let back: RunConfig = toml::from_str(&written).unwrap_or_else(|e| panic!("the written config.toml does not parse: {e}\n{written}"));
    check(&back, &f.spec).expect("the written config passes check again");
    let _ = coadapt_coadaptation::resume::check_compatible(&back, &cfg);
}

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        load(text);
    }
    if let Ok(text) = mutated(&mut Unstructured::new(data)) {
        load(&text);
    }
});
