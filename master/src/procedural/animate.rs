//! A transformation written out (Bourque–Dudek §4): its stops read or
//! matched, and its frames rendered, saved and added to the GIF and WebP
//! one at a time, so memory holds one frame whatever the count.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use serde_json::{json, Value};

use super::catalogue::Catalogue;
use super::config::{frame_name, TransformConfig, GIF, REPORT, WEBP};
use super::pattern::Pattern;
use super::search::{match_texture, MatchResult, MatchSettings};
use super::transform::Path as TransformPath;
use crate::imaging::{self, animation};
use crate::progress::Progress;

/// Largest pattern JSON read as a stop.
const MAX_PATTERN_BYTES: u64 = 1 << 20;

/// Whether `path` names a pattern JSON (else an image to match).
pub fn is_pattern(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("json"))
}

/// A pattern written by `texsyn match --params`.
pub fn load_pattern(path: &Path) -> Result<Pattern> {
    let bytes = imaging::read_regular(path, MAX_PATTERN_BYTES, "pattern")?;
    let v: Value = serde_json::from_slice(&bytes)
        .with_context(|| format!("{} is not JSON", path.display()))?;
    Pattern::from_json(&v).with_context(|| {
        format!(
            "{} is not a pattern written by texsyn match --params",
            path.display()
        )
    })
}

/// A stop of a transformation: a pattern JSON as given, or an image matched
/// (with its match).
pub fn load_stop(
    path: &Path,
    cat: &Catalogue,
    settings: &MatchSettings,
) -> Result<(Pattern, Option<MatchResult>)> {
    if is_pattern(path) {
        return Ok((load_pattern(path)?, None));
    }
    let m = match_texture(&imaging::load_color(path)?, cat, settings)?;
    Ok((m.pattern.clone(), Some(m)))
}

fn create(path: &Path) -> Result<BufWriter<File>> {
    let f = File::create(path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(BufWriter::new(f))
}

/// Renders `frames` at the configured size into `dir` (frame PNGs, and the
/// GIF and WebP unless the delay is 0), one frame at a time.
pub fn write_frames(
    dir: &Path,
    frames: &[Pattern],
    cfg: &TransformConfig,
    progress: &dyn Progress,
) -> Result<()> {
    let (w, h) = cfg.size;
    let animate = cfg.delay > 0;
    let mut gif_file = animate.then(|| create(&dir.join(GIF))).transpose()?;
    let mut gif = (gif_file.as_mut())
        .map(|f| animation::GifWriter::new(f, cfg.delay))
        .transpose()?;
    let mut webp = animate
        .then(|| animation::WebpWriter::new(create(&dir.join(WEBP))?, w, h, cfg.delay))
        .transpose()?;
    progress.start("frames", frames.len() as u64, "frames");
    for (i, f) in frames.iter().enumerate() {
        let img = f.render(w, h);
        imaging::save_color(&dir.join(frame_name(i)), &img)?;
        if let (Some(g), Some(p)) = (&mut gif, &mut webp) {
            g.add(&img)?;
            p.add(&img)?;
        }
        progress.advance(1);
    }
    progress.finish();
    // The GIF's trailer is written when its encoder is dropped.
    drop(gif);
    if let Some(mut f) = gif_file {
        f.flush()
            .with_context(|| format!("cannot write {}", dir.join(GIF).display()))?;
    }
    if let Some(p) = webp {
        p.finish()
            .with_context(|| format!("cannot write {}", dir.join(WEBP).display()))?;
    }
    Ok(())
}

/// The `transform.json` report: stops, path, frames, time.
pub fn report(stops: &[Pattern], path: &TransformPath, frames: &[Pattern], seconds: f64) -> Value {
    json!({
        "stops": stops.iter().map(Pattern::to_json).collect::<Vec<_>>(),
        "path_points": path.points.len(),
        "path_length": path.steps.iter().sum::<f64>(),
        "largest_step": path.steps.iter().cloned().fold(0.0, f64::max),
        "jumps": path.jumps.iter().filter(|&&j| j).count(),
        "seconds": seconds,
        "frames": frames.iter().map(Pattern::to_json).collect::<Vec<_>>(),
    })
}

/// Writes the frames, animations and report into the configured output
/// directory, replacing an older set only when all are written.
/// `started` is when the run began (for the report's seconds).
pub fn write_transform(
    cfg: &TransformConfig,
    stops: &[Pattern],
    path: &TransformPath,
    frames: &[Pattern],
    started: Instant,
    progress: &dyn Progress,
) -> Result<()> {
    let out = imaging::OutputDir::create(&cfg.output, &cfg.inputs())?;
    write_frames(out.path(), frames, cfg, progress)?;
    let report = report(stops, path, frames, started.elapsed().as_secs_f64());
    imaging::save_bytes(
        &out.path().join(REPORT),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    out.commit()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::procedural::recovery::draw;
    use crate::procedural::shaders::by_name;
    use crate::procedural::transform::TransformSettings;

    /// Frames streamed to disk give the bytes of the whole-set encoders.
    #[test]
    fn streamed_animations_are_the_whole_set_encodings() {
        let dir = tempfile::tempdir().unwrap();
        let frames: Vec<Pattern> = (0..4).map(|k| draw(by_name("spots").unwrap(), k)).collect();
        let cfg = TransformConfig {
            a: "a.json".into(),
            b: "b.json".into(),
            keys: Vec::new(),
            catalogue: "cat.json".into(),
            output: dir.path().join("unused"),
            frames: frames.len(),
            size: (24, 16),
            delay: 90,
            path: TransformSettings::default(),
            search: MatchSettings::default(),
            budget: crate::budget::Budget::default(),
        };
        write_frames(dir.path(), &frames, &cfg, &crate::progress::Silent).unwrap();
        let images: Vec<_> = frames.iter().map(|f| f.render(24, 16)).collect();
        let read = |n: &str| std::fs::read(dir.path().join(n)).unwrap();
        assert!(read(GIF) == animation::encode_gif(&images, 90).unwrap());
        assert!(read(WEBP) == animation::encode_webp(&images, 90).unwrap());
        let png = imaging::load_color(&dir.path().join(frame_name(3))).unwrap();
        assert!(png.rgb == images[3].rgb);
    }
}
