//! Labelled photos for procedural matching (Bourque–Dudek §3.4: matches
//! judged against real targets): each photo's expected shader families and,
//! where it has one, its count per image (rows, boards, cells across the
//! centred square that matching analyses), and the check of a match
//! against its label.
//!
//! The label file has one photo per line, whitespace-separated:
//! `file families count how`, where `families` is `name` or `a|b` (any of
//! them is right), `count` is a number or `-`, and the rest of the line says
//! how the count was measured. `#` starts a comment.

use anyhow::{bail, ensure, Context, Result};

use super::pattern::Pattern;
use super::shaders::by_name;

/// A match's count may differ from the label's by this share.
pub const COUNT_TOLERANCE: f64 = 0.15;

/// One labelled photo.
#[derive(Clone, Debug, PartialEq)]
pub struct Label {
    pub file: String,
    /// The shader families that are right for it.
    pub families: Vec<String>,
    /// Its count per image, when it has one.
    pub count: Option<f64>,
    /// How the count was measured.
    pub how: String,
}

/// Reads a label file's text; a bad line is refused naming it.
pub fn parse(text: &str) -> Result<Vec<Label>> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let at = || format!("label line {}", i + 1);
        let mut parts = line.split_whitespace();
        let (Some(file), Some(families), Some(count)) = (parts.next(), parts.next(), parts.next())
        else {
            bail!(
                "{}: give `file families count how`, e.g. `brick.png bricks 14 rows counted`",
                at()
            );
        };
        let families: Vec<String> = families.split('|').map(str::to_string).collect();
        for f in &families {
            ensure!(
                by_name(f).is_some(),
                "{}: unknown shader family '{f}'",
                at()
            );
        }
        let count = match count {
            "-" => None,
            c => {
                let v: f64 = c
                    .parse()
                    .ok()
                    .filter(|v: &f64| v.is_finite() && *v > 0.0)
                    .with_context(|| {
                        format!("{}: count '{c}' is not a positive number or -", at())
                    })?;
                Some(v)
            }
        };
        out.push(Label {
            file: file.to_string(),
            families,
            count,
            how: parts.collect::<Vec<_>>().join(" "),
        });
    }
    Ok(out)
}

/// A match judged against its label.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    pub family_right: bool,
    /// The match's count, when its shader has one.
    pub count: Option<f64>,
    /// |found − label| / label, when both have a count.
    pub count_error: Option<f64>,
    /// Family right, and the count within [`COUNT_TOLERANCE`] where the
    /// label has one.
    pub right: bool,
}

/// Judges `found` against `label`.
pub fn check(label: &Label, found: &Pattern) -> Verdict {
    let family_right = label.families.iter().any(|f| f == found.shader.name);
    // Counted as the labels count them, along rows (`count_across`).
    let count = found.shader.count_across(&found.params);
    let count_error = match (label.count, count) {
        (Some(want), Some(got)) => Some((got - want).abs() / want),
        _ => None,
    };
    let count_ok = match (label.count, count_error) {
        (None, _) => true,
        (Some(_), Some(e)) => e <= COUNT_TOLERANCE,
        (Some(_), None) => false,
    };
    Verdict {
        family_right,
        count,
        count_error,
        right: family_right && count_ok,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(name: &str, params: Vec<f64>) -> Pattern {
        Pattern {
            shader: by_name(name).unwrap(),
            params,
            colours: [[0.0; 3], [255.0; 3]],
        }
    }

    #[test]
    fn labels_parse_with_alternatives_counts_and_comments() {
        let l = parse("# photos\nbrick.png bricks 14 rows counted in the viewer\n\nwalnut.png clouds|turbulence -  # noise\n").unwrap();
        assert_eq!(l.len(), 2);
        assert_eq!(l[0].count, Some(14.0));
        assert_eq!(l[0].how, "rows counted in the viewer");
        assert_eq!(l[1].families, vec!["clouds", "turbulence"]);
        assert_eq!(l[1].count, None);
    }

    #[test]
    fn bad_label_lines_are_refused_naming_the_line() {
        for (text, needle) in [
            ("a.png bricks", "line 1"),
            ("a.png plaid 3 x", "unknown shader family 'plaid'"),
            ("\na.png bricks -3 x", "line 2"),
            ("a.png bricks NaN x", "not a positive number"),
        ] {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.contains(needle), "{text}: {e}");
        }
    }

    #[test]
    fn a_right_match_passes_and_planted_wrong_labels_fail() {
        // 14 rows of bricks, matched with 13: within 15%.
        let found = pattern("bricks", vec![13.0, 3.0, 0.1, 2.0, 0.1, 0.0]);
        let right = parse("b.png bricks|planks 14 counted").unwrap();
        let v = check(&right[0], &found);
        assert!(v.right && v.family_right, "{v:?}");
        assert!((v.count_error.unwrap() - 1.0 / 14.0).abs() < 1e-12);
        // A wrong family planted in the label fails...
        let wrong_family = parse("b.png stripes 14 counted").unwrap();
        let v = check(&wrong_family[0], &found);
        assert!(!v.right && !v.family_right, "{v:?}");
        // ...and so does a count off by more than 15% (13 against 16).
        let wrong_count = parse("b.png bricks 16 counted").unwrap();
        let v = check(&wrong_count[0], &found);
        assert!(v.family_right && !v.right, "{v:?}");
        // A label with a count is not met by a shader without one.
        let v = check(
            &parse("w.png clouds 5 x").unwrap()[0],
            &pattern("clouds", vec![3.0, 0.5]),
        );
        assert!(v.family_right && !v.right, "{v:?}");
        // Without a count the family decides.
        let v = check(
            &parse("w.png clouds - x").unwrap()[0],
            &pattern("clouds", vec![3.0, 0.5]),
        );
        assert!(v.right, "{v:?}");
    }

    #[test]
    fn scattered_cells_are_judged_by_the_cells_a_row_meets() {
        // Five Worley points per unit, jittered over their whole cell: a
        // row meets about six cells per unit, and that is what a photo's
        // cells counted along a row are compared with.
        let found = pattern("cells", vec![5.0, 1.0, 1.0, 0.1]);
        let six = check(&parse("s.png cells 6 counted").unwrap()[0], &found);
        assert!(six.right, "{six:?}");
        let got = six.count.unwrap();
        assert!(got > 5.75 && got < 6.5, "{got}");
        let five = check(&parse("s.png cells 5 counted").unwrap()[0], &found);
        assert!(five.family_right && !five.right, "{five:?}");
        // On a square grid (the least jitter) the count stays near the
        // points per unit.
        let grid = check(
            &parse("s.png cells 5 counted").unwrap()[0],
            &pattern("cells", vec![5.0, 0.2, 1.0, 0.1]),
        );
        assert!(grid.right, "{grid:?}");
    }
}
