//! Progress reporting from the bake engine to whoever drives it (a CLI bar, API events), and the
//! parts of the bundle that are final before the bake ends.
//!
//! Invariants: implementations are cheap and thread-safe; the engine calls `advance` from rayon
//! workers. Each bundle passed to `sections_ready` holds the final bundle's sections up to some
//! point in file order (layout, shapes, blocks, transport, then DRT, probes, DNRT) and nothing
//! after it, so its encoding, cut before the table of contents, is a prefix of the final
//! bundle's bytes.

/// Receives stage changes and progress steps.
pub trait Progress: Sync {
    /// A new stage begins with `total` work items.
    fn stage(&self, name: &str, total: u64);
    /// `n` more items of the current stage are done.
    fn advance(&self, n: u64);
    /// Whether `sections_ready` does anything (building the partial bundle costs a copy).
    fn wants_sections(&self) -> bool {
        false
    }
    /// The bundle's leading sections are final (see the module invariant).
    fn sections_ready(&self, _bundle: &lightfarm_proto::bundle::Bundle) {}
}

/// Ignores everything.
pub struct NoProgress;

impl Progress for NoProgress {
    fn stage(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
}
