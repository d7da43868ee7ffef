//! Lightmap texels on mesh clutter: one atlas per mesh, its texels (world position, normal,
//! area) and the map from a hit on a triangle back to its texel (the triangle equivalent of
//! [`crate::bake::scene::geometry::Geometry::texel_at`]).
//!
//! **UV space.** Atlas coordinates are in texel units, `x` to the right and `y` down; texel
//! `(i, j)` is the square `[i, i+1] × [j, j+1]` and its centre `(i + ½, j + ½)`.
//! - With `TEXCOORD_1` on every triangle (a glTF's lightmap UVs, `[0, 1]²`, `v` down as glTF
//!   has it): the atlas is `N × N` with `N = ⌈√(A_world / A_uv) / h⌉` (clamped to
//!   `1..=MAX_ATLAS_SIDE`), so the mean density is `h` metres per texel; `uv · N` are the
//!   texel coordinates. Overlapping UVs are the author's choice: such texels are shared.
//! - Otherwise a generated chart atlas (a clean implementation, see below): triangles are
//!   grouped into charts by edge adjacency (vertices equal bit for bit) while their face normal
//!   stays within [`CHART_MAX_ANGLE_DEG`] of the chart's first triangle; each chart is projected
//!   orthographically onto the plane of that normal, measured in `h`-sized texels, and the
//!   charts' rectangles are packed on shelves (tallest first) with a [`GUTTER`]-texel gap. A
//!   chart whose projection folds over itself (a texel centre strictly inside two of its
//!   triangles) is split into one chart per triangle. An axis-aligned chart's first tangent axis
//!   is the face's first tangent axis (`proto::face`), so a mesh cube's faces lie like a box's.
//!
//! **Resolution.** `h` (metres per texel) is the mesh's largest bounding-box extent divided by
//! the scene's `texels_per_face`: a mesh cube gets `T × T` texels per face, exactly as the same
//! cube as box clutter does.
//!
//! **Texels.** Every texel whose square overlaps a triangle with positive area (conservative
//! rasterisation, so thin triangles get texels) is a texel; a triangle that overlaps none (a
//! zero-area UV triangle) gets the texel holding its UV centroid. Texels are ordered row-major
//! (`j` then `i`). A texel's owner is the first triangle containing its centre, else the first
//! overlapping it; its position is the centre clamped into the owner's UV triangle and mapped
//! to the world, its normal the owner's face normal (winding: counter-clockwise is the outside,
//! as glTF and OBJ have it), its area `h²` scaled by the owner's world/UV area ratio.
//!
//! Why not a crate: `uvunwrap` (pure Rust, MIT, 0.2: normal-cone charts, LSCM flattening, shape
//! packing) would give curved meshes fewer, larger charts; it is young and was not checked
//! here for output that is bit-identical at any thread count (its `parallel` feature), which
//! the bake promises; xatlas needs a C++ toolchain through its bindings. Clutter props have
//! near-planar charts, for which planar projection is exact (distortion at most
//! 1/cos 30° elsewhere) and ~400 lines keep the bake deterministic. Trying `uvunwrap` once its
//! determinism is checked is a follow-up.
//!
//! **Sides.** A closed piece of the mesh (every edge shared by two of its triangles in opposite
//! directions, [`closed_pieces`]) is lit from outside: a piece wound inside-out (negative
//! signed volume) is flipped before the atlas is built. An open piece (a sheet) is lit on its
//! counter-clockwise side; rays reaching its other side see an occluder only.
//!
//! Invariants: deterministic (no hashing with random state, ties broken by index); every
//! triangle has at least one texel; the texels of different generated charts are disjoint.

use std::collections::BTreeMap;

use glam::DVec3;

/// Largest angle between a chart triangle's normal and the chart's normal.
pub const CHART_MAX_ANGLE_DEG: f64 = 30.0;
/// Empty texels between packed charts.
pub const GUTTER: u32 = 1;
/// Largest atlas side, in texels.
pub const MAX_ATLAS_SIDE: u32 = 4096;

/// Where the atlas's UVs came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AtlasSource {
    Texcoord1,
    Generated,
}

/// Why an atlas could not be built.
#[derive(Debug, thiserror::Error)]
pub enum AtlasError {
    #[error("{object}: TEXCOORD_1 of triangle {triangle} is outside [0, 1]")]
    UvOutOfRange { object: String, triangle: usize },
    #[error("{object}: TEXCOORD_1 covers no area")]
    UvEmpty { object: String },
    #[error("{object}: lightmap atlas would be {width}×{height} texels, more than {limit} a side")]
    TooLarge {
        object: String,
        width: u32,
        height: u32,
        limit: u32,
    },
}

