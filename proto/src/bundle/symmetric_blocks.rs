//! Blocks that instance a shape through a box symmetry (bundle format 2, section kind 14), and
//! the unfolding a runtime does at load: one permuted copy of a shape's operators per (shape,
//! symmetry) used, so per-frame code never permutes.
//!
//! A shape's operators are defined in its canonical frame; a block that is a rotation or mirror
//! image of it stores the [`BoxSymmetry`] taking the block's frame to the shape's, and its closed
//! faces. With `perm = symmetry.texel_permutation(closed, T)` (block texel → shape texel):
//! `U_b(block)[x] = U_b[perm[x]]`, `T_d→b(block)[:, x] = T_d→b[:, perm[x]]`, an opening on block
//! face `f` is the shape's opening on `symmetry.map_face(f)` with `U_r` rows permuted alike, and
//! the mode coefficients `b` mean the same in both frames, so transport and DRT operators, which
//! read `b`, need nothing.
//!
//! Invariant: `decode` accepts a symmetric block only if its closed faces tile the shape's rows
//! exactly (`rows = faces · T²`), so unfolding never indexes out of range.

use crate::box_symmetry::BoxSymmetry;
use crate::wire::{Reader, Writer};
use crate::Face;

use super::{BlockOps, Bundle, BundleError, Matrix, OpeningOps, ShapeOps};

/// How a block instances its shape: the symmetry from the block's frame to the shape's, and the
/// block's closed faces (which fix the texel layout the permutation runs over).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BlockSymmetry {
    pub symmetry: BoxSymmetry,
    /// Bit `f.index()` set for each closed face of the block, in the block's frame.
    pub closed: u8,
}

impl BlockSymmetry {
    /// The block's closed faces, in [`Face::ALL`] order.
    pub fn closed_faces(&self) -> Vec<Face> {
        Face::ALL
            .into_iter()
            .filter(|f| self.closed & (1 << f.index()) != 0)
            .collect()
    }

    /// The closed-face mask of a list of faces.
    pub fn mask(closed: &[Face]) -> u8 {
        closed.iter().fold(0, |m, f| m | 1 << f.index())
    }

    /// Texels per face side `T` when the closed faces tile `rows` texels as `faces · T²`.
    fn texels_per_side(&self, rows: u32) -> Option<usize> {
        let faces = self.closed.count_ones() as usize;
        if faces == 0 || self.closed >> 6 != 0 || !(rows as usize).is_multiple_of(faces) {
            return None;
        }
        let per_face = rows as usize / faces;
        let t = (per_face as f64).sqrt().round() as usize;
        (t * t == per_face && t > 0).then_some(t)
    }

    /// Whether this symmetry can instance `shape` (what `Bundle::validate` checks).
    pub(super) fn check(&self, shape: &ShapeOps) -> Result<(), String> {
        if self.texels_per_side(shape.u_b.rows).is_none() {
            return Err(format!(
                "closed faces {:#08b} do not tile the shape's {} texels as T×T per face",
                self.closed, shape.u_b.rows
            ));
        }
        for o in &shape.openings {
            let Some(face) = Face::ALL.get(o.face as usize) else {
                return Err(format!("shape opening face {} is not a face", o.face));
            };
            let block_face = self.symmetry.inverse().map_face(*face);
            if self.closed & (1 << block_face.index()) != 0 {
                return Err(format!(
                    "the shape's opening {face} maps onto the block's closed face {block_face}"
                ));
            }
        }
        Ok(())
    }

    /// Block texel → shape texel, for a shape of `rows` texels (checked by `check`).
    pub fn texel_permutation(&self, rows: u32) -> Vec<u32> {
        let t = self.texels_per_side(rows).unwrap_or(0);
        self.symmetry.texel_permutation(&self.closed_faces(), t)
    }
}

/// Writes section kind 14: `n:u32 × (id:str shape:u32 texel_offset:u32 symmetry:u8 closed:u8)`.
/// An identity block writes symmetry 0 and closed 0.
pub(super) fn write_blocks(w: &mut Writer, blocks: &[BlockOps]) {
    w.u32(blocks.len() as u32);
    for b in blocks {
        w.str(&b.id);
        w.u32(b.shape);
        w.u32(b.texel_offset);
        let (code, closed) = b.symmetry.map_or((0, 0), |s| (s.symmetry.code(), s.closed));
        w.u8(code);
        w.u8(closed);
    }
}

/// Reads section kind 14.
pub(super) fn read_blocks(r: &mut Reader) -> Result<Vec<BlockOps>, BundleError> {
    let n = r.u32()? as usize;
    let mut out = Vec::with_capacity(n.min(r.remaining() / 14));
    for _ in 0..n {
        let id = r.str()?;
        let shape = r.u32()?;
        let texel_offset = r.u32()?;
        let code = r.u8()?;
        let closed = r.u8()?;
        let symmetry = BoxSymmetry::from_code(code).ok_or_else(|| {
            BundleError::Invalid(format!("block {id}: symmetry code {code} is not below 48"))
        })?;
        out.push(BlockOps {
            id,
            shape,
            texel_offset,
            symmetry: (!symmetry.is_identity()).then_some(BlockSymmetry { symmetry, closed }),
        });
    }
    Ok(out)
}

