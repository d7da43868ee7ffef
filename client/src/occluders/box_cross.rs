//! What one primitive does to every shadow segment from a box of points to a light
//! ([`Occluders::prim_crosses_box_segments`]): crosses none, crosses each, or maybe — the
//! classification `box_shadows` runs per occluder of a light buffer's cells toward a run of
//! texels. Module [`crate::box_shadows`] says why each answer is exact to the f32 per-ray test.
//!
//! Units: metres, world frame; the box and the light in f64 (the light given in f32, as the
//! rays use it).

use super::tree::Prim;
use lightfarm_proto::face::tangent_axes;

use super::{Occluders, EPS_SCALE, T_EPS_REL};

/// [`Occluders::prim_crosses_box_segments`]'s slack on positions, relative to the largest
/// coordinate or the scale: a hundred times the f32 test's rounding.
const BOX_SLACK_REL: f64 = 1e-5;
/// [`Occluders::prim_crosses_box_segments`]'s slack on segment parameters (the f32 test rounds `t`
/// to a few 1e-7).
const BOX_T_SLACK: f64 = 1e-5;

/// The shadow segments from a box to a light ([`Occluders::box_segments`]): the light and the
/// box in f64, whether all are finite, the slack on positions and the box's distance to the
/// light.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BoxSegments {
    l: [f64; 3],
    lo: [f64; 3],
    hi: [f64; 3],
    finite: bool,
    slack: f64,
    len_min: f64,
}

/// What one primitive does to a box's shadow segments ([`Occluders::prim_crosses_box_segments`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BoxCross {
    /// It crosses none of them.
    Never,
    /// It crosses every one.
    Every,
    /// Some, or it cannot tell.
    Maybe,
}

/// Distance from `p` to the closed box `[lo, hi]` (0 inside).
fn box_distance(p: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
    (0..3)
        .map(|k| {
            let gap = (lo[k] - p[k]).max(p[k] - hi[k]).max(0.0);
            gap * gap
        })
        .sum::<f64>()
        .sqrt()
}

impl Occluders {
    /// [`Occluders::prim_crosses_box_segments`] of one box (the form the tests use).
    #[cfg(test)]
    pub(crate) fn prim_crosses_from_box(
        &self,
        i: usize,
        light: [f32; 3],
        lo: [f64; 3],
        hi: [f64; 3],
    ) -> BoxCross {
        self.prim_crosses_box_segments(i, &self.box_segments(light, lo, hi))
    }

    /// The segments from the box `[lo, hi]` to `light`, prepared for
    /// [`Occluders::prim_crosses_box_segments`] (what the tests of every primitive share).
    pub(crate) fn box_segments(&self, light: [f32; 3], lo: [f64; 3], hi: [f64; 3]) -> BoxSegments {
        let l = light.map(f64::from);
        let finite = l.iter().chain(&lo).chain(&hi).all(|x| x.is_finite());
        // Slack for the f32 test's rounding: coordinates and the scale set its size.
        let mag = (0..3).fold(self.scale as f64, |m, k| {
            m.max(l[k].abs()).max(lo[k].abs()).max(hi[k].abs())
        });
        BoxSegments {
            l,
            lo,
            hi,
            finite,
            slack: BOX_SLACK_REL * mag,
            len_min: if finite {
                box_distance(l, lo, hi)
            } else {
                f64::NAN
            },
        }
    }

