//! Where DRT's inpainting finds the f64 transport into the few blocks that hold a buried
//! texel: a transport the bake holds ([`MrtTransport`]), or one the transport cache hands out
//! block by block ([`crate::bake::cache::transport::LazyTransport`]), so a rebake after a
//! clutter edit reads those blocks' operators, not the level's (1.86 GB of f64 at 1,000
//! blocks).
//!
//! Invariant: [`TransportSource::into_targets`] returns every operator into each marked
//! target block, in the order the whole transport lists them, so [`MrtTransport::reaches`]
//! and [`MrtTransport::row`] answer for a marked target exactly as on the whole transport.

use crate::bake::transport::build::MrtTransport;

/// The cached transport into a block could not be read (evicted, or corrupt): the cache entry
/// is dropped, and the bake computes the transport again.
#[derive(Debug, thiserror::Error)]
#[error("cached transport into block {block} could not be read: {reason}")]
pub struct TransportUnavailable {
    pub block: usize,
    pub reason: String,
}

/// The f64 MRT transport into chosen target blocks.
pub trait TransportSource: Sync {
    /// Every operator into the blocks `targets` marks (indexed by block), in transport order.
    fn into_targets(&self, targets: &[bool]) -> Result<MrtTransport, TransportUnavailable>;
}

impl TransportSource for MrtTransport {
    fn into_targets(&self, targets: &[bool]) -> Result<MrtTransport, TransportUnavailable> {
        Ok(self.for_targets(targets))
    }
}
