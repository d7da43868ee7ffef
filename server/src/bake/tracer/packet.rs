//! Four triangles of one BVH leaf tested against one ray at once: the tracer's f32 triangle
//! test ([`super::Tracer`]'s `classify`) in structure-of-arrays lanes (glam's `Vec4`, an
//! `__m128` on x86-64), so a leaf's triangles cost one test instead of one each.
//!
//! The lanes compute what the one-triangle test computes, in the same order and with the same
//! margins, so each lane's verdict is that test's for the same `far`. Unused lanes (a leaf with
//! fewer than four triangles left) are masked out, never reported.
//!
//! Frames: world metres, f32 (vertex 0 and both edges rounded from f64, as the one-triangle
//! copy holds them).

use glam::{Vec3A, Vec4};

use super::F32_MARGIN;

/// One triangle's f32 copy for the test: vertex 0, the two edges from it (computed in f64,
/// then rounded) and their lengths.
#[derive(Clone, Copy, Debug)]
pub(super) struct FastTriangle {
    pub v0: Vec3A,
    pub e1: Vec3A,
    pub e2: Vec3A,
    pub len1: f32,
    pub len2: f32,
}

/// Up to four triangles: vertex 0, the edges from it and their lengths, per lane.
#[derive(Clone, Copy, Debug)]
pub(super) struct TrianglePacket {
    v0: [Vec4; 3],
    e1: [Vec4; 3],
    e2: [Vec4; 3],
    len1: Vec4,
    len2: Vec4,
    /// BVH slot of each lane.
    pub slots: [u32; 4],
    /// Bit `i` set when lane `i` holds a triangle.
    pub valid: u32,
}

/// What the packet's test says per lane (bit masks over lanes, and the lanes' f32 distance and
/// its margin). A lane in neither mask is a sure hit.
pub(super) struct PacketVerdict {
    pub miss: u32,
    pub unsure: u32,
    /// Lanes the ray nearly parallels (within `unsure`: their distance means nothing).
    pub parallel: u32,
    pub t: [f32; 4],
    pub margin: [f32; 4],
}

impl TrianglePacket {
    /// A packet of `lanes` (at most four): each triangle with its BVH slot.
    pub fn new(lanes: &[(u32, FastTriangle)]) -> TrianglePacket {
        assert!(lanes.len() <= 4, "a packet holds four triangles");
        let mut p = TrianglePacket {
            v0: [Vec4::ZERO; 3],
            e1: [Vec4::ZERO; 3],
            e2: [Vec4::ZERO; 3],
            len1: Vec4::ZERO,
            len2: Vec4::ZERO,
            slots: [0; 4],
            valid: 0,
        };
        for (lane, &(slot, t)) in lanes.iter().enumerate() {
            for k in 0..3 {
                p.v0[k][lane] = t.v0[k];
                p.e1[k][lane] = t.e1[k];
                p.e2[k][lane] = t.e2[k];
            }
            p.len1[lane] = t.len1;
            p.len2[lane] = t.len2;
            p.slots[lane] = slot;
            p.valid |= 1 << lane;
        }
        p
    }

    /// The test of every lane against `o + t·d` for `epsilon < t < far`, at the scene scale
    /// `s`; see the tracer's module doc for the margins.
    #[inline(always)]
    pub fn classify(&self, o: Vec3A, d: Vec3A, epsilon: f32, far: f32, s: f32) -> PacketVerdict {
        let [dx, dy, dz] = [d.x, d.y, d.z].map(Vec4::splat);
        let [e1x, e1y, e1z] = self.e1;
        let [e2x, e2y, e2z] = self.e2;
        // p = d × e2, det = e1 · p.
        let px = dy * e2z - dz * e2y;
        let py = dz * e2x - dx * e2z;
        let pz = dx * e2y - dy * e2x;
        let det = e1x * px + e1y * py + e1z * pz;
        let inv = Vec4::ONE / det;
        let svx = Vec4::splat(o.x) - self.v0[0];
        let svy = Vec4::splat(o.y) - self.v0[1];
        let svz = Vec4::splat(o.z) - self.v0[2];
        let a = (svx * px + svy * py + svz * pz) * inv;
        // q = sv × e1.
        let qx = svy * e1z - svz * e1y;
        let qy = svz * e1x - svx * e1z;
        let qz = svx * e1y - svy * e1x;
        let b = (dx * qx + dy * qy + dz * qz) * inv;
        let t = (e2x * qx + e2y * qy + e2z * qz) * inv;
        let bound = Vec4::splat(3.0 * s) * self.len1.max(self.len2) * inv.abs();
        let margin = Vec4::splat(F32_MARGIN);
        let m = margin * (bound + Vec4::ONE);
        let mt = margin * (bound * self.len2 + t.abs() + Vec4::splat(s));
        let parallel = !det
            .abs()
            .cmpgt(Vec4::splat(1e-3) * self.len1 * self.len2)
            .bitmask()
            & self.valid;
        let (eps, one) = (Vec4::splat(epsilon), Vec4::ONE);
        let two_m = m + m;
        let outside = t.cmplt(eps - mt).bitmask()
            | t.cmpgt(Vec4::splat(far) + mt).bitmask()
            | a.cmplt(-m).bitmask()
            | a.cmpgt(one + m).bitmask()
            | b.cmplt(-m).bitmask()
            | (a + b).cmpgt(one + two_m).bitmask();
        let miss = (outside & !parallel & self.valid) | !self.valid & 0xF;
        let doubtful = a.cmplt(m).bitmask()
            | b.cmplt(m).bitmask()
            | (a + b).cmpgt(one - two_m).bitmask()
            | t.cmple(eps + mt).bitmask();
        let unsure = (parallel | doubtful) & !miss & 0xF;
        PacketVerdict {
            miss,
            unsure,
            parallel,
            t: t.to_array(),
            margin: mt.to_array(),
        }
    }
}
