//! Delta Radiance Transfer (paper 000): the scene-dependent operators that add clutter to MRT.
//!
//! # Layout (in data-flow order)
//! - [`clutter_basis`]: the basis for direct light on a clutter object (`T_d→c`).
//! - [`clutter_sampling`]: importance sampling toward clutter for the gathers (ours).
//! - [`sight`]: which block texels could see clutter at all, through the openings, decided
//!   before any ray (texels that cannot are not traced).
//! - [`rays`]: the two ray passes (block texels toward clutter, clutter texels) and their reuse
//!   across bakes, bounded by [`reach`] (the region a texel's rays swept); stored on disk by
//!   [`crate::bake::cache::drt_rays`].
//! - [`build`]: the delta operators `ΔU_b`, `ΔU_c`, `C_b` and the exact gather, from the rays
//!   ([`build::DrtInputs`]: what it reads), accumulated as [`rows`]; buried block texels get
//!   [`inpaint`]ed transport.
//! - [`tiles`]: the exact gather's few-hit entries pooled by tile of the surface they hit
//!   ([`tiles::TilePool`], bundle format 2.6).
//! - [`compaction`]: their low-rank form, where smaller.
//! - [`error`]: [`error::DrtError`], why a DRT build failed (rays and build share it).
//! - [`lit_source`]: [`lit_source::LitSource`], the block or clutter object a row reads (the
//!   SH gathers key their rows by it too).

pub mod build;
pub mod clutter_basis;
pub mod clutter_sampling;
pub mod compaction;
pub mod error;
pub mod inpaint;
pub mod lit_source;
pub mod rays;
pub mod reach;
pub mod rows;
pub mod sight;
pub mod tiles;
