//! Why the DRT operators could not be built: shared by the ray passes ([`super::rays`], whose
//! cache can fail) and the operator build ([`super::build`], whose SVDs can), so neither depends
//! on the other for it.

use crate::bake::math::low_rank::LowRankError;
use crate::bake::transport::source::TransportUnavailable;

/// Why the DRT operators could not be built.
#[derive(Debug, thiserror::Error)]
pub enum DrtError {
    #[error(transparent)]
    LowRank(#[from] LowRankError),
    #[error("ray cache: {0}")]
    Cache(#[from] std::io::Error),
    #[error(transparent)]
    Transport(#[from] TransportUnavailable),
}
