//! `texsyn-bench morph`: the synthesis on coordinates (ARCHITECTURE §10).
//! The 512² morph of two exemplars per neighbourhood (Manke–Wünsche §6 times
//! it on one 2.13 GHz core: under 12 s reduced, 17 s half-reduced), then
//! `--method parallel` against the block method on the bundled textures,
//! scored by `texsyn compare`'s measures.

use std::time::Instant;

use anyhow::Result;
use clap::Args;
use texsyn::block::Silent;
use texsyn::compare;
use texsyn::imaging::{self, ColorImage};
use texsyn::parallel::synth::{self, Neighbourhood, ParallelSettings};
use texsyn::parallel::weights;
use texsyn::search::{LocalSearch, Plan, PlannedSearch};
use texsyn::{synthesize, Config, Mode, SynthMethod};
use texsyn_engine::Engine;

use crate::cases::RunArgs;

#[derive(Args, Debug)]
pub struct MorphArgs {
    #[command(flatten)]
    pub run: RunArgs,
    /// The two exemplars of the morph (in --textures).
    #[arg(
        long,
        default_value = "pink_marble_color_128.png,leaves_green_color_161.png"
    )]
    pub pair: String,
    /// Side of the morph.
    #[arg(long, default_value_t = 512)]
    pub size: usize,
    /// Textures (in --textures) for the comparison with the block method; none
    /// skips it.
    #[arg(
        long,
        default_value = "brick_color_96.png,pink_marble_color_128.png,cracked_color_144.png,leaves_green_color_161.png,mossy_rock_color_128.png"
    )]
    pub compare: String,
    /// Side of the outputs compared.
    #[arg(long, default_value_t = 256)]
    pub compare_size: usize,
}

fn settings(neighbourhood: Neighbourhood) -> ParallelSettings {
    ParallelSettings::defaults_for(neighbourhood, true)
}

pub fn run(a: &MorphArgs) -> Result<()> {
    let dir = a.run.textures.dir()?;
    let pool = a.run.pool()?;
    let names: Vec<&str> = a.pair.split(',').map(str::trim).collect();
    let exemplars = names
        .iter()
        .map(|n| imaging::load_color(&dir.join(n)))
        .collect::<Result<Vec<_>>>()?;
    let refs: Vec<&ColorImage> = exemplars.iter().collect();
    let n = a.size;
    let maps = weights::ramp(refs.len(), weights::Axis::X, n, n);
    println!(
        "morph {n}×{n} of {} | {} thread(s) | best of {}",
        names.join(" + "),
        pool.current_num_threads(),
        a.run.reps.max(1)
    );
    for (name, nb) in [
        ("reduced", Neighbourhood::Reduced),
        ("half", Neighbourhood::Half),
        ("5x5", Neighbourhood::Full(5)),
        ("7x7", Neighbourhood::Full(7)),
    ] {
        let mut best = f64::INFINITY;
        for _ in 0..a.run.reps.max(1) {
            let t = Instant::now();
            let mut backend = LocalSearch::new(Engine::default());
            let out = pool.install(|| {
                synth::morph(
                    &refs,
                    &maps,
                    n,
                    n,
                    &settings(nb),
                    &mut backend,
                    &texsyn::progress::Silent,
                )
            })?;
            best = best.min(t.elapsed().as_secs_f64());
            a.run.save(&format!("morph_{name}.png"), &out.image)?;
        }
        println!("  {name:8} {best:.3} s");
    }
    if a.compare.trim().is_empty() {
        return Ok(());
    }
    let m = a.compare_size;
    println!(
        "\n{m}×{m}: sample against output (S_F higher is better; S_L, colour, patch fidelity lower)"
    );
    println!("  texture                     method          S_F    S_L    colour  patch   time");
    for name in a.compare.split(',').map(str::trim) {
        let sample = imaging::load_color(&dir.join(name))?;
        let t = Instant::now();
        let mut backend = PlannedSearch::new(Plan::Exact, LocalSearch::new(Engine::default()));
        let mode = Mode::Synth {
            width: m,
            height: m,
            method: SynthMethod::Grow,
        };
        let block =
            pool.install(|| synthesize(&sample, &mode, &Config::default(), &mut backend, &Silent))?;
        let block_t = t.elapsed().as_secs_f64();
        let mut outs = vec![("block", block.image, block_t)];
        for (label, nb) in [
            ("parallel", Neighbourhood::Reduced),
            ("parallel half", Neighbourhood::Half),
        ] {
            let t = Instant::now();
            let mut backend = LocalSearch::new(Engine::default());
            let out = pool.install(|| {
                synth::synthesize(
                    &sample,
                    m,
                    m,
                    &settings(nb),
                    &mut backend,
                    &texsyn::progress::Silent,
                )
            })?;
            outs.push((label, out.image, t.elapsed().as_secs_f64()));
        }
        for (label, img, secs) in &outs {
            let c = compare::compare(&sample, img)?;
            println!(
                "  {name:27} {label:14} {:.3}  {:.3}  {:.4}  {:6.2}  {secs:.2} s",
                c.s_f, c.s_l, c.colour, c.patch_fidelity
            );
            let stem = name.trim_end_matches(".png");
            a.run
                .save(&format!("{stem}_{}.png", label.replace(' ', "_")), img)?;
        }
    }
    Ok(())
}
