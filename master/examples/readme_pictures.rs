//! Makes the before/after pictures of the README from the bundled textures:
//! `cargo run --release --example readme_pictures [NAME...]` writes `docs/*.png`.

use std::path::Path;

use anyhow::Result;
use texsyn::block::growth_neighbourhood;
use texsyn::block::Silent;
use texsyn::imaging::{self, ColorImage};
use texsyn::parallel::{
    self, solid,
    synth::{Neighbourhood, ParallelSettings},
    weights,
};
use texsyn::search::{LocalSearch, Plan, PlannedSearch};
use texsyn::{synthesize, Config, Mode, Position, Stitch, SynthMethod};
use texsyn_engine::Engine;

fn run(sample: &ColorImage, mode: Mode, cfg: Config) -> Result<ColorImage> {
    let mut backend = PlannedSearch::new(Plan::Exact, LocalSearch::new(Engine::default()));
    let out = synthesize(sample, &mode, &cfg, &mut backend, &Silent)?;
    println!(
        "  {} in {:.2} s",
        out.report.mode, out.report.synthesis_seconds
    );
    Ok(out.image)
}

/// `texsyn synth`'s growth to `side`² with its defaults: path stitching,
/// N = 13 where the coarsest level holds it.
fn grown(sample: &ColorImage, side: usize) -> (Mode, Config) {
    let mode = Mode::Synth {
        width: side,
        height: side,
        method: SynthMethod::Grow,
    };
    let cfg = Config {
        stitch: Stitch::Path,
        neighbourhood: growth_neighbourhood([sample.width, sample.height], 0),
        ..Config::default()
    };
    (mode, cfg)
}

/// Pictures side by side on a white background, 8 px apart, top-aligned.
fn side_by_side(images: &[&ColorImage]) -> ColorImage {
    let gap = 8;
    let w = images.iter().map(|i| i.width).sum::<usize>() + gap * (images.len() - 1);
    let h = images.iter().map(|i| i.height).max().unwrap_or(0);
    let mut out = ColorImage::from_vec(w, h, vec![255; w * h * 3]);
    let mut x0 = 0;
    for img in images {
        for y in 0..img.height {
            for x in 0..img.width {
                out.set(x0 + x, y, img.get(x, y));
            }
        }
        x0 += img.width + gap;
    }
    out
}

fn tiled(img: &ColorImage, nx: usize, ny: usize) -> ColorImage {
    let (w, h) = (img.width * nx, img.height * ny);
    let mut out = ColorImage::new(w, h);
    for y in 0..h {
        for x in 0..w {
            out.set(x, y, img.get(x % img.width, y % img.height));
        }
    }
    out
}

