//! Progress reporting from the bake engine to whoever drives it (a CLI bar, API events).
//!
//! Invariant: implementations are cheap and thread-safe; the engine calls `advance` from rayon
//! workers.

/// Receives stage changes and progress steps.
pub trait Progress: Sync {
    /// A new stage begins with `total` work items.
    fn stage(&self, name: &str, total: u64);
    /// `n` more items of the current stage are done.
    fn advance(&self, n: u64);
}

/// Ignores everything.
pub struct NoProgress;

impl Progress for NoProgress {
    fn stage(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
}