/// One lightmap texel of a mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshTexel {
    /// Column and row in the atlas.
    pub x: u32,
    pub y: u32,
    /// The triangle the texel's centre maps through.
    pub triangle: u32,
    pub chart: u32,
    /// Barycentric coordinates of `position` in the owner triangle.
    pub bary: [f64; 3],
    pub position: [f64; 3],
    pub normal: [f64; 3],
    /// World area of the texel (m²).
    pub area: f64,
}

/// A mesh's lightmap atlas.
#[derive(Clone, Debug)]
pub struct MeshAtlas {
    pub width: u32,
    pub height: u32,
    pub source: AtlasSource,
    /// Metres per texel the resolution was chosen for.
    pub texel_metres: f64,
    /// Per triangle: its vertices in atlas texel coordinates.
    pub triangle_uv: Vec<[[f64; 2]; 3]>,
    /// Per triangle: its chart.
    pub triangle_chart: Vec<u32>,
    pub n_charts: usize,
    /// Texels in row-major order.
    pub texels: Vec<MeshTexel>,
    /// `width × height`, local texel index or `u32::MAX`.
    grid: Vec<u32>,
    /// Per triangle, the texels it overlaps: `tri_texels[tri_start[k]..tri_start[k + 1]]`.
    tri_start: Vec<u32>,
    tri_texels: Vec<u32>,
    triangles: Vec<[[f64; 3]; 3]>,
}

/// Unit face normal by winding.
pub fn face_normal(t: &[[f64; 3]; 3]) -> [f64; 3] {
    let [a, b, c] = t.map(DVec3::from);
    let n = (b - a).cross(c - a);
    (n / n.length()).to_array()
}

fn area2(a: [f64; 2], b: [f64; 2], c: [f64; 2]) -> f64 {
    (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
}

/// Barycentric coordinates of `p` in the 2D triangle `t` (None if degenerate).
fn bary2(t: &[[f64; 2]; 3], p: [f64; 2]) -> Option<[f64; 3]> {
    let a = area2(t[0], t[1], t[2]);
    if a.abs() < 1e-300 {
        return None;
    }
    let b0 = area2(p, t[1], t[2]) / a;
    let b1 = area2(t[0], p, t[2]) / a;
    Some([b0, b1, 1.0 - b0 - b1])
}

/// Closest point of the 2D triangle `t` to `p`, as barycentric coordinates.
fn closest_bary2(t: &[[f64; 2]; 3], p: [f64; 2]) -> [f64; 3] {
    if let Some(b) = bary2(t, p) {
        if b.iter().all(|x| *x >= 0.0) {
            return b;
        }
    }
    // Nearest point on the three edges.
    let mut best = (f64::INFINITY, [1.0, 0.0, 0.0]);
    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
        let (a, b) = (t[i], t[j]);
        let d = [b[0] - a[0], b[1] - a[1]];
        let len2 = d[0] * d[0] + d[1] * d[1];
        let s = if len2 > 0.0 {
            (((p[0] - a[0]) * d[0] + (p[1] - a[1]) * d[1]) / len2).clamp(0.0, 1.0)
        } else {
            0.0
        };
        let q = [a[0] + s * d[0], a[1] + s * d[1]];
        let dist = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2);
        if dist < best.0 {
            let mut w = [0.0; 3];
            w[i] = 1.0 - s;
            w[j] = s;
            best = (dist, w);
        }
    }
    best.1
}

/// True when the 2D triangle and the square `[x, x+1] × [y, y+1]` overlap by more than `eps`
/// along every separating axis (positive-area overlap).
fn overlaps_square(t: &[[f64; 2]; 3], x: f64, y: f64, eps: f64) -> bool {
    let square = [[x, y], [x + 1.0, y], [x + 1.0, y + 1.0], [x, y + 1.0]];
    let mut axes: Vec<[f64; 2]> = vec![[1.0, 0.0], [0.0, 1.0]];
    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
        let e = [t[j][0] - t[i][0], t[j][1] - t[i][1]];
        let l = (e[0] * e[0] + e[1] * e[1]).sqrt();
        if l > 0.0 {
            axes.push([-e[1] / l, e[0] / l]);
        }
    }
    axes.iter().all(|a| {
        let proj = |p: &[f64; 2]| p[0] * a[0] + p[1] * a[1];
        let (t0, t1) = t
            .iter()
            .map(proj)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |m, v| {
                (m.0.min(v), m.1.max(v))
            });
        let (s0, s1) = square
            .iter()
            .map(proj)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |m, v| {
                (m.0.min(v), m.1.max(v))
            });
        t1.min(s1) - t0.max(s0) > eps
    })
}

