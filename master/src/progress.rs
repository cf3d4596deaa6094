//! How a method reports progress: one trait for every method (levels of the
//! block and coordinate methods, sub-passes of solids, tiles, generations,
//! catalogue samples). The CLI implements it once, as progress bars; a
//! library caller passes [`Silent`] or its own.

/// Receives progress. A run is a sequence of stages (a level, a set of
/// tiles...), each of a known number of steps.
pub trait Progress: Sync {
    /// A stage of `len` steps begins: `label` names it (e.g. `level 2 (3/5)`),
    /// `unit` names a step (`blocks`, `tiles`...).
    fn start(&self, _label: &str, _len: u64, _unit: &str) {}
    /// `n` more steps of the stage are done.
    fn advance(&self, _n: u64) {}
    /// `done` steps of the stage are done (for stages that count absolutely).
    fn set_done(&self, _done: u64) {}
    /// The stage ended.
    fn finish(&self) {}
    /// A one-line summary of a finished stage (where the time went).
    fn note(&self, _text: &str) {}
}

/// No progress output.
pub struct Silent;
impl Progress for Silent {}
