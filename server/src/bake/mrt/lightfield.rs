//! The lightfield on a block opening: radiance crossing an axis-aligned rectangle, discretised
//! into `K×K` spatial cells × `d×d` direction bins (MRT's interface lightfields).
//!
//! Frame: a lightfield is defined by the opening's rectangle (world-aligned, tangent axes in
//! ascending order) and the travel direction `sign · e_axis`. Directions are binned by their
//! tangent components `(ω_u, ω_v)`, a point of the unit disk, mapped to the square by the inverse
//! concentric map; equal-area bins there are equal projected solid angle, which is exactly how
//! cosine-weighted rays distribute. Two blocks sharing an opening index the same lightfield
//! identically (same rectangle, same world axes, same travel sign), so the outgoing lightfield of
//! one is the incoming lightfield of the other with no resampling.
//!
//! Invariant: index = cell · d² + bin, cell = cv · K + cu, bin = bv · d + bu.

use crate::bake::math::sampling::{invert_concentric_disk, sample_concentric_disk};

/// Discretisation of one opening's lightfield.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightfieldFrame {
    pub axis: usize,
    /// +1 or −1: the travel direction along `axis`.
    pub sign: f64,
    /// Plane coordinate along `axis`.
    pub coord: f64,
    pub min: [f64; 2],
    pub max: [f64; 2],
    pub cells: usize,
    pub dirs: usize,
}

impl LightfieldFrame {
    pub fn len(&self) -> usize {
        self.cells * self.cells * self.dirs * self.dirs
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn tangents(&self) -> (usize, usize) {
        lightfarm_proto::face::tangent_axes(self.axis)
    }

    /// Index of the cell and bin of a ray crossing the plane at `p` travelling along `w`.
    pub fn index(&self, p: [f64; 3], w: [f64; 3]) -> usize {
        let (u, v) = self.tangents();
        let cell_of = |x: f64, lo: f64, hi: f64, n: usize| {
            (((x - lo) / (hi - lo) * n as f64).floor().max(0.0) as usize).min(n - 1)
        };
        let cu = cell_of(p[u], self.min[0], self.max[0], self.cells);
        let cv = cell_of(p[v], self.min[1], self.max[1], self.cells);
        let sq = invert_concentric_disk([w[u], w[v]]);
        let bu = ((sq[0] * self.dirs as f64).floor() as usize).min(self.dirs - 1);
        let bv = ((sq[1] * self.dirs as f64).floor() as usize).min(self.dirs - 1);
        (cv * self.cells + cu) * self.dirs * self.dirs + bv * self.dirs + bu
    }

    /// A point in cell `index`'s spatial cell and a travel direction in its bin, from four
    /// uniform numbers.
    pub fn sample(&self, index: usize, u_pos: [f64; 2], u_dir: [f64; 2]) -> ([f64; 3], [f64; 3]) {
        let d2 = self.dirs * self.dirs;
        let cell = index / d2;
        let bin = index % d2;
        let (cu, cv) = (cell % self.cells, cell / self.cells);
        let (bu, bv) = (bin % self.dirs, bin / self.dirs);
        let (u, v) = self.tangents();
        let mut p = [0.0; 3];
        p[self.axis] = self.coord;
        p[u] =
            self.min[0] + (cu as f64 + u_pos[0]) / self.cells as f64 * (self.max[0] - self.min[0]);
        p[v] =
            self.min[1] + (cv as f64 + u_pos[1]) / self.cells as f64 * (self.max[1] - self.min[1]);
        let sq = [
            (bu as f64 + u_dir[0]) / self.dirs as f64,
            (bv as f64 + u_dir[1]) / self.dirs as f64,
        ];
        let disk = sample_concentric_disk(sq);
        let mut w = [0.0; 3];
        w[u] = disk[0];
        w[v] = disk[1];
        w[self.axis] = self.sign
            * (1.0 - disk[0] * disk[0] - disk[1] * disk[1])
                .max(1e-12)
                .sqrt();
        (p, w)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::math::sampling::sobol_2d;

    #[test]
    fn samples_land_in_their_own_cell_and_bin() {
        let frame = LightfieldFrame {
            axis: 0,
            sign: -1.0,
            coord: 4.0,
            min: [0.0, 1.0],
            max: [3.0, 5.0],
            cells: 3,
            dirs: 4,
        };
        for index in 0..frame.len() {
            for i in 0..16 {
                let (p, w) = frame.sample(
                    index,
                    sobol_2d(index as u64, i),
                    sobol_2d(999 + index as u64, i),
                );
                assert!(w[0] < 0.0);
                assert_eq!(frame.index(p, w), index);
            }
        }
    }
}