/// A deterministic tangent frame for a chart normal: the first tangent is the first world axis
/// other than the dominant one, made orthogonal to `n`.
fn chart_frame(n: [f64; 3]) -> (DVec3, DVec3) {
    let n = DVec3::from(n);
    let a = n.abs();
    let dominant = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    let (first, second) = lightfarm_proto::face::tangent_axes(dominant);
    let mut e = DVec3::ZERO;
    e[first] = 1.0;
    let u = e - e.dot(n) * n;
    let u = u / u.length();
    // Second tangent: the remaining world axis' direction, so axis-aligned faces keep
    // ascending tangent axes (`proto::face`).
    let mut v = n.cross(u);
    if v[second] < 0.0 {
        v = -v;
    }
    (u, v)
}

/// Charts by edge adjacency within the normal cone; per triangle its chart, in order of first
/// triangle.
fn group_charts(triangles: &[[[f64; 3]; 3]], normals: &[[f64; 3]]) -> (Vec<u32>, usize) {
    type Key = [u64; 3];
    let key = |p: [f64; 3]| p.map(f64::to_bits);
    let mut edges: BTreeMap<(Key, Key), Vec<u32>> = BTreeMap::new();
    for (k, t) in triangles.iter().enumerate() {
        for (i, j) in [(0, 1), (1, 2), (2, 0)] {
            let (a, b) = (key(t[i]), key(t[j]));
            let e = if a <= b { (a, b) } else { (b, a) };
            edges.entry(e).or_default().push(k as u32);
        }
    }
    let cos_max = CHART_MAX_ANGLE_DEG.to_radians().cos();
    let mut chart = vec![u32::MAX; triangles.len()];
    let mut n_charts = 0u32;
    for seed in 0..triangles.len() {
        if chart[seed] != u32::MAX {
            continue;
        }
        let n_seed = DVec3::from(normals[seed]);
        chart[seed] = n_charts;
        let mut queue = std::collections::VecDeque::from([seed]);
        while let Some(k) = queue.pop_front() {
            let t = triangles[k];
            for (i, j) in [(0, 1), (1, 2), (2, 0)] {
                let (a, b) = (key(t[i]), key(t[j]));
                let e = if a <= b { (a, b) } else { (b, a) };
                for &m in &edges[&e] {
                    let m = m as usize;
                    if chart[m] == u32::MAX && DVec3::from(normals[m]).dot(n_seed) >= cos_max {
                        chart[m] = n_charts;
                        queue.push_back(m);
                    }
                }
            }
        }
        n_charts += 1;
    }
    (chart, n_charts as usize)
}

/// Pieces of a mesh (triangles connected through shared edges, vertices equal bit for bit)
/// and whether each is closed: every edge used by exactly two of its triangles in opposite
/// directions. Returns per triangle (piece, closed) and, per piece, its signed volume
/// (positive when counter-clockwise faces outward).
pub fn closed_pieces(triangles: &[[[f64; 3]; 3]]) -> (Vec<(u32, bool)>, Vec<f64>) {
    type Key = [u64; 3];
    let key = |p: [f64; 3]| p.map(f64::to_bits);
    // Directed edge uses per undirected edge: (+1 for a→b with a < b, −1 otherwise).
    let mut edges: BTreeMap<(Key, Key), Vec<(u32, i8)>> = BTreeMap::new();
    for (k, t) in triangles.iter().enumerate() {
        for (i, j) in [(0, 1), (1, 2), (2, 0)] {
            let (a, b) = (key(t[i]), key(t[j]));
            let (e, dir) = if a <= b { ((a, b), 1) } else { ((b, a), -1) };
            edges.entry(e).or_default().push((k as u32, dir));
        }
    }
    let mut piece = vec![u32::MAX; triangles.len()];
    let mut closed = Vec::new();
    let mut volume = Vec::new();
    for seed in 0..triangles.len() {
        if piece[seed] != u32::MAX {
            continue;
        }
        let id = closed.len() as u32;
        let (mut is_closed, mut vol) = (true, 0.0);
        piece[seed] = id;
        let mut queue = std::collections::VecDeque::from([seed]);
        while let Some(k) = queue.pop_front() {
            let t = triangles[k];
            let [a, b, c] = t.map(DVec3::from);
            vol += a.dot(b.cross(c)) / 6.0;
            for (i, j) in [(0, 1), (1, 2), (2, 0)] {
                let (a, b) = (key(t[i]), key(t[j]));
                let e = if a <= b { (a, b) } else { (b, a) };
                let uses = &edges[&e];
                if uses.len() != 2 || uses[0].1 == uses[1].1 {
                    is_closed = false;
                }
                for &(m, _) in uses {
                    if piece[m as usize] == u32::MAX {
                        piece[m as usize] = id;
                        queue.push_back(m as usize);
                    }
                }
            }
        }
        closed.push(is_closed);
        volume.push(vol);
    }
    (
        piece.iter().map(|p| (*p, closed[*p as usize])).collect(),
        volume,
    )
}

