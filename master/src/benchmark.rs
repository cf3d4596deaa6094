//! `texsyn bench`: the paper's two configurations end to end (Stahlhut Table 1
//! and §10.2, DESIGN §5), with times per level and in total.

use std::path::PathBuf;

use anyhow::{Context, Result};
use texsyn_worker::Engine;

use crate::cli::{existing_dir, BenchArgs};
use crate::imaging;
use crate::search::LocalSearch;
use crate::synth::{self, Config, Mode, Silent, SynthMethod};

struct Case {
    name: &'static str,
    file: &'static str,
    size: usize,
    block: usize,
    neighbourhood: usize,
    levels: usize,
}

const CASES: [Case; 2] = [
    Case {
        name: "a",
        file: "brick_gray_64.png",
        size: 192,
        block: 3,
        neighbourhood: 9,
        levels: 3,
    },
    Case {
        name: "b",
        file: "gravel_gray_500.png",
        size: 1000,
        block: 5,
        neighbourhood: 11,
        levels: 4,
    },
];

fn textures_dir(arg: &Option<PathBuf>) -> PathBuf {
    arg.clone().unwrap_or_else(|| {
        let here = PathBuf::from("../shared/textures");
        if here.is_dir() {
            here
        } else {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/textures")
        }
    })
}

pub(crate) fn run(a: &BenchArgs) -> Result<()> {
    let dir = textures_dir(&a.textures);
    existing_dir(&dir).context("texture directory for the bench (give --textures DIR)")?;
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = a.threads {
            b = b.num_threads(t);
        }
        b.build()?
    };
    let which: Vec<&Case> = CASES
        .iter()
        .filter(|c| a.which == "paper" || a.which == c.name)
        .collect();
    anyhow::ensure!(
        !which.is_empty(),
        "unknown bench '{}': use a, b or paper",
        a.which
    );
    println!(
        "kernel {} | {} thread(s) | batch K = {}",
        Engine::default().kernel().name(),
        pool.current_num_threads(),
        a.batch
    );
    for case in which {
        let sample = imaging::load_color(&dir.join(case.file))?;
        let cfg = Config {
            block: case.block,
            neighbourhood: case.neighbourhood,
            levels: case.levels,
            batch: a.batch,
            ..Config::default()
        };
        let mode = Mode::Synth {
            width: case.size,
            height: case.size,
            method: SynthMethod::Grow,
        };
        let reps = if case.name == "a" { a.reps.max(1) } else { 1 };
        let mut best: Option<synth::Output> = None;
        for _ in 0..reps {
            let mut backend = LocalSearch::new(Engine::default());
            let out =
                pool.install(|| synth::synthesize(&sample, &mode, &cfg, &mut backend, &Silent))?;
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
            "({}) {}x{} from {} ({}x{}), {}x{} neighbourhood, {}x{} blocks, {} levels, exhaustive, best of {reps}:",
            case.name,
            case.size,
            case.size,
            case.file,
            sample.width,
            sample.height,
            case.neighbourhood,
            case.neighbourhood,
            case.block,
            case.block,
            r.levels
        );
        for l in &r.per_level {
            println!(
                "    level {} canvas {:>4}x{:<4} refs {:>7} queries {:>6}  build {:>7.4} s  search {:>8.4} s  level {:>8.4} s",
                l.level, l.canvas[0], l.canvas[1], l.reference_vectors, l.queries, l.build_seconds, l.search_seconds, l.total_seconds
            );
        }
        println!("    total synthesis time {:.4} s", r.synthesis_seconds);
        if let Some(o) = &a.out {
            std::fs::create_dir_all(o)?;
            imaging::save_color(&o.join(format!("bench_{}.png", case.name)), &out.image)?;
        }
    }
    Ok(())
}
