//! The one memory budget every method checks its estimate against before it
//! allocates: the `--max-memory` cap when given, otherwise what this machine
//! and the process's cgroup can still give (the engine's
//! [`texsyn_engine::budget::available_bytes`]).

use anyhow::{ensure, Result};

/// A run's memory budget.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Budget {
    /// The cap of `--max-memory`, in bytes; `None` for what is available.
    pub cap: Option<u64>,
}

impl Budget {
    /// A budget capped at `mb` MiB (`--max-memory`), or what is available.
    pub fn of_mib(mb: Option<u64>) -> Self {
        Budget {
            cap: mb.map(|m| m.saturating_mul(1 << 20)),
        }
    }

    /// The bytes a run may take, when known.
    pub fn limit(&self) -> Option<u64> {
        self.cap.or_else(texsyn_engine::budget::available_bytes)
    }

    /// Refuses `what` when its estimated peak `needed` bytes exceed the
    /// budget; the message names the memory and `fix` (what to change).
    pub fn check(&self, what: &str, needed: u64, fix: &str) -> Result<()> {
        if let Some(limit) = self.limit() {
            ensure!(
                needed <= limit,
                "{what} needs about {} of memory, but {} {}; {fix}",
                human(needed),
                human(limit),
                if self.cap.is_some() {
                    "are allowed (--max-memory)"
                } else {
                    "are available"
                }
            );
        }
        Ok(())
    }
}

/// Bytes as MiB or GiB with one decimal.
pub fn human(bytes: u64) -> String {
    let gib = bytes as f64 / (1u64 << 30) as f64;
    if gib >= 1.0 {
        format!("{gib:.1} GiB")
    } else {
        format!("{:.1} MiB", bytes as f64 / (1u64 << 20) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cap_refuses_what_exceeds_it_and_names_the_fix() {
        let b = Budget::of_mib(Some(10));
        assert_eq!(b.limit(), Some(10 << 20));
        assert!(b.check("x", 10 << 20, "fix").is_ok());
        let e = b.check("a 9×9 thing", (10 << 20) + 1, "use a smaller --size");
        let msg = e.unwrap_err().to_string();
        assert!(
            msg.contains("a 9×9 thing") && msg.contains("--max-memory"),
            "{msg}"
        );
        assert!(msg.contains("use a smaller --size"), "{msg}");
        assert_eq!(human(3 << 30), "3.0 GiB");
        assert_eq!(human(5 << 19), "2.5 MiB");
    }
}
