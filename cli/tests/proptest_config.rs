//! Property tests of the run config loader: `configs/half-cheetah-tiny.toml` with arbitrary
//! keys set to arbitrary values, removed, or misspelt either loads (`toml::from_str`, the
//! initial designs filled in, `run::check` against HalfCheetah, `SnapshotConfig::validate`) or
//! is refused with an error that names the key; it never panics.

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::LazyLock;

use coadapt_coadaptation::config::{RunConfig, check, resolve_initial_designs};
use coadapt_core::EnvSpec;
use proptest::prelude::*;
use toml::{Table, Value};

const TINY: &str = include_str!("../../configs/half-cheetah-tiny.toml");

/// Keys that serialise to nothing by default (`Option`s).
const OPTIONAL_KEYS: &[&str] =
    &["optimizer.cmaes.population", "optimizer.sim-cmaes.population", "optimizer.cmaes-es.population", "learner.sac.target-entropy"];

/// Enum spellings and robot names, so string values are often accepted ones.
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
    "",
];

struct Fixed {
    spec: EnvSpec,
    base: Table,
    /// Every key of a run config (dotted path to a leaf) and its value in the default config.
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

static FIXED: LazyLock<Fixed> = LazyLock::new(|| {
    let spec = coadapt_robots::make("half-cheetah").unwrap().spec().clone();
    let base: Table = toml::from_str(TINY).unwrap();
    let mut keys = Vec::new();
    leaves(&mut Vec::new(), &Table::try_from(RunConfig::default()).unwrap(), &mut keys);
    leaves(&mut Vec::new(), &base, &mut keys);
    keys.sort_by(|a, b| a.0.cmp(&b.0));
    keys.dedup_by(|a, b| a.0 == b.0);
    for k in OPTIONAL_KEYS {
        keys.push((k.split('.').map(String::from).collect(), Value::Integer(1)));
    }
    Fixed { spec, base, keys }
});

fn float() -> impl Strategy<Value = f64> {
    prop_oneof![
        2 => -10.0f64..10.0,
        1 => prop::sample::select(vec![0.0, -0.0, 1e-9, 5e-324, 1e9, 1.8e19, 1e300, f64::MAX, f64::INFINITY, f64::NEG_INFINITY, f64::NAN]),
        1 => any::<f64>(),
    ]
}

fn int() -> impl Strategy<Value = i64> {
    prop_oneof![
        2 => -3..300i64,
        1 => prop::sample::select(vec![i64::MAX, i64::MIN, 1 << 32, (1 << 32) - 1, 1 << 53, 1_000_000_000]),
        1 => any::<i64>(),
    ]
}

fn floats() -> impl Strategy<Value = Value> {
    prop::collection::vec(float().prop_map(Value::Float), 0..8).prop_map(Value::Array)
}

fn any_value() -> BoxedStrategy<Value> {
    prop_oneof![
        int().prop_map(Value::Integer),
        float().prop_map(Value::Float),
        any::<bool>().prop_map(Value::Boolean),
        prop::sample::select(WORDS).prop_map(|s| Value::String(s.into())),
        "\\PC{0,12}".prop_map(Value::String),
        floats(),
        prop::collection::vec(floats(), 0..4).prop_map(Value::Array),
        Just(Value::Table(Table::new())),
    ]
    .boxed()
}

/// A value of the same type as `like`, with new contents.
fn value_like(like: &Value) -> BoxedStrategy<Value> {
    match like {
        Value::String(_) => {
            prop_oneof![prop::sample::select(WORDS).prop_map(|s| Value::String(s.into())), "\\PC{0,12}".prop_map(Value::String)].boxed()
        }
        Value::Integer(_) => int().prop_map(Value::Integer).boxed(),
        Value::Float(_) => float().prop_map(Value::Float).boxed(),
        Value::Boolean(_) => any::<bool>().prop_map(Value::Boolean).boxed(),
        Value::Array(a) if matches!(a.first(), Some(Value::Array(_))) => {
            prop::collection::vec(floats(), 0..4).prop_map(Value::Array).boxed()
        }
        Value::Array(_) => {
            prop_oneof![floats(), prop::collection::vec(int().prop_map(Value::Integer), 0..4).prop_map(Value::Array)].boxed()
        }
        _ => any_value(),
    }
}

/// One change to the config.
#[derive(Clone, Debug)]
enum Edit {
    Set(Vec<String>, Value),
    Remove(Vec<String>),
    /// A key the config does not have, beside a real one.
    Unknown(Vec<String>, Value),
}

impl Edit {
    /// The key a refusal must name.
    fn key(&self) -> &str {
        match self {
            Edit::Set(p, _) | Edit::Remove(p) | Edit::Unknown(p, _) => p.last().unwrap(),
        }
    }
}

fn edit() -> impl Strategy<Value = Edit> {
    prop::sample::select((0..FIXED.keys.len()).collect::<Vec<_>>()).prop_flat_map(|i| {
        let (path, like) = FIXED.keys[i].clone();
        let p = path.clone();
        let unknown = (any_value(), "[a-z][a-z-]{0,10}").prop_map(move |(v, k)| {
            let mut p = p.clone();
            *p.last_mut().unwrap() = format!("{k}-x");
            Edit::Unknown(p, v)
        });
        prop_oneof![
            6 => value_like(&like).prop_map({
                let path = path.clone();
                move |v| Edit::Set(path.clone(), v)
            }),
            2 => any_value().prop_map({
                let path = path.clone();
                move |v| Edit::Set(path.clone(), v)
            }),
            1 => Just(Edit::Remove(path)),
            1 => unknown,
        ]
    })
}

fn apply(t: &mut Table, e: &Edit) {
    let (path, v) = match e {
        Edit::Set(p, v) | Edit::Unknown(p, v) => (p, Some(v.clone())),
        Edit::Remove(p) => (p, None),
    };
    let (last, parents) = path.split_last().unwrap();
    let mut t = t;
    for p in parents {
        let entry = t.entry(p.clone()).or_insert_with(|| Value::Table(Table::new()));
        if !entry.is_table() {
            *entry = Value::Table(Table::new());
        }
        t = entry.as_table_mut().unwrap();
    }
    match v {
        Some(v) => t.insert(last.clone(), v),
        None => t.remove(last),
    };
}

/// What `coadapt run` does with a config file before it starts anything.
fn load(text: &str) -> anyhow::Result<RunConfig> {
    let mut cfg: RunConfig = toml::from_str(text)?;
    resolve_initial_designs(&mut cfg, &FIXED.spec);
    check(&cfg, &FIXED.spec)?;
    cfg.snapshot.validate().map_err(anyhow::Error::msg)?;
    Ok(cfg)
}

fn edited(edits: &[Edit]) -> String {
    let mut t = FIXED.base.clone();
    for e in edits {
        apply(&mut t, e);
    }
    toml::to_string(&t).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    /// One edit: the config loads, or the error names the edited key.
    #[test]
    fn proptest_config_edit_loads_or_names_the_key(e in edit()) {
        let text = edited(std::slice::from_ref(&e));
        match load(&text) {
            Ok(cfg) => {
                // What the learner writes as the run's config.toml reads back the same way.
                let written = toml::to_string(&cfg).unwrap();
                prop_assert!(load(&written).is_ok(), "the written config does not load:\n{}", written);
            }
            Err(err) => {
                let msg = format!("{err:#}");
                prop_assert!(msg.contains(e.key()), "the error does not name `{}`: {}\n{}", e.key(), msg, text);
            }
        }
    }

    /// Several edits at once: never a panic.
    #[test]
    fn proptest_config_edits_never_panic(edits in prop::collection::vec(edit(), 1..6)) {
        let _ = load(&edited(&edits));
    }

    /// Raw text edits of the file: a byte range replaced by arbitrary text.
    #[test]
    fn proptest_config_text_edits_never_panic(at in any::<prop::sample::Index>(), cut in 0..16usize, insert in "\\PC{0,16}") {
        let mut text = TINY.to_string();
        let mut i = at.index(text.len());
        while !text.is_char_boundary(i) {
            i -= 1;
        }
        let mut j = (i + cut).min(text.len());
        while !text.is_char_boundary(j) {
            j -= 1;
        }
        text.replace_range(i..j, &insert);
        let _ = load(&text);
    }
}

#[test]
fn the_tiny_config_loads() {
    load(TINY).unwrap();
}