impl MeshAtlas {
    /// Builds the atlas of `triangles` (world, metres, counter-clockwise outside) at `h`
    /// metres per texel; `lightmap_uv` (TEXCOORD_1, one per triangle) when the mesh has it.
    pub fn build(
        object: &str,
        triangles: &[[[f64; 3]; 3]],
        lightmap_uv: Option<&[[[f64; 2]; 3]]>,
        h: f64,
    ) -> Result<MeshAtlas, AtlasError> {
        let normals: Vec<[f64; 3]> = triangles.iter().map(face_normal).collect();
        let (mut triangle_chart, mut n_charts) = group_charts(triangles, &normals);
        let (width, height, triangle_uv, source) = match lightmap_uv {
            Some(uv) => {
                for (k, t) in uv.iter().enumerate() {
                    if t.iter()
                        .flatten()
                        .any(|x| !(-1e-6..=1.0 + 1e-6).contains(x))
                    {
                        return Err(AtlasError::UvOutOfRange {
                            object: object.to_string(),
                            triangle: k,
                        });
                    }
                }
                let world: f64 = triangles
                    .iter()
                    .map(crate::bake::scene::mesh::triangle_area)
                    .sum();
                let uv_area: f64 = uv.iter().map(|t| 0.5 * area2(t[0], t[1], t[2]).abs()).sum();
                if !(uv_area > 1e-12) {
                    return Err(AtlasError::UvEmpty {
                        object: object.to_string(),
                    });
                }
                let side = ((world / uv_area).sqrt() / h).ceil();
                if side > MAX_ATLAS_SIDE as f64 {
                    return Err(AtlasError::TooLarge {
                        object: object.to_string(),
                        width: side as u32,
                        height: side as u32,
                        limit: MAX_ATLAS_SIDE,
                    });
                }
                let n = (side as u32).max(1);
                let scaled = uv
                    .iter()
                    .map(|t| t.map(|p| p.map(|x| x.clamp(0.0, 1.0) * n as f64)))
                    .collect();
                (n, n, scaled, AtlasSource::Texcoord1)
            }
            None => {
                let (w, hgt, uv) = generate(
                    object,
                    triangles,
                    &normals,
                    &mut triangle_chart,
                    &mut n_charts,
                    h,
                )?;
                (w, hgt, uv, AtlasSource::Generated)
            }
        };
        Ok(Self::rasterise(
            triangles,
            &normals,
            triangle_uv,
            triangle_chart,
            n_charts,
            width,
            height,
            source,
            h,
        ))
    }

