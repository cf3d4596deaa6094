//! `texsyn-bench paper`: the paper's two configurations end to end (Stahlhut
//! Table 1 and §10.2, ARCHITECTURE §6), with times per level and in total.

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use texsyn::block::Silent;
use texsyn::search::LocalSearch;
use texsyn::{synthesize, Output};
use texsyn_engine::Engine;

use crate::cases::{Case, RunArgs, CASES};

#[derive(ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum CaseName {
    /// 192×192 from 64×64 (9×9 neighbourhood, 3×3 blocks, 3 levels).
    A,
    /// 1000×1000 from 500×500 (11×11 neighbourhood, 5×5 blocks, 4 levels).
    B,
}

#[derive(Args, Debug)]
pub struct PaperArgs {
    /// Only this configuration (default: both).
    #[arg(long, value_enum)]
    pub case: Option<CaseName>,
    #[command(flatten)]
    pub run: RunArgs,
}

impl CaseName {
    /// Whether `case` is this configuration.
    fn is(self, case: &Case) -> bool {
        case.name
            == match self {
                Self::A => "a",
                Self::B => "b",
            }
    }
}

pub fn run(a: &PaperArgs) -> Result<()> {
    let dir = a.run.textures.dir()?;
    let pool = a.run.pool()?;
    println!(
        "kernel {} | {} thread(s) | batch K = {}",
        Engine::default().kernel().name(),
        pool.current_num_threads(),
        a.run.batch
    );
    let which = CASES.iter().filter(|c| a.case.is_none_or(|n| n.is(c)));
    for case in which {
        let sample = texsyn::imaging::load_color(&dir.join(case.file))?;
        let (cfg, mode) = case.run(a.run.batch);
        let reps = a.run.reps.max(1);
        let mut best: Option<Output> = None;
        for _ in 0..reps {
            let mut backend = LocalSearch::new(Engine::default());
            let out = pool.install(|| synthesize(&sample, &mode, &cfg, &mut backend, &Silent))?;
            if best
                .as_ref()
                .is_none_or(|b| out.report.synthesis_seconds < b.report.synthesis_seconds)
            {
                best = Some(out);
            }
        }
        let out = best.context("no run")?;
        let r = &out.report;
        println!(
            "{}, exhaustive, best of {reps}:",
            case.describe(&sample, r.levels)
        );
        for l in &r.per_level {
            println!(
                "    level {} canvas {:>4}x{:<4} refs {:>7} queries {:>6}  build {:>7.4} s  search {:>8.4} s  level {:>8.4} s  pruned {}",
                l.level, l.canvas[0], l.canvas[1], l.reference_vectors, l.queries, l.build_seconds, l.search_seconds, l.total_seconds,
                crate::prune_text(l.prune)
            );
        }
        println!("    total synthesis time {:.4} s", r.synthesis_seconds);
        a.run
            .save(&format!("bench_{}.png", case.name), &out.image)?;
    }
    Ok(())
}