/// `m` with row `i` taken from row `perm[i]`.
fn permute_rows(m: &Matrix, perm: &[u32]) -> Matrix {
    let cols = m.cols as usize;
    let mut data = Vec::with_capacity(m.data.len());
    for &p in perm {
        let p = p as usize;
        data.extend_from_slice(&m.data[p * cols..(p + 1) * cols]);
    }
    Matrix {
        rows: m.rows,
        cols: m.cols,
        data,
    }
}

/// `m` with column `j` taken from column `perm[j]`.
fn permute_cols(m: &Matrix, perm: &[u32]) -> Matrix {
    let cols = m.cols as usize;
    let mut data = Vec::with_capacity(m.data.len());
    for i in 0..m.rows as usize {
        let row = &m.data[i * cols..(i + 1) * cols];
        data.extend(perm.iter().map(|p| row[*p as usize]));
    }
    Matrix {
        rows: m.rows,
        cols: m.cols,
        data,
    }
}

/// A shape's operators seen from a block instancing it through `s`.
fn instance(shape: &ShapeOps, s: &BlockSymmetry) -> ShapeOps {
    let perm = s.texel_permutation(shape.u_b.rows);
    let inverse = s.symmetry.inverse();
    let mut openings: Vec<OpeningOps> = shape
        .openings
        .iter()
        .map(|o| OpeningOps {
            face: inverse.map_face(Face::ALL[o.face as usize]).index() as u8,
            u_r: permute_rows(&o.u_r, &perm),
        })
        .collect();
    openings.sort_by_key(|o| o.face);
    ShapeOps {
        key: s.symmetry.instance_key(&shape.key),
        u_b: permute_rows(&shape.u_b, &perm),
        t_db: permute_cols(&shape.t_db, &perm),
        openings,
    }
}

impl Bundle {
    /// The same bundle with every symmetric block given its own permuted copy of its shape
    /// (one per distinct (shape, symmetry)) and no symmetries left: what a runtime applies
    /// without permuting per frame. A bundle without symmetric blocks comes back unchanged.
    /// Call on a validated bundle (`decode` validates).
    pub fn unfold_symmetries(mut self) -> Bundle {
        let mut made: Vec<((u32, BlockSymmetry), u32)> = Vec::new();
        for b in 0..self.blocks.len() {
            let Some(s) = self.blocks[b].symmetry.take() else {
                continue;
            };
            let shape = self.blocks[b].shape;
            let index = match made.iter().find(|(k, _)| *k == (shape, s)) {
                Some((_, i)) => *i,
                None => {
                    let copy = instance(&self.shapes[shape as usize], &s);
                    self.shapes.push(copy);
                    let i = self.shapes.len() as u32 - 1;
                    made.push(((shape, s), i));
                    i
                }
            };
            self.blocks[b].shape = index;
        }
        self
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn instancing_permutes_rows_of_u_and_columns_of_t_alike() {
        // Closed faces -x, -y, +y, +z at T = 2: 16 texels, rank 3.
        let closed = [Face::NegX, Face::NegY, Face::PosY, Face::PosZ];
        let shape = ShapeOps {
            key: "k".into(),
            u_b: Matrix::from_fn(16, 3, |i, j| (i * 10 + j) as f32),
            t_db: Matrix::from_fn(3, 16, |i, j| (j * 10 + i) as f32),
            openings: vec![],
        };
        for g in BoxSymmetry::all() {
            let s = BlockSymmetry {
                symmetry: g,
                closed: BlockSymmetry::mask(&closed),
            };
            let perm = s.texel_permutation(16);
            let inst = instance(&shape, &s);
            for x in 0..16usize {
                for k in 0..3usize {
                    assert_eq!(
                        inst.u_b.data[x * 3 + k],
                        shape.u_b.data[perm[x] as usize * 3 + k]
                    );
                    assert_eq!(
                        inst.t_db.data[k * 16 + x],
                        shape.t_db.data[k * 16 + perm[x] as usize]
                    );
                }
            }
            // U T (the block's self-transport) is the shape's, renumbered.
            let ut = |m: &ShapeOps, a: usize, b: usize| -> f32 {
                (0..3)
                    .map(|k| m.u_b.data[a * 3 + k] * m.t_db.data[k * 16 + b])
                    .sum()
            };
            for a in 0..16 {
                for b in 0..16 {
                    assert_eq!(
                        ut(&inst, a, b),
                        ut(&shape, perm[a] as usize, perm[b] as usize)
                    );
                }
            }
        }
    }

    #[test]
    fn symmetries_that_do_not_tile_the_shape_are_refused() {
        let shape = ShapeOps {
            key: "k".into(),
            u_b: Matrix::from_fn(12, 1, |_, _| 0.0),
            t_db: Matrix::from_fn(1, 12, |_, _| 0.0),
            openings: vec![],
        };
        let s = |closed: u8| BlockSymmetry {
            symmetry: BoxSymmetry::from_code(9).unwrap(),
            closed,
        };
        assert!(s(0b000111).check(&shape).is_ok()); // 3 faces × 2²
        assert!(s(0b000011).check(&shape).is_err()); // 2 × 6: not square
        assert!(s(0).check(&shape).is_err());
        assert!(s(0b1000_0111).check(&shape).is_err()); // bit past the six faces
    }
}
