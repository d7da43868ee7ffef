//! Modular Radiance Transfer (paper 001): scene-independent operators of one shape.
//!
//! # Layout
//! - [`flux`]: turns a shape's coefficients so that the first alone carries the flux.
//! - [`lighting_prior`]: the direct-light basis a shape's operators are fitted on.
//! - [`lightfield`]: radiance crossing a block opening, discretised in space and direction.
//! - [`shape`]: a shape's operators `U_b`, `T_d→b` and its openings' `U_r` (content-keyed).
//! - [`shape_symmetry`]: a block's operators from its canonical shape's (rotation, mirror).
//! - [`one_bounce`]: sparse one-bounce gather rows over a whole scene (the dense `--full`
//!   operator).

pub mod flux;
pub mod lightfield;
pub mod lighting_prior;
pub mod one_bounce;
pub mod shape;
pub mod shape_symmetry;
