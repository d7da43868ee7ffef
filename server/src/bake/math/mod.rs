//! Numerical building blocks of the bake, free of any scene concept.
//!
//! # Layout
//! - [`sampling`]: seeded quasi-random numbers (scrambled Sobol', Halton), hemisphere and disk
//!   maps, and [`sampling::Purpose`], the registry of every random stream a bake draws.
//! - [`low_rank`]: truncated SVD with ranks chosen from an energy tolerance (f64, faer).
//! - [`matrix`]: the bake's f64 matrices as the bundle's f32 ones, and their energy `‖m‖_F²`
//!   (the one sum every truncation by energy reads).

pub mod low_rank;
pub mod matrix;
pub mod sampling;
