//! Compact transport with shared source bases (transport kind 3, format 2.2), and the
//! unfolding a runtime does at load back to plain compact transport (kind 2).
//!
//! In compact transport each receiving block B stores `Z_B` (k_B × Σ r_A), one column per
//! source block A's shape coefficient. What B receives from A passes A's openings, so over all
//! the blocks A lights, `[Y_B Z_BA]_B` has a low numerical rank j_A < r_A: A's light that
//! leaves it lies near a j_A-dimensional row space `Q_A` (j_A × r_A, orthonormal rows) that every
//! receiver shares. Kind 3 stores `Q_A` once per source and, per receiver, `Z'_BA = Z_BA Q_Aᵀ`
//! (k_B × j_A) in place of `Z_BA`, so the unfolded `Z_BA ≈ Z'_BA Q_A`. Sources without a basis
//! keep their r_A columns as in kind 2 (the baker factors a source only when that is smaller).
//!
//! Units: as kind 2 (albedo-free radiance per unit of b). `Q_A` is dimensionless.
//!
//! Invariant: [`SourceBases::unfold`] sums each product in a fixed order (f64 accumulation,
//! one rounding to f32), so a bundle unfolds to the same bits on every machine.

use super::{Bundle, CompactEntry, Matrix, TransportOps};

/// One source block's shared basis.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceBasis {
    pub source_block: u32,
    /// j × r_source, rows orthonormal (up to the codec).
    pub q: Matrix,
}

/// Compact transport whose entries read some sources through their [`SourceBasis`].
#[derive(Clone, Debug, PartialEq)]
pub struct SourceBases {
    /// Ascending by source block, at most one each.
    pub bases: Vec<SourceBasis>,
    /// As [`TransportOps::Compact`]'s, except that `z`'s columns for a source with a basis are
    /// its j basis coefficients instead of its r shape coefficients.
    pub entries: Vec<CompactEntry>,
}

impl SourceBases {
    /// The basis of `source`, if it has one.
    pub fn basis(&self, source: u32) -> Option<&Matrix> {
        self.bases
            .binary_search_by_key(&source, |b| b.source_block)
            .ok()
            .map(|i| &self.bases[i].q)
    }

    /// Columns source `source` takes in an entry's `z`: its basis' rank, else `rank`
    /// (its shape's).
    pub fn width(&self, source: u32, rank: u32) -> u32 {
        self.basis(source).map_or(rank, |q| q.rows)
    }

    /// Plain compact entries (`z` over every source's shape coefficients): `Z_BA = Z'_BA Q_A`
    /// for sources with a basis, the columns as stored for the others. `rank(a)` is block a's
    /// shape rank. Call on a validated bundle's transport (`decode` validates).
    pub fn unfold(&self, rank: impl Fn(u32) -> u32) -> Vec<CompactEntry> {
        self.entries
            .iter()
            .map(|e| {
                let k = e.z.rows as usize;
                let width: usize = e.sources.iter().map(|&s| rank(s) as usize).sum();
                let mut z = Matrix::zeros(k, width);
                let (mut from, mut to) = (0usize, 0usize);
                for &s in &e.sources {
                    let r = rank(s) as usize;
                    match self.basis(s) {
                        Some(q) => {
                            let j = q.rows as usize;
                            for i in 0..k {
                                let coef = &e.z.row(i)[from..from + j];
                                let out = &mut z.data[i * width + to..i * width + to + r];
                                for (c, o) in out.iter_mut().enumerate() {
                                    let mut sum = 0.0f64;
                                    for (m, &a) in coef.iter().enumerate() {
                                        sum += f64::from(a) * f64::from(q.data[m * r + c]);
                                    }
                                    *o = sum as f32;
                                }
                            }
                            from += j;
                        }
                        None => {
                            for i in 0..k {
                                z.data[i * width + to..i * width + to + r]
                                    .copy_from_slice(&e.z.row(i)[from..from + r]);
                            }
                            from += r;
                        }
                    }
                    to += r;
                }
                CompactEntry {
                    target_block: e.target_block,
                    sources: e.sources.clone(),
                    y: e.y.clone(),
                    z,
                }
            })
            .collect()
    }
}

impl Bundle {
    /// The same bundle with transport kind 3 unfolded to kind 2 ([`SourceBases::unfold`]), and
    /// the factored form it held (None for any other transport, which comes back unchanged):
    /// a runtime reads kind 2's sizes and sums everywhere and may apply the factored products.
    /// Call on a validated bundle, its blocks' symmetries unfolded or not (ranks are the
    /// shapes').
    pub fn unfold_source_bases(mut self) -> (Bundle, Option<SourceBases>) {
        let Some(TransportOps::Factored(f)) = self
            .transport
            .take_if(|t| matches!(t, TransportOps::Factored(_)))
        else {
            return (self, None);
        };
        let rank = |b: u32| self.shapes[self.blocks[b as usize].shape as usize].u_b.cols;
        self.transport = Some(TransportOps::Compact(f.unfold(rank)));
        (self, Some(f))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unfolding_multiplies_the_basis_in_and_copies_unfactored_sources() {
        // Two sources: block 1 (rank 3) with a 2 × 3 basis, block 2 (rank 2) without.
        let q = Matrix::from_fn(2, 3, |i, j| (1 + i + 2 * j) as f32);
        let z = Matrix::from_fn(2, 4, |i, j| (10 * i + j) as f32 - 1.5);
        let f = SourceBases {
            bases: vec![SourceBasis {
                source_block: 1,
                q: q.clone(),
            }],
            entries: vec![CompactEntry {
                target_block: 0,
                sources: vec![1, 2],
                y: Matrix::from_fn(5, 2, |i, j| (i * j) as f32),
                z: z.clone(),
            }],
        };
        assert_eq!(f.width(1, 3), 2);
        assert_eq!(f.width(2, 2), 2);
        let out = f.unfold(|b| [4, 3, 2][b as usize]);
        let u = &out[0].z;
        assert_eq!((u.rows, u.cols), (2, 5));
        for i in 0..2 {
            for c in 0..3 {
                let want: f32 = (0..2).map(|m| z.data[i * 4 + m] * q.data[m * 3 + c]).sum();
                assert_eq!(u.data[i * 5 + c], want, "row {i} column {c}");
            }
            assert_eq!(&u.data[i * 5 + 3..i * 5 + 5], &z.data[i * 4 + 2..i * 4 + 4]);
        }
        assert_eq!(out[0].y, f.entries[0].y);
    }
}
