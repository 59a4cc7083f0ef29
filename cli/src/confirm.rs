//! `coadapt confirm`: the operator's answer to a run waiting for a prototype or a reset
//! (`schedule.confirm-designs`, `schedule.reset-needs-confirmation`). The files and their
//! checks are `coadapt_learner::prototype`'s; this only parses the flags and reports.

use std::path::PathBuf;

use clap::Args;
use coadapt_learner::prototype::{self, Answer, Verdict};

/// Answer a run that waits for a prototype to be built (or the robot to be reset).
///
/// With `schedule.confirm-designs = true` a run stops at each design and prints its dimensions
/// by name; build it, then run `coadapt confirm RUN_DIR` (built as asked), `--as-built
/// V1,V2,...` (the measured dimensions of what was built, in the design's order: they replace
/// the requested ones in every later transition and in designs.csv) or `--reject` (the
/// optimiser proposes its next-best design instead). With `schedule.reset-needs-confirmation =
/// true` it stops before each episode: reset the robot, then `coadapt confirm RUN_DIR --reset`.
/// The run goes on within `schedule.confirm-poll-secs`.
#[derive(Debug, Args)]
pub struct ConfirmArgs {
    /// The waiting run's directory (the one its progress lines name).
    #[arg(value_name = "RUN_DIR")]
    pub run_dir: PathBuf,
    /// The measured dimensions of what was built, comma-separated, one per design entry, each
    /// inside the design box.
    #[arg(long, value_name = "V1,V2,...", value_delimiter = ',', allow_negative_numbers = true, num_args = 1, conflicts_with_all = ["reject", "reset"])]
    pub as_built: Option<Vec<f32>>,
    /// Do not build this design: the optimiser proposes its next-best one.
    #[arg(long, conflicts_with = "reset")]
    pub reject: bool,
    /// The robot has been reset by hand: the waiting episode may start.
    #[arg(long)]
    pub reset: bool,
}

/// `coadapt confirm`.
pub fn run(args: ConfirmArgs) -> anyhow::Result<()> {
    let dir = &args.run_dir;
    if args.reset {
        let (r, replaced) = prototype::confirm_reset(dir)?;
        println!("reset confirmed: {} may start{}", prototype::reset_name(r.mode, r.episode, r.design_index), note(replaced));
        return Ok(());
    }
    let answer = match (args.as_built, args.reject) {
        (Some(v), _) => Answer::AsBuilt(v),
        (None, true) => Answer::Reject,
        (None, false) => Answer::Confirm,
    };
    let c = prototype::confirm_prototype(dir, &answer)?;
    let p = &c.prototype;
    let what = format!("design {} [{} {}]", p.index + 1, p.kind, p.method);
    match (c.decision.decision, &c.decision.as_built) {
        (Verdict::Reject, _) => println!("{what} rejected: the optimiser proposes its next-best design{}", note(c.replaced)),
        (Verdict::Confirm, Some(v)) => println!(
            "{what} built as {} (requested {}){}",
            prototype::describe(&prototype::named_dimensions(&names(p), v)),
            prototype::describe(&p.dimensions),
            note(c.replaced)
        ),
        (Verdict::Confirm, None) => println!("{what} confirmed as built: {}{}", prototype::describe(&p.dimensions), note(c.replaced)),
    }
    Ok(())
}

fn names(p: &prototype::Prototype) -> Vec<String> {
    p.dimensions.iter().map(|d| d.0.clone()).collect()
}

fn note(replaced: bool) -> &'static str {
    if replaced { " (replacing an earlier answer the run had not read yet)" } else { "" }
}