    #[allow(clippy::too_many_arguments)]
    fn rasterise(
        triangles: &[[[f64; 3]; 3]],
        normals: &[[f64; 3]],
        triangle_uv: Vec<[[f64; 2]; 3]>,
        triangle_chart: Vec<u32>,
        n_charts: usize,
        width: u32,
        height: u32,
        source: AtlasSource,
        h: f64,
    ) -> MeshAtlas {
        let (w, hgt) = (width as usize, height as usize);
        // Per cell: (owner containing the centre, first overlapping triangle).
        let mut cells: Vec<(u32, u32)> = vec![(u32::MAX, u32::MAX); w * hgt];
        let mut overlaps: Vec<Vec<u32>> = vec![Vec::new(); triangles.len()];
        for (k, t) in triangle_uv.iter().enumerate() {
            let lo = |a: usize| t.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min);
            let hi = |a: usize| t.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max);
            let (x0, x1) = (
                lo(0).floor().max(0.0) as usize,
                (hi(0).ceil() as usize).min(w),
            );
            let (y0, y1) = (
                lo(1).floor().max(0.0) as usize,
                (hi(1).ceil() as usize).min(hgt),
            );
            for y in y0..y1 {
                for x in x0..x1 {
                    if !overlaps_square(t, x as f64, y as f64, 1e-9) {
                        continue;
                    }
                    overlaps[k].push((y * w + x) as u32);
                    let cell = &mut cells[y * w + x];
                    if cell.1 == u32::MAX {
                        cell.1 = k as u32;
                    }
                    let inside = bary2(t, [x as f64 + 0.5, y as f64 + 0.5])
                        .is_some_and(|b| b.iter().all(|v| *v >= -1e-9));
                    if inside && cell.0 == u32::MAX {
                        cell.0 = k as u32;
                    }
                }
            }
            if overlaps[k].is_empty() {
                // Zero-area UV triangle: the texel holding its centroid.
                let c = [0, 1].map(|a| (t[0][a] + t[1][a] + t[2][a]) / 3.0);
                let x = (c[0].floor().max(0.0) as usize).min(w - 1);
                let y = (c[1].floor().max(0.0) as usize).min(hgt - 1);
                overlaps[k].push((y * w + x) as u32);
                let cell = &mut cells[y * w + x];
                if cell.1 == u32::MAX {
                    cell.1 = k as u32;
                }
            }
        }
        let mut grid = vec![u32::MAX; w * hgt];
        let mut texels = Vec::new();
        for (i, &(inside, first)) in cells.iter().enumerate() {
            let owner = if inside != u32::MAX { inside } else { first };
            if owner == u32::MAX {
                continue;
            }
            let (x, y) = ((i % w) as u32, (i / w) as u32);
            let k = owner as usize;
            let t_uv = &triangle_uv[k];
            let b = closest_bary2(t_uv, [x as f64 + 0.5, y as f64 + 0.5]);
            let tri = &triangles[k];
            let position =
                std::array::from_fn(|a| b[0] * tri[0][a] + b[1] * tri[1][a] + b[2] * tri[2][a]);
            let uv_area = 0.5 * area2(t_uv[0], t_uv[1], t_uv[2]).abs();
            let area = if uv_area > 1e-12 {
                crate::bake::scene::mesh::triangle_area(tri) / uv_area
            } else {
                h * h
            };
            grid[i] = texels.len() as u32;
            texels.push(MeshTexel {
                x,
                y,
                triangle: owner,
                chart: triangle_chart[k],
                bary: b,
                position,
                normal: normals[k],
                area,
            });
        }
        let mut tri_start = vec![0u32];
        let mut tri_texels = Vec::new();
        for cells in overlaps {
            tri_texels.extend(cells.iter().map(|c| grid[*c as usize]));
            tri_start.push(tri_texels.len() as u32);
        }
        MeshAtlas {
            width,
            height,
            source,
            texel_metres: h,
            triangle_uv,
            triangle_chart,
            n_charts,
            texels,
            grid,
            tri_start,
            tri_texels,
            triangles: triangles.to_vec(),
        }
    }

    /// The texels triangle `k` overlaps (local indices).
    pub fn triangle_texels(&self, k: usize) -> &[u32] {
        &self.tri_texels[self.tri_start[k] as usize..self.tri_start[k + 1] as usize]
    }

    /// The local texel a hit at world point `p` on triangle `k` lands in: barycentric → UV →
    /// texel, O(1); a point whose cell holds no texel (on an edge, outside the conservative
    /// cover by rounding) takes the triangle's texel with the nearest centre.
    pub fn texel_at(&self, k: usize, p: [f64; 3]) -> usize {
        let [t0, t1, t2] = self.triangles[k].map(DVec3::from);
        let (e1, e2, d) = (t1 - t0, t2 - t0, DVec3::from(p) - t0);
        let n = e1.cross(e2);
        let nn = n.length_squared();
        let b1 = d.cross(e2).dot(n) / nn;
        let b2 = e1.cross(d).dot(n) / nn;
        let b = [1.0 - b1 - b2, b1, b2];
        let uv = &self.triangle_uv[k];
        let q: [f64; 2] =
            std::array::from_fn(|a| b[0] * uv[0][a] + b[1] * uv[1][a] + b[2] * uv[2][a]);
        // The cell holding a point of the triangle overlaps it, so it is one of its texels (or,
        // for a point on an edge, a neighbour's in the same chart: charts are a gutter apart).
        let (x, y) = (q[0].floor(), q[1].floor());
        if x >= 0.0 && y >= 0.0 && x < self.width as f64 && y < self.height as f64 {
            let local = self.grid[y as usize * self.width as usize + x as usize];
            if local != u32::MAX {
                return local as usize;
            }
        }
        let own = self.triangle_texels(k);
        let dist = |&&l: &&u32| {
            let tx = &self.texels[l as usize];
            (tx.x as f64 + 0.5 - q[0]).powi(2) + (tx.y as f64 + 0.5 - q[1]).powi(2)
        };
        *own.iter()
            .min_by(|a, b| dist(a).total_cmp(&dist(b)))
            .expect("every triangle has a texel") as usize
    }
}