    /// What primitive `i` does to every segment [`Occluders::occluded`] tests from a point of
    /// the box `[lo, hi]` to `light` (prepared by [`Occluders::box_segments`], once for all the
    /// primitives a box query tests; module [`crate::box_shadows`] says why each answer is
    /// exact to the f32 test): [`BoxCross::Never`] when it crosses none, [`BoxCross::Every`]
    /// when it crosses each one, else [`BoxCross::Maybe`]. Conservative: `Maybe` is always a
    /// correct answer, and a non-finite box or light gets it.
    pub(crate) fn prim_crosses_box_segments(&self, i: usize, b: &BoxSegments) -> BoxCross {
        let BoxSegments {
            l,
            lo,
            hi,
            finite,
            slack,
            len_min,
        } = *b;
        if !finite {
            return BoxCross::Maybe;
        }
        match *self.prim(i) {
            Prim::Rect {
                axis,
                coord,
                min,
                max,
            } => {
                let a = axis as usize;
                let c = coord as f64;
                // The plane is not strictly between the light and any point: the f32 test's
                // `t = (c − o_a) / (l_a − o_a)` is ≤ 0, ≥ 1 or not taken (`d_a = 0`), for a
                // difference of f32 values keeps its sign and rounding keeps their order.
                if (l[a] >= c && lo[a] >= c) || (l[a] <= c && hi[a] <= c) {
                    return BoxCross::Never;
                }
                if !((l[a] < c && lo[a] > c) || (l[a] > c && hi[a] < c)) {
                    return BoxCross::Maybe;
                }
                // Every segment crosses the plane: where, is the central projection from the
                // light of the box onto it, inside the box around its corners' projections.
                // A corner's projection along tangent k takes `s` from its coordinate along
                // the normal and its own coordinate along k: the eight corners give, per
                // tangent, the four pairs of (lo or hi along a, lo or hi along k), two
                // divisions in all.
                let (u, v) = tangent_axes(axis as usize);
                let (mut plo, mut phi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
                for pa in [lo[a], hi[a]] {
                    let s = (c - l[a]) / (pa - l[a]);
                    for (j, k) in [u, v].into_iter().enumerate() {
                        for pk in [lo[k], hi[k]] {
                            let x = l[k] + s * (pk - l[k]);
                            plo[j] = plo[j].min(x);
                            phi[j] = phi[j].max(x);
                        }
                    }
                }
                let (rmin, rmax) = (min.map(f64::from), max.map(f64::from));
                if (0..2).any(|j| phi[j] < rmin[j] - slack || plo[j] > rmax[j] + slack) {
                    return BoxCross::Never;
                }
                if !(0..2).all(|j| plo[j] > rmin[j] + slack && phi[j] < rmax[j] - slack) {
                    return BoxCross::Maybe;
                }
                // Inside the rect everywhere: a hit when `t` is inside the segment's open
                // interval, whose margin is widest for the shortest segment.
                let t_at = |oa: f64| (c - oa) / (l[a] - oa);
                let (t0, t1) = (t_at(lo[a]), t_at(hi[a]));
                if len_min.is_nan() || len_min <= 0.0 {
                    return BoxCross::Maybe;
                }
                let eps = T_EPS_REL as f64 + EPS_SCALE as f64 * self.scale as f64 / len_min;
                let margin = eps * (1.0 + BOX_T_SLACK) + BOX_T_SLACK;
                if t0.min(t1) > margin && t0.max(t1) < 1.0 - margin {
                    BoxCross::Every
                } else {
                    BoxCross::Maybe
                }
            }
            Prim::Tri(p) => {
                // Only the plane: the light and the whole box strictly on one side of it, by
                // more than the test's rounding, put the line's crossing outside the segment.
                let p = p.map(|q| q.map(f64::from));
                let e1 = [0, 1, 2].map(|k| p[1][k] - p[0][k]);
                let e2 = [0, 1, 2].map(|k| p[2][k] - p[0][k]);
                let n = [
                    e1[1] * e2[2] - e1[2] * e2[1],
                    e1[2] * e2[0] - e1[0] * e2[2],
                    e1[0] * e2[1] - e1[1] * e2[0],
                ];
                let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                if !norm.is_finite() || norm <= 0.0 {
                    return BoxCross::Maybe;
                }
                let side = |q: [f64; 3]| {
                    ((q[0] - p[0][0]) * n[0] + (q[1] - p[0][1]) * n[1] + (q[2] - p[0][2]) * n[2])
                        / norm
                };
                let sl = side(l);
                if sl.is_nan() || sl.abs() <= slack {
                    return BoxCross::Maybe;
                }
                let all_with_light = (0..8).all(|corner| {
                    let q = [0, 1, 2].map(|k| if corner >> k & 1 == 0 { lo[k] } else { hi[k] });
                    side(q) * sl.signum() > slack
                });
                if all_with_light {
                    BoxCross::Never
                } else {
                    BoxCross::Maybe
                }
            }
        }
    }
}
