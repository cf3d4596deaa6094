//! The one parser of sizes and grids (`WxH`, `N` or `XxYxZ`) used by every
//! command's flags.

use anyhow::{bail, ensure, Context, Result};

use crate::lattice::{Lattice, LatticeSpec};
use crate::{block, imaging};

/// Parses `s`, the value of `flag`, as positive numbers joined by `x` (`WxH`,
/// `XxYxZ`); `counts` lists how many numbers are allowed, `example` shows one.
pub fn parse_dims(s: &str, flag: &str, counts: &[usize], example: &str) -> Result<Vec<usize>> {
    let parts: Vec<&str> = s.split(['x', 'X']).map(str::trim).collect();
    // The name of each side, for the messages.
    let side = |i: usize| match (parts.len(), i) {
        (2, 0) => "width",
        (2, _) => "height",
        (3, 0) => "x edge",
        (3, 1) => "y edge",
        (3, _) => "z edge",
        _ => "side",
    };
    let nums = parts
        .iter()
        .enumerate()
        .map(|(i, v)| match v.parse::<usize>() {
            Ok(0) => bail!("{flag} '{s}': the {} must be at least 1", side(i)),
            Ok(n) => Ok(n),
            Err(_) => bail!(
                "{flag} '{s}': the {} '{v}' is not a positive number, e.g. {flag} {example}",
                side(i)
            ),
        })
        .collect::<Result<Vec<_>>>()?;
    ensure!(
        counts.contains(&nums.len()),
        "{flag} '{s}' has {} numbers; give it as e.g. {flag} {example}",
        nums.len()
    );
    Ok(nums)
}

/// Parses an output `--size WxH`, checked against the canvas limits.
pub fn parse_size(s: &str) -> Result<(usize, usize)> {
    let d = parse_dims(s, "--size", &[2], "512x512")?;
    let (w, h) = (d[0], d[1]);
    ensure!(
        w.saturating_mul(h) <= block::MAX_CANVAS_PIXELS && w.max(h) <= imaging::MAX_SIDE,
        "size {w}x{h} is too large: the limit is {} pixels and {} per side; use a smaller --size",
        block::MAX_CANVAS_PIXELS,
        imaging::MAX_SIDE
    );
    Ok((w, h))
}

/// Parses a `WxH` pair of `flag` (a grid, a tile size) without limits.
pub fn parse_pair(s: &str, flag: &str) -> Result<(usize, usize)> {
    let d = parse_dims(s, flag, &[2], "4x4")?;
    Ok((d[0], d[1]))
}

/// Parses `--lattice WxH` (two periods in pixels, fractions allowed),
/// `--lattice auto` or `--lattice none`.
pub fn parse_lattice(s: &str) -> Result<LatticeSpec> {
    if s.trim().eq_ignore_ascii_case("auto") {
        return Ok(LatticeSpec::Auto);
    }
    if s.trim().eq_ignore_ascii_case("none") {
        return Ok(LatticeSpec::Off);
    }
    let (w, h) = s.split_once(['x', 'X']).with_context(|| {
        format!("--lattice '{s}' is not WxH, auto or none, e.g. --lattice 32x32")
    })?;
    // The periods' range is checked with the sample (`Lattice::validate`).
    let period = |name: &str, v: &str| -> Result<f64> {
        v.trim().parse().with_context(|| {
            format!("--lattice '{s}': the {name} '{v}' is not a number, e.g. --lattice 32x32")
        })
    };
    Ok(LatticeSpec::Given(Lattice {
        period: [period("width", w)?, period("height", h)?],
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_bad_ones_name_the_flag() {
        assert_eq!(parse_size("64x32").unwrap(), (64, 32));
        assert_eq!(parse_size(" 7 X 9 ").unwrap(), (7, 9));
        assert_eq!(parse_pair("3x2", "--grid").unwrap(), (3, 2));
        assert_eq!(parse_dims("5", "--size", &[1, 3], "128").unwrap(), vec![5]);
        for bad in ["64", "0x4", "ax4", "4x", "1x2x3", "", "-1x4"] {
            let e = parse_size(bad).unwrap_err().to_string();
            assert!(e.contains("--size"), "{bad}: {e}");
        }
        assert!(parse_size("100000x100000").is_err());
        assert!(parse_size("ax10")
            .unwrap_err()
            .to_string()
            .contains("width"));
        assert!(parse_size("10x0")
            .unwrap_err()
            .to_string()
            .contains("height"));
    }
}
