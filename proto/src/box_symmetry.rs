//! Symmetries of an axis-aligned box: the 48 signed permutations of the axes, and how one maps a
//! block's local frame, faces and face grids (texels, lightfield cells and direction bins) onto a
//! canonical shape's.
//!
//! A block whose box is a rotation or mirror image of another (a T-junction facing east and one
//! facing north) has the same scene-independent operators up to a renumbering of texels, so the
//! bundle stores the canonical shape once and each block names the symmetry that takes its local
//! frame to the shape's (`docs/bundle-format.md`, section `blocks` kind 14).
//!
//! Convention: a symmetry `g` takes block-local coordinates (the box at `[0, extent]`) to the
//! canonical shape's: block axis `k` becomes canonical axis `g.axis(k)`, reversed when
//! `g.flips(k)`: `p_c[axis(k)] = flips(k) ? e[k] − p[k] : p[k]`, directions likewise without the
//! extent. Code 0 is the identity; `code = permutation · 8 + flip bits (x = 1, y = 2, z = 4)`.
//!
//! Texels are `T×T` per closed face in [`Face::ALL`] order, texel `(i, j)` at `j·T + i` along the
//! face's ascending tangent axes ([`crate::face`]). Whatever `g`, a face's grid maps onto the
//! image face's grid by a [`GridMap`] (swap of the two tangent axes, reversal of each), the same
//! for any grid laid along the tangent axes: texels, and an opening's lightfield cells and
//! concentric-map direction bins (the concentric map commutes with the square's symmetries).
//!
//! Invariant: pure functions of their arguments, no allocation beyond the returned vectors;
//! callers validate inputs from the wire (`BoxSymmetry::from_code` refuses codes ≥ 48).

use crate::Face;

/// The six permutations of three axes; `PERMUTATIONS[p][k]` is the image of axis `k`.
const PERMUTATIONS: [[usize; 3]; 6] = [
    [0, 1, 2],
    [0, 2, 1],
    [1, 0, 2],
    [1, 2, 0],
    [2, 0, 1],
    [2, 1, 0],
];

/// One of the 48 symmetries of an axis-aligned box (up to its extents).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Default)]
pub struct BoxSymmetry(u8);

/// How a face's `n × n` grid maps onto its image face's grid under a [`BoxSymmetry`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct GridMap {
    /// The face's first tangent axis becomes the image's second.
    pub swap: bool,
    /// Reverse the first (`i`) coordinate, before any swap.
    pub flip_i: bool,
    /// Reverse the second (`j`) coordinate, before any swap.
    pub flip_j: bool,
}

impl GridMap {
    /// The image of grid cell `(i, j)` of an `n × n` grid.
    pub fn apply(self, i: usize, j: usize, n: usize) -> (usize, usize) {
        let a = if self.flip_i { n - 1 - i } else { i };
        let b = if self.flip_j { n - 1 - j } else { j };
        if self.swap {
            (b, a)
        } else {
            (a, b)
        }
    }

    /// The image of the cell with index `j·n + i`, as an index.
    pub fn apply_index(self, index: usize, n: usize) -> usize {
        let (i, j) = self.apply(index % n, index / n, n);
        j * n + i
    }
}

impl BoxSymmetry {
    pub const IDENTITY: BoxSymmetry = BoxSymmetry(0);
    /// Number of symmetries.
    pub const COUNT: u8 = 48;

    /// The symmetry with this wire code, if valid.
    pub fn from_code(code: u8) -> Option<BoxSymmetry> {
        (code < Self::COUNT).then_some(BoxSymmetry(code))
    }

    /// Wire code (0 = identity).
    pub fn code(self) -> u8 {
        self.0
    }

    /// All 48, identity first.
    pub fn all() -> impl Iterator<Item = BoxSymmetry> {
        (0..Self::COUNT).map(BoxSymmetry)
    }

    pub fn is_identity(self) -> bool {
        self.0 == 0
    }

    /// The key naming a shape's operators seen through this symmetry: the shape's own key for
    /// the identity, else `key~code` (the bake's per-block operators and the client's unfolded
    /// shapes are named alike).
    pub fn instance_key(self, shape_key: &str) -> String {
        if self.is_identity() {
            shape_key.to_string()
        } else {
            format!("{shape_key}~{}", self.0)
        }
    }

    /// The canonical axis block axis `k` becomes.
    pub fn axis(self, k: usize) -> usize {
        PERMUTATIONS[(self.0 / 8) as usize][k]
    }

    /// Whether block axis `k` is reversed.
    pub fn flips(self, k: usize) -> bool {
        self.0 & (1 << k) != 0
    }

    /// The inverse symmetry (canonical frame → block frame).
    pub fn inverse(self) -> BoxSymmetry {
        let mut perm = [0usize; 3];
        let mut flip_bits = 0u8;
        for k in 0..3 {
            // Canonical axis axis(k) goes back to block axis k, reversed alike.
            perm[self.axis(k)] = k;
            if self.flips(k) {
                flip_bits |= 1 << self.axis(k);
            }
        }
        let p = PERMUTATIONS
            .iter()
            .position(|q| *q == perm)
            .expect("every permutation is listed");
        BoxSymmetry(p as u8 * 8 + flip_bits)
    }

    /// The canonical box's extents.
    pub fn map_extent(self, extent: [f64; 3]) -> [f64; 3] {
        let mut out = [0.0; 3];
        for (k, e) in extent.iter().enumerate() {
            out[self.axis(k)] = *e;
        }
        out
    }

