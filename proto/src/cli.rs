//! Command-line helpers shared by `texsyn` and `texsyn-worker`: one-line
//! usage errors and the one parser of the duration flags.

/// Parses the command line of `program`. A usage error (unknown flag, bad
/// value) is printed as one line `PROGRAM: error: ...` and exits with code 1;
/// help and version go out as clap prints them.
pub fn parse_or_exit<C: clap::Parser>(program: &str) -> C {
    use clap::error::ErrorKind;
    C::try_parse().unwrap_or_else(|e| {
        if matches!(
            e.kind(),
            ErrorKind::DisplayHelp
                | ErrorKind::DisplayVersion
                | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
        ) {
            e.exit()
        }
        eprintln!("{program}: error: {}", usage_line(&e.render().to_string()));
        std::process::exit(1)
    })
}

/// A clap error as one line, without the usage and the "for more
/// information" lines, pointing at `--help`.
fn usage_line(text: &str) -> String {
    let parts: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| {
            !l.is_empty() && !l.starts_with("Usage:") && !l.starts_with("For more information")
        })
        .map(|l| l.strip_prefix("error: ").unwrap_or(l))
        .collect();
    let mut line = parts.join(" ");
    if !line.contains("--help") {
        line.push_str(" (see --help)");
    }
    line
}

/// An error message as one line (line breaks of nested causes become spaces).
pub fn one_line(message: &str) -> String {
    message
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" ")
}

/// Parses a number of seconds in `min..=max` (finite), as a clap value
/// parser: `value_parser = |s: &str| parse_seconds(s, 0.1, 600.0)`.
pub fn parse_seconds(s: &str, min: f64, max: f64) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| {
        format!("'{s}' is not a number of seconds; give one between {min} and {max}")
    })?;
    check_seconds(v, s, min, max)
}

/// `v` (written `text`) when finite and in `min..=max`.
pub fn check_seconds(v: f64, text: &str, min: f64, max: f64) -> Result<f64, String> {
    if v.is_finite() && (min..=max).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{text} seconds is out of range; give a number between {min} and {max}"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clap_errors_become_one_line() {
        let text = "error: unexpected argument '--x' found\n\nUsage: texsyn [OPTIONS]\n\nFor more information, try '--help'.\n";
        assert_eq!(
            usage_line(text),
            "unexpected argument '--x' found (see --help)"
        );
    }

    #[test]
    fn seconds_are_finite_and_in_range() {
        assert_eq!(parse_seconds(" 2.5 ", 0.1, 600.0), Ok(2.5));
        for bad in ["nan", "inf", "-inf", "-1", "0", "601", "1e300", "x", ""] {
            assert!(parse_seconds(bad, 0.1, 600.0).is_err(), "{bad}");
        }
    }
}
