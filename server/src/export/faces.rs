//! The rectangles of a box surface (a block's closed faces, a clutter box's six faces) rebuilt
//! from its texels: a face is a run of consecutive texels with one axis-aligned normal, laid out
//! `j·n_u + i` with `i` along the first tangent axis `u` and `j` along `v` (ascending world
//! axes other than the normal's, `lightfarm_proto::Face`), each texel `texel_size` = `[s_u, s_v]`.
//!
//! Invariant: a returned face covers exactly its texels: its rectangle is the texel centres'
//! extent grown by half a texel, so texel `(i, j)`'s centre sits at `(i + ½, j + ½)` texels
//! from the face's `(min_u, min_v)` corner.

use lightfarm_proto::bundle::Layout;
use lightfarm_proto::face::tangent_axes;

/// One axis-aligned face of a surface.
#[derive(Clone, Debug, PartialEq)]
pub struct BoxFace {
    /// Global index of texel `(0, 0)`.
    pub first_texel: usize,
    /// World axis of the normal (0 = x, 1 = y, 2 = z) and its sign.
    pub axis: usize,
    pub normal_sign: f32,
    /// The plane's coordinate along `axis` (metres).
    pub coord: f32,
    /// Tangent axes, ascending.
    pub u: usize,
    pub v: usize,
    pub n_u: usize,
    pub n_v: usize,
    /// Extent along `u` and `v` (metres).
    pub min: [f32; 2],
    pub max: [f32; 2],
}

impl BoxFace {
    /// The world position of face point `(a, b)` in `[0, 1]²` (fractions along `u`, `v`).
    pub fn point(&self, a: f32, b: f32) -> [f32; 3] {
        let mut p = [0.0f32; 3];
        p[self.axis] = self.coord;
        p[self.u] = self.min[0] + a * (self.max[0] - self.min[0]);
        p[self.v] = self.min[1] + b * (self.max[1] - self.min[1]);
        p
    }

    pub fn normal(&self) -> [f32; 3] {
        let mut n = [0.0f32; 3];
        n[self.axis] = self.normal_sign;
        n
    }
}

fn dominant_axis(n: [f32; 3]) -> usize {
    (0..3)
        .max_by(|&a, &b| n[a].abs().total_cmp(&n[b].abs()))
        .expect("three axes")
}

/// The faces of the `count` texels from `offset`; an error naming what does not fit.
pub fn box_faces(layout: &Layout, offset: usize, count: usize) -> Result<Vec<BoxFace>, String> {
    let end = offset + count;
    if end > layout.positions.len() || end > layout.normals.len() || end > layout.texel_size.len() {
        return Err(format!("texels {offset}..{end} lie outside the layout"));
    }
    let same = |a: [f32; 3], b: [f32; 3]| (0..3).all(|c| (a[c] - b[c]).abs() < 1e-4);
    let mut faces = Vec::new();
    let mut start = offset;
    while start < end {
        let normal = layout.normals[start];
        let mut stop = start + 1;
        while stop < end && same(layout.normals[stop], normal) {
            stop += 1;
        }
        let axis = dominant_axis(normal);
        if (normal[axis].abs() - 1.0).abs() > 1e-3 {
            return Err(format!(
                "texel {} has normal {normal:?}, not along an axis",
                start - offset
            ));
        }
        let (u, v) = tangent_axes(axis);
        let size = layout.texel_size[start];
        let first = layout.positions[start];
        let n_u = (start..stop)
            .take_while(|&t| (layout.positions[t][v] - first[v]).abs() < 0.25 * size[1])
            .count();
        let len = stop - start;
        if n_u == 0 || len % n_u != 0 {
            return Err(format!(
                "the {len} texels from {} do not form rows of equal length",
                start - offset
            ));
        }
        let n_v = len / n_u;
        let last_u = layout.positions[start + n_u - 1][u];
        let last_v = layout.positions[start + (n_v - 1) * n_u][v];
        faces.push(BoxFace {
            first_texel: start,
            axis,
            normal_sign: normal[axis].signum(),
            coord: first[axis],
            u,
            v,
            n_u,
            n_v,
            min: [first[u] - 0.5 * size[0], first[v] - 0.5 * size[1]],
            max: [last_u + 0.5 * size[0], last_v + 0.5 * size[1]],
        });
        start = stop;
    }
    Ok(faces)
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::bundle::SurfaceInfo;

    /// A 3×2 face on the floor (y = 0, normal +y) with 0.5 × 0.25 m texels, then a 2×2 face at
    /// x = 4 facing −x: both are found with their extents, and every texel centre sits at the
    /// (i + ½, j + ½) point of its face.
    #[test]
    fn rebuilds_faces_from_texel_centres() {
        let mut layout = Layout::default();
        let mut push = |p: [f32; 3], n: [f32; 3], s: [f32; 2]| {
            layout.positions.push(p);
            layout.normals.push(n);
            layout.texel_size.push(s);
        };
        for j in 0..2 {
            for i in 0..3 {
                let p = [
                    1.0 + 0.5 * (i as f32 + 0.5),
                    0.0,
                    2.0 + 0.25 * (j as f32 + 0.5),
                ];
                push(p, [0.0, 1.0, 0.0], [0.5, 0.25]);
            }
        }
        for j in 0..2 {
            for i in 0..2 {
                push(
                    [4.0, i as f32 + 0.5, j as f32 + 0.5],
                    [-1.0, 0.0, 0.0],
                    [1.0, 1.0],
                );
            }
        }
        layout.surfaces.push(SurfaceInfo {
            name: "block:a".into(),
            texel_offset: 0,
            texel_count: 10,
        });
        let faces = box_faces(&layout, 0, 10).unwrap();
        assert_eq!(faces.len(), 2);
        let floor = &faces[0];
        assert_eq!(
            (floor.axis, floor.u, floor.v, floor.n_u, floor.n_v),
            (1, 0, 2, 3, 2)
        );
        assert_eq!((floor.min, floor.max), ([1.0, 2.0], [2.5, 2.5]));
        assert_eq!(floor.normal(), [0.0, 1.0, 0.0]);
        let wall = &faces[1];
        assert_eq!(
            (wall.axis, wall.normal_sign, wall.first_texel),
            (0, -1.0, 6)
        );
        assert_eq!(
            (wall.min, wall.max, wall.coord),
            ([0.0, 0.0], [2.0, 2.0], 4.0)
        );
        for face in &faces {
            for j in 0..face.n_v {
                for i in 0..face.n_u {
                    let a = (i as f32 + 0.5) / face.n_u as f32;
                    let b = (j as f32 + 0.5) / face.n_v as f32;
                    let p = face.point(a, b);
                    let t = layout.positions[face.first_texel + j * face.n_u + i];
                    assert!((0..3).all(|c| (p[c] - t[c]).abs() < 1e-6), "{p:?} vs {t:?}");
                }
            }
        }
        // Rows of unequal length are refused by texel.
        let err = box_faces(&layout, 0, 5).unwrap_err();
        assert!(err.contains("rows of equal length"), "{err}");
    }
}