    /// A block-local point in the canonical frame (`extent`: the block's).
    pub fn map_point(self, p: [f64; 3], extent: [f64; 3]) -> [f64; 3] {
        let mut out = [0.0; 3];
        for k in 0..3 {
            out[self.axis(k)] = if self.flips(k) {
                extent[k] - p[k]
            } else {
                p[k]
            };
        }
        out
    }

    /// A block-local direction in the canonical frame.
    pub fn map_direction(self, d: [f64; 3]) -> [f64; 3] {
        let mut out = [0.0; 3];
        for k in 0..3 {
            out[self.axis(k)] = if self.flips(k) { -d[k] } else { d[k] };
        }
        out
    }

    /// The canonical face block face `f` becomes.
    pub fn map_face(self, f: Face) -> Face {
        let a = f.axis();
        let max_side = f.is_max_side() != self.flips(a);
        Face::ALL[2 * self.axis(a) + usize::from(max_side)]
    }

    /// How face `f`'s grid maps onto `map_face(f)`'s grid.
    pub fn grid_map(self, f: Face) -> GridMap {
        let (u, v) = f.tangent_axes();
        GridMap {
            swap: self.axis(u) > self.axis(v),
            flip_i: self.flips(u),
            flip_j: self.flips(v),
        }
    }

    /// Per texel of a block with closed faces `closed` (any order; texels are laid out in
    /// [`Face::ALL`] order) and `t × t` texels per face, the index of the canonical shape's texel
    /// it is. The canonical shape's closed faces are the images of `closed`.
    pub fn texel_permutation(self, closed: &[Face], t: usize) -> Vec<u32> {
        let block_faces: Vec<Face> = Face::ALL
            .into_iter()
            .filter(|f| closed.contains(f))
            .collect();
        let canonical_faces: Vec<Face> = Face::ALL
            .into_iter()
            .filter(|f| block_faces.iter().any(|b| self.map_face(*b) == *f))
            .collect();
        let per_face = t * t;
        let mut out = Vec::with_capacity(block_faces.len() * per_face);
        for f in &block_faces {
            let image = self.map_face(*f);
            let slot = canonical_faces
                .iter()
                .position(|c| *c == image)
                .expect("the image of a closed face is closed");
            let map = self.grid_map(*f);
            for index in 0..per_face {
                out.push((slot * per_face + map.apply_index(index, t)) as u32);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn compose(a: BoxSymmetry, b: BoxSymmetry, p: [f64; 3], e: [f64; 3]) -> [f64; 3] {
        b.map_point(a.map_point(p, e), a.map_extent(e))
    }

    #[test]
    fn inverse_undoes_every_symmetry() {
        let e = [2.0, 3.0, 5.0];
        let p = [0.25, 1.5, 4.0];
        for g in BoxSymmetry::all() {
            let back = compose(g, g.inverse(), p, e);
            assert_eq!(back, p, "{g:?}");
            assert_eq!(g.inverse().inverse(), g);
            for f in Face::ALL {
                assert_eq!(g.inverse().map_face(g.map_face(f)), f);
            }
        }
        assert_eq!(BoxSymmetry::all().count(), 48);
        assert!(BoxSymmetry::from_code(48).is_none());
    }

    #[test]
    fn faces_map_where_their_points_go() {
        // A point on face f maps onto face map_face(f) of the canonical box.
        let e = [2.0, 3.0, 5.0];
        for g in BoxSymmetry::all() {
            let ce = g.map_extent(e);
            for f in Face::ALL {
                let (u, v) = f.tangent_axes();
                let mut p = [0.0; 3];
                p[f.axis()] = if f.is_max_side() { e[f.axis()] } else { 0.0 };
                p[u] = 0.3 * e[u];
                p[v] = 0.6 * e[v];
                let q = g.map_point(p, e);
                let image = g.map_face(f);
                let expect = if image.is_max_side() {
                    ce[image.axis()]
                } else {
                    0.0
                };
                assert_eq!(q[image.axis()], expect, "{g:?} {f}");
            }
        }
    }

    #[test]
    fn grid_map_follows_texel_centres() {
        // Texel (i, j)'s centre maps to the centre of texel grid_map(i, j) on the image face.
        let e = [2.0, 3.0, 5.0];
        let t = 4;
        for g in BoxSymmetry::all() {
            let ce = g.map_extent(e);
            for f in Face::ALL {
                let (u, v) = f.tangent_axes();
                let image = g.map_face(f);
                let (cu, cv) = image.tangent_axes();
                for j in 0..t {
                    for i in 0..t {
                        let mut p = [0.0; 3];
                        p[f.axis()] = if f.is_max_side() { e[f.axis()] } else { 0.0 };
                        p[u] = (i as f64 + 0.5) / t as f64 * e[u];
                        p[v] = (j as f64 + 0.5) / t as f64 * e[v];
                        let q = g.map_point(p, e);
                        let ci = (q[cu] / ce[cu] * t as f64).floor() as usize;
                        let cj = (q[cv] / ce[cv] * t as f64).floor() as usize;
                        assert_eq!(g.grid_map(f).apply(i, j, t), (ci, cj), "{g:?} {f}");
                    }
                }
            }
        }
    }

    #[test]
    fn texel_permutation_is_a_bijection_onto_the_canonical_texels() {
        let closed = [Face::NegX, Face::NegY, Face::PosY, Face::PosZ];
        for g in BoxSymmetry::all() {
            let perm = g.texel_permutation(&closed, 3);
            let mut seen = perm.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..36).collect::<Vec<u32>>(), "{g:?}");
        }
        let id = BoxSymmetry::IDENTITY.texel_permutation(&closed, 3);
        assert_eq!(id, (0..36).collect::<Vec<u32>>());
    }
}