/// The generated chart atlas: per-triangle UVs in texel units and the atlas size.
fn generate(
    object: &str,
    triangles: &[[[f64; 3]; 3]],
    normals: &[[f64; 3]],
    chart: &mut Vec<u32>,
    n_charts: &mut usize,
    h: f64,
) -> Result<(u32, u32, Vec<[[f64; 2]; 3]>), AtlasError> {
    // Project each chart; split charts that fold over themselves.
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); *n_charts];
    for (k, c) in chart.iter().enumerate() {
        members[*c as usize].push(k);
    }
    let mut charts: Vec<(Vec<usize>, Vec<[[f64; 2]; 3]>)> = Vec::new();
    for tris in members {
        let (u, v) = chart_frame(normals[tris[0]]);
        let project = |k: usize| {
            triangles[k].map(|p| {
                let p = DVec3::from(p);
                [p.dot(u) / h, p.dot(v) / h]
            })
        };
        let uv: Vec<[[f64; 2]; 3]> = tris.iter().map(|&k| project(k)).collect();
        if folds(&uv) {
            for &k in &tris {
                charts.push((vec![k], vec![project(k)]));
            }
        } else {
            charts.push((tris, uv));
        }
    }
    // Chart rectangles: origin at the floor of the chart's minimum, size to the ceiling.
    let rects: Vec<([f64; 2], [u32; 2])> = charts
        .iter()
        .map(|(_, uv)| {
            let lo = [0, 1].map(|a| {
                uv.iter()
                    .flatten()
                    .map(|p| p[a])
                    .fold(f64::INFINITY, f64::min)
            });
            let hi = [0, 1].map(|a| {
                uv.iter()
                    .flatten()
                    .map(|p| p[a])
                    .fold(f64::NEG_INFINITY, f64::max)
            });
            // An extent within rounding of a whole number of texels takes exactly that many.
            let size = [0, 1].map(|a| ((hi[a] - lo[a]) - 1e-9).ceil().max(1.0) as u32);
            (lo, size)
        })
        .collect();
    // Shelf packing, tallest first (ties by chart order).
    let mut order: Vec<usize> = (0..charts.len()).collect();
    order.sort_by(|a, b| rects[*b].1[1].cmp(&rects[*a].1[1]).then(a.cmp(b)));
    let total: f64 = rects
        .iter()
        .map(|r| ((r.1[0] + GUTTER) * (r.1[1] + GUTTER)) as f64)
        .sum();
    let widest = rects.iter().map(|r| r.1[0]).max().unwrap_or(1);
    let width = (total.sqrt().ceil() as u32).max(widest);
    let mut origin = vec![[0u32; 2]; charts.len()];
    let (mut x, mut y, mut shelf) = (0u32, 0u32, 0u32);
    for &c in &order {
        let [cw, ch] = rects[c].1;
        if x > 0 && x + cw > width {
            y += shelf + GUTTER;
            x = 0;
            shelf = 0;
        }
        origin[c] = [x, y];
        x += cw + GUTTER;
        shelf = shelf.max(ch);
    }
    let height = (y + shelf).max(1);
    if width > MAX_ATLAS_SIDE || height > MAX_ATLAS_SIDE {
        return Err(AtlasError::TooLarge {
            object: object.to_string(),
            width,
            height,
            limit: MAX_ATLAS_SIDE,
        });
    }
    let mut triangle_uv = vec![[[0.0; 2]; 3]; triangles.len()];
    for (c, (tris, uv)) in charts.iter().enumerate() {
        let (lo, _) = rects[c];
        for (&k, t) in tris.iter().zip(uv) {
            chart[k] = c as u32;
            triangle_uv[k] = t.map(|p| {
                [
                    p[0] - lo[0] + origin[c][0] as f64,
                    p[1] - lo[1] + origin[c][1] as f64,
                ]
            });
        }
    }
    *n_charts = charts.len();
    Ok((width, height, triangle_uv))
}