fn main() -> Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let tex = root.join("assets/textures");
    let docs = root.join("docs");
    std::fs::create_dir_all(&docs)?;
    // Names on the command line (fill, extend, synth, lattice, tiles, omega,
    // morph, replay, solid) make only those pictures.
    let only: Vec<String> = std::env::args().skip(1).collect();
    let want = |name: &str| only.is_empty() || only.iter().any(|o| o == name);

    if want("fill") {
        println!("fill: coffee beans with a red scribble");
        let photo = imaging::load_color(&tex.join("coffee_scribble_color_400.png"))?;
        let holes = imaging::load_mask(
            &tex.join("coffee_scribble_mask_400.png"),
            photo.width,
            photo.height,
        )?;
        let filled = run(
            &photo,
            Mode::Fill {
                holes,
                source: None,
            },
            Config::default(),
        )?;
        imaging::save_color(&docs.join("fill.png"), &side_by_side(&[&photo, &filled]))?;
    }
    if want("extend") {
        println!("extend --tileable: brick, shown tiled 2×2");
        let brick = imaging::load_color(&tex.join("brick_color_96.png"))?;
        let cfg = Config {
            tileable: true,
            ..Config::default()
        };
        let extended = run(
            &brick,
            Mode::Extend {
                width: 192,
                height: 192,
                position: Position::Center,
            },
            cfg,
        )?;
        imaging::save_color(
            &docs.join("extend_tileable.png"),
            &side_by_side(&[&brick, &tiled(&extended, 2, 2)]),
        )?;
    }
    if want("synth") {
        println!("synth: leaves and pink marble");
        let mut row = Vec::new();
        for name in ["leaves_green_color_161.png", "pink_marble_color_128.png"] {
            let sample = imaging::load_color(&tex.join(name))?;
            let (mode, cfg) = grown(&sample, 320);
            let out = run(&sample, mode, cfg)?;
            row.push(sample);
            row.push(out);
        }
        let refs: Vec<&ColorImage> = row.iter().collect();
        imaging::save_color(&docs.join("synth.png"), &side_by_side(&refs))?;
    }
    if want("lattice") {
        println!("synth --lattice: coloured tiles, without and with the lattice rule");
        let sample = imaging::load_color(&tex.join("tiles_color_256.png"))?;
        let (mode, free) = grown(&sample, 384);
        let on_grid = Config {
            lattice: Some(texsyn::block::Lattice {
                period: [32.0, 32.0],
            }),
            ..free.clone()
        };
        let plain = run(&sample, mode.clone(), free)?;
        let kept = run(&sample, mode, on_grid)?;
        imaging::save_color(
            &docs.join("lattice.png"),
            &side_by_side(&[&sample, &plain, &kept]),
        )?;
    }
    if want("tiles") {
        println!("tiles: coffee beans, one tile against eight (the paper's Fig. 10 index)");
        let beans = imaging::load_color(&tex.join("coffee_beans_color_512.png"))?;
        let settings = texsyn::tiles::SomolConfig {
            tile_size: Some(128),
            ..Default::default()
        }
        .settings(&beans, None)?;
        let set = texsyn::tiles::make_tile_set(&beans, None, &settings, &texsyn::progress::Silent)?;
        let one = texsyn::tiles::assemble(&set.tiles, &vec![vec![1; 4]; 4])?;
        let index = [[7, 6, 1, 5], [3, 7, 5, 8], [5, 1, 6, 2], [4, 3, 2, 3]].map(Vec::from);
        let eight = texsyn::tiles::assemble(&set.tiles, &index)?;
        imaging::save_color(&docs.join("tiles.png"), &side_by_side(&[&one, &eight]))?;
    }
    if want("omega") {
        println!("ω-tiles: pink marble, 38 tiles of 80² laid 6×4 by the scan-line tiler");
        let marble = imaging::load_color(&tex.join("pink_marble_color_128.png"))?;
        let set = texsyn::tiles::omega::OmegaSet::of_size(38)?;
        let mut evaluator = texsyn::tiles::ais::Evaluator::new(&set, &marble, 80)?;
        let settings = texsyn::tiles::ais::AisSettings::default();
        let found = texsyn::tiles::ais::search(
            &mut evaluator,
            &marble,
            &settings,
            &texsyn::progress::Silent,
        )?;
        let (omega_tiles, _) =
            texsyn::tiles::ais::build_tiles(&mut evaluator, &marble, &found.genes)?;
        let index: Vec<Vec<usize>> = texsyn::tiles::omega::scan_line_tiling(&set, 6, 4, 2)?
            .into_iter()
            .map(|r| r.into_iter().map(|k| k + 1).collect())
            .collect();
        let wall = texsyn::tiles::assemble(&omega_tiles, &index)?;
        imaging::save_color(&docs.join("omega.png"), &side_by_side(&[&marble, &wall]))?;
    }
    if want("morph") {
        println!("morph: pink marble to leaves, a horizontal ramp, half-reduced");
        let a = imaging::load_color(&tex.join("pink_marble_color_128.png"))?;
        let b = imaging::load_color(&tex.join("leaves_green_color_161.png"))?;
        let (w, h) = (640, 192);
        let maps = weights::ramp(2, weights::Axis::X, w, h);
        let settings = ParallelSettings::defaults_for(Neighbourhood::Half, true);
        let t = std::time::Instant::now();
        let mut backend = LocalSearch::new(Engine::default());
        let out = parallel::synth::morph(
            &[&a, &b],
            &maps,
            w,
            h,
            &settings,
            &mut backend,
            &texsyn::progress::Silent,
        )?;
        println!("  {:.2} s", t.elapsed().as_secs_f64());
        imaging::save_color(
            &docs.join("morph.png"),
            &side_by_side(&[&a, &out.image, &b]),
        )?;
    }
    if want("replay") {
        println!("replay: mossy rock 1024² synthesised, its height, normal and roughness replayed");
        let shared = root.join("../shared/textures");
        let map = |k: &str| shared.join(format!("mossy_rock_{k}_1024.png"));
        let colour = imaging::load_color(&map("color"))?;
        let side = 384;
        let t = std::time::Instant::now();
        let mut backend = LocalSearch::new(Engine::default());
        let out = parallel::synth::synthesize(
            &colour,
            side,
            side,
            &ParallelSettings::defaults_for(Neighbourhood::Full(7), false),
            &mut backend,
            &texsyn::progress::Silent,
        )?;
        println!("  {:.2} s", t.elapsed().as_secs_f64());
        let mut row = vec![out.image];
        for k in ["height", "normal", "roughness"] {
            let deep = imaging::load_image(&map(k))?;
            let replayed = deep.rebuild(&out.coords[0].coords, side, side, None)?;
            row.push(ColorImage::from_vec(
                side,
                side,
                replayed.to_dynamic().into_rgb8().into_raw(),
            ));
        }
        let refs: Vec<&ColorImage> = row.iter().collect();
        imaging::save_color(&docs.join("replay.png"), &side_by_side(&refs))?;
    }
    if want("solid") {
        println!("solid: pink marble on x, y and z, 128³, half-reduced");
        let marble = imaging::load_color(&tex.join("pink_marble_color_128.png"))?;
        let views: Vec<solid::View> = solid::Axis::ALL
            .into_iter()
            .map(|axis| solid::View {
                axis,
                exemplar: &marble,
                material: 0,
            })
            .collect();
        let t = std::time::Instant::now();
        let mut backend = LocalSearch::new(Engine::default());
        let out = solid::synthesize(
            &views,
            &solid::MaterialWeights::Single,
            [128; 3],
            &solid::SolidSettings::default(),
            &mut backend,
            &texsyn::progress::Silent,
        )?;
        println!("  {:.2} s", t.elapsed().as_secs_f64());
        let v = texsyn::imaging::volume::Volume::new(out.size, 3, out.colour)?;
        imaging::save_color(
            &docs.join("solid.png"),
            &side_by_side(&[&marble, &v.preview(4)]),
        )?;
    }
    if want("procedural") {
        use texsyn::procedural::{self as matching, catalogue, transform};
        println!("procedural: pink marble matched, then transformed into the leopard match");
        let t = std::time::Instant::now();
        let cat = catalogue::Catalogue::build(
            &catalogue::BuildSettings::default(),
            &texsyn::progress::Silent,
        )?;
        println!("  catalogue {:.1} s", t.elapsed().as_secs_f64());
        let settings = matching::MatchSettings::default();
        let marble = imaging::load_color(&tex.join("pink_marble_color_128.png"))?;
        // A photo that another shader matches, so the row shows a jump.
        let leopard = matching::analysis_image(
            &imaging::load_color(&root.join("../shared/textures/leopard_color_64.png"))?,
            128,
        );
        let a = matching::match_texture(&marble, &cat, &settings)?;
        let b = matching::match_texture(&leopard, &cat, &settings)?;
        for m in [&a, &b] {
            println!(
                "  {} S_F {:.3} S_L {:.3} colour {:.3} in {:.1} s",
                m.pattern.shader.name, m.s_f, m.s_l, m.colour, m.seconds
            );
        }
        let path = transform::transform(
            &cat,
            &[a.pattern.clone(), b.pattern.clone()],
            &transform::TransformSettings::default(),
        )?;
        let side = 128;
        let mut row = vec![marble.clone(), a.pattern.render(side, side)];
        for f in transform::frames(&path, 6).iter().skip(1) {
            row.push(f.render(side, side));
        }
        row.push(leopard.clone());
        let refs: Vec<&ColorImage> = row.iter().collect();
        imaging::save_color(&docs.join("procedural.png"), &side_by_side(&refs))?;
    }
    println!("wrote {}", docs.display());
    Ok(())
}
