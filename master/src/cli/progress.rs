//! The CLI's one [`Progress`] implementation: a bar per stage on stderr,
//! hidden with `--quiet` (indicatif also hides it when stderr is not a
//! terminal), and a spinner for work of unknown length.

use std::sync::Mutex;

use indicatif::{ProgressBar, ProgressStyle};

use crate::progress::Progress;

/// A progress bar per stage.
pub struct Bars {
    bar: Mutex<Option<ProgressBar>>,
    quiet: bool,
}

impl Bars {
    pub fn new(quiet: bool) -> Self {
        Bars {
            bar: Mutex::new(None),
            quiet,
        }
    }

    fn with(&self, f: impl FnOnce(&ProgressBar)) {
        if let Some(b) = self.bar.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
            f(b);
        }
    }
}

impl Progress for Bars {
    fn start(&self, label: &str, len: u64, unit: &str) {
        tracing::info!(stage = label, steps = len, "started");
        if self.quiet {
            return;
        }
        let bar = ProgressBar::new(len);
        let template =
            format!("{{msg}} [{{bar:40}}] {{pos}}/{{len}} {unit} {{elapsed_precise}} eta {{eta}}");
        bar.set_style(
            ProgressStyle::with_template(&template)
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        bar.set_message(label.to_string());
        let old = self
            .bar
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .replace(bar);
        if let Some(old) = old {
            old.finish_and_clear();
        }
    }

    fn advance(&self, n: u64) {
        self.with(|b| b.inc(n));
    }

    fn set_done(&self, done: u64) {
        self.with(|b| b.set_position(done));
    }

    fn finish(&self) {
        if let Some(b) = self.bar.lock().unwrap_or_else(|e| e.into_inner()).take() {
            b.finish_and_clear();
        }
    }

    fn note(&self, text: &str) {
        if self.shows_notes() {
            eprintln!("{text}");
        }
    }
}

impl Bars {
    /// Whether notes go to the terminal: not with `--quiet`, and not when
    /// stderr is a pipe or a file (the notes are in the `RUST_LOG=info` log).
    fn shows_notes(&self) -> bool {
        use std::io::IsTerminal;
        !self.quiet && std::io::stderr().is_terminal()
    }
}

impl Drop for Bars {
    fn drop(&mut self) {
        self.finish();
    }
}

/// A spinner with `message` for work of unknown length (hidden with `--quiet`).
pub fn spinner(quiet: bool, message: String) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new_spinner();
    b.set_message(message);
    b.enable_steady_tick(std::time::Duration::from_millis(120));
    b
}