/// True when some texel centre lies strictly inside two of the chart's projected triangles.
fn folds(uv: &[[[f64; 2]; 3]]) -> bool {
    if uv.len() < 2 {
        return false;
    }
    // The grid as placed: whole texels from the chart's minimum.
    let lo = [0, 1].map(|a| {
        uv.iter()
            .flatten()
            .map(|p| p[a])
            .fold(f64::INFINITY, f64::min)
    });
    let mut seen: BTreeMap<(i64, i64), usize> = BTreeMap::new();
    for (k, t) in uv.iter().enumerate() {
        let t = &t.map(|p| [p[0] - lo[0], p[1] - lo[1]]);
        let lo = |a: usize| t.iter().map(|p| p[a]).fold(f64::INFINITY, f64::min);
        let hi = |a: usize| t.iter().map(|p| p[a]).fold(f64::NEG_INFINITY, f64::max);
        for y in (lo(1) - 0.5).floor() as i64..=(hi(1) - 0.5).ceil() as i64 {
            for x in (lo(0) - 0.5).floor() as i64..=(hi(0) - 0.5).ceil() as i64 {
                let c = [x as f64 + 0.5, y as f64 + 0.5];
                if bary2(t, c).is_some_and(|b| b.iter().all(|v| *v > 1e-7)) {
                    if let Some(other) = seen.insert((x, y), k) {
                        if other != k {
                            return true;
                        }
                    }
                }
            }
        }
    }
    false
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 12 outward-wound triangles of the box `[lo, hi]`.
    pub(crate) fn cube(lo: [f64; 3], hi: [f64; 3]) -> Vec<[[f64; 3]; 3]> {
        let c = |i: usize| [0, 1, 2].map(|k| if i >> k & 1 == 0 { lo[k] } else { hi[k] });
        lightfarm_proto::testing::BOX_QUADS
            .iter()
            .flat_map(|q| [[c(q[0]), c(q[1]), c(q[2])], [c(q[0]), c(q[2]), c(q[3])]])
            .collect()
    }

    fn overlap_area_positive(a: &[[f64; 2]; 3], b: &[[f64; 2]; 3]) -> bool {
        // Separating axis over both triangles' edge normals, shrunk by a tolerance.
        let mut axes = Vec::new();
        for t in [a, b] {
            for (i, j) in [(0, 1), (1, 2), (2, 0)] {
                axes.push([t[i][1] - t[j][1], t[j][0] - t[i][0]]);
            }
        }
        axes.iter().all(|ax| {
            let l = (ax[0] * ax[0] + ax[1] * ax[1]).sqrt();
            let proj = |t: &[[f64; 2]; 3]| {
                let v = t.map(|p| (p[0] * ax[0] + p[1] * ax[1]) / l);
                (
                    v.iter().copied().fold(f64::INFINITY, f64::min),
                    v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
                )
            };
            let (pa, pb) = (proj(a), proj(b));
            pa.1.min(pb.1) - pa.0.max(pb.0) > 1e-6
        })
    }

    #[test]
    fn mesh_box_gets_texels_at_the_density_of_its_longest_side() {
        let t = 6;
        let tris = cube([1.0, 0.0, 1.0], [2.0, 1.2, 2.0]);
        let h = 1.2 / t as f64;
        let atlas = MeshAtlas::build("clutter \"c\"", &tris, None, h).unwrap();
        assert_eq!(atlas.source, AtlasSource::Generated);
        assert_eq!(atlas.n_charts, 6);
        // h = 1.2 m / 6 = 0.2 m: the four 1.0 × 1.2 m sides get 5 × 6 texels, the two
        // 1.0 × 1.0 m caps 5 × 5 (a cube gets T × T on every face, as a box).
        assert_eq!(atlas.texels.len(), 4 * 30 + 2 * 25);
        for texel in &atlas.texels {
            assert!((texel.area - h * h).abs() < 1e-12, "{}", texel.area);
        }
    }

    #[test]
    fn generated_atlas_covers_every_triangle_without_overlap_and_is_deterministic() {
        // A cube, a sliver 1 µm wide, a fan of slanted triangles (a tent) and a lone triangle.
        let mut tris = cube([0.0, 0.0, 0.0], [1.0, 1.0, 1.0]);
        tris.push([[2.0, 0.0, 0.0], [3.0, 0.0, 0.0], [2.5, 0.000001, 0.0]]);
        tris.push([[0.0, 2.0, 0.0], [1.0, 2.5, 0.0], [0.0, 2.0, 1.0]]);
        tris.push([[1.0, 2.5, 0.0], [1.0, 2.5, 1.0], [0.0, 2.0, 1.0]]);
        tris.push([[1.0, 2.5, 0.0], [2.0, 2.0, 0.0], [1.0, 2.5, 1.0]]);
        tris.push([[2.0, 2.0, 0.0], [2.0, 2.0, 1.0], [1.0, 2.5, 1.0]]);
        tris.push([[-1.0, -1.0, 3.0], [-0.2, -1.0, 3.1], [-1.0, -0.3, 2.5]]);
        let h = 0.1;
        let atlas = MeshAtlas::build("clutter \"m\"", &tris, None, h).unwrap();
        let again = MeshAtlas::build("clutter \"m\"", &tris, None, h).unwrap();
        assert_eq!(atlas.texels, again.texels);
        assert_eq!(atlas.triangle_uv, again.triangle_uv);
        // Every triangle has a texel; every texel lies inside the atlas.
        for k in 0..tris.len() {
            assert!(
                !atlas.triangle_texels(k).is_empty(),
                "triangle {k} has no texel"
            );
        }
        for t in &atlas.texels {
            assert!(t.x < atlas.width && t.y < atlas.height);
            assert!(t.position.iter().chain(&t.normal).all(|x| x.is_finite()));
        }
        // Triangles of different charts never overlap in the atlas, and no texel serves two
        // charts (the gutter).
        for a in 0..tris.len() {
            for b in a + 1..tris.len() {
                if atlas.triangle_chart[a] != atlas.triangle_chart[b] {
                    assert!(
                        !overlap_area_positive(&atlas.triangle_uv[a], &atlas.triangle_uv[b]),
                        "triangles {a} and {b} overlap"
                    );
                    let ta = atlas.triangle_texels(a);
                    assert!(atlas.triangle_texels(b).iter().all(|x| !ta.contains(x)));
                }
            }
        }
        // Within a chart, triangles meet only along edges.
        for a in 0..tris.len() {
            for b in a + 1..tris.len() {
                if atlas.triangle_chart[a] == atlas.triangle_chart[b] {
                    assert!(!overlap_area_positive(
                        &atlas.triangle_uv[a],
                        &atlas.triangle_uv[b]
                    ));
                }
            }
        }
        // The sliver (1 m long, 1 µm wide) gets the 10 texels it crosses, all its own.
        let sliver = atlas.triangle_texels(12);
        assert_eq!(sliver.len(), 10);
        assert!(sliver
            .iter()
            .all(|t| atlas.texels[*t as usize].triangle == 12));
    }

    #[test]
    fn hits_map_back_to_the_texel_they_land_in() {
        let tris = cube([0.0, 0.0, 0.0], [1.0, 0.7, 1.3]);
        let h = 1.3 / 8.0;
        let atlas = MeshAtlas::build("clutter \"c\"", &tris, None, h).unwrap();
        // A texel's own centre maps to itself.
        for (k, t) in atlas.texels.iter().enumerate() {
            assert_eq!(atlas.texel_at(t.triangle as usize, t.position), k);
        }
        // Any point on a triangle lands in the texel whose square holds its UV, within half a
        // texel diagonal of the texel centre's world position (faces are flat).
        for (k, tri) in tris.iter().enumerate() {
            for (a, b) in [(0.2, 0.3), (0.6, 0.1), (0.05, 0.9), (0.33, 0.33)] {
                let p: [f64; 3] = std::array::from_fn(|i| {
                    (1.0 - a - b) * tri[0][i] + a * tri[1][i] + b * tri[2][i]
                });
                let texel = &atlas.texels[atlas.texel_at(k, p)];
                let uv = atlas.triangle_uv[k];
                let q: [f64; 2] =
                    std::array::from_fn(|i| (1.0 - a - b) * uv[0][i] + a * uv[1][i] + b * uv[2][i]);
                assert_eq!(
                    (texel.x, texel.y),
                    (q[0].floor() as u32, q[1].floor() as u32)
                );
                let d = DVec3::from(texel.position).distance(DVec3::from(p));
                assert!(d <= h * 0.5f64.sqrt() * (1.0 + 1e-9), "{d} > half diagonal");
            }
        }
    }

    #[test]
    fn lightmap_uvs_place_texels_where_they_say() {
        // A 2 m square in y = 0 with u along z and v along x (not the generated frame).
        let p = |x: f64, z: f64| [x, 0.0, z];
        let tris = vec![
            [p(0.0, 0.0), p(0.0, 2.0), p(2.0, 2.0)],
            [p(0.0, 0.0), p(2.0, 2.0), p(2.0, 0.0)],
        ];
        let uv = |x: f64, z: f64| [z / 2.0, x / 2.0];
        let uvs = vec![
            [uv(0.0, 0.0), uv(0.0, 2.0), uv(2.0, 2.0)],
            [uv(0.0, 0.0), uv(2.0, 2.0), uv(2.0, 0.0)],
        ];
        let atlas = MeshAtlas::build("clutter \"q\"", &tris, Some(&uvs), 0.25).unwrap();
        assert_eq!(atlas.source, AtlasSource::Texcoord1);
        assert_eq!((atlas.width, atlas.height), (8, 8));
        assert_eq!(atlas.texels.len(), 64);
        for t in &atlas.texels {
            let want = [(t.y as f64 + 0.5) * 0.25, 0.0, (t.x as f64 + 0.5) * 0.25];
            assert!(
                DVec3::from(t.position).distance(DVec3::from(want)) < 1e-12,
                "{:?} vs {want:?}",
                t.position
            );
        }
        let bad = vec![[[0.0, 0.0], [1.5, 0.0], [0.0, 1.0]]; 2];
        let err = MeshAtlas::build("clutter \"q\"", &tris, Some(&bad), 0.25).unwrap_err();
        assert!(
            err.to_string()
                .starts_with("clutter \"q\": TEXCOORD_1 of triangle 0"),
            "{err}"
        );
    }

    #[test]
    fn closed_pieces_are_found_and_oriented() {
        let mut tris = cube([0.0; 3], [1.0; 3]);
        let (pieces, volumes) = closed_pieces(&tris);
        assert!(pieces.iter().all(|p| *p == (0, true)));
        assert!((volumes[0] - 1.0).abs() < 1e-12);
        for t in tris.iter_mut() {
            t.swap(1, 2);
        }
        tris.push([[3.0, 0.0, 0.0], [4.0, 0.0, 0.0], [3.0, 1.0, 0.0]]);
        let (pieces, volumes) = closed_pieces(&tris);
        assert!((volumes[0] + 1.0).abs() < 1e-12);
        assert_eq!(pieces[12], (1, false));
    }
}
