//! A block's shape operators from its canonical shape's, when the block is a rotation or mirror
//! image of it (`ShapeSpec::canonical`): texels renumbered by the box symmetry, and each
//! opening's lightfield cells and direction bins likewise.
//!
//! With `g` taking the block's frame to the canonical one, `σ` (block texel → canonical texel,
//! `BoxSymmetry::texel_permutation`) and per block opening `f` the lightfield permutation `π_f`
//! (block index → index on the canonical opening `g(f)`, [`lightfield_permutation`]):
//! `U_b[x] = U_b^c[σ(x)]`, `L_imp[x] = L_imp^c[σ(x)]`, `T_d→b[:, x] = T_d→b^c[:, σ(x)]`,
//! `U_r,f[x] = U_r^c[σ(x)]`, `W_f[:, i] = W^c[:, π_f(i)]`, `OutImp_f[i] = OutImp^c[π_f(i)]` and
//! `Pass_{f'→f}[i, j] = Pass^c[π_f(i), π_f'(j)]`. These are the canonical estimate's operators
//! exactly, renumbered; the mode coefficients `b` mean the same in both frames, so the bundle
//! ships the canonical `U_b`, `T_d→b` once with the block's symmetry and the client permutes at
//! load (`lightfarm_proto::bundle::BlockSymmetry`).
//!
//! An instance stores what the stages after the propagation read per block: `U_b`, `L_imp`
//! and `U_r` ([`instance_operators`]). The propagation, which runs before the instances are
//! made, reads its `Pass` alone ([`instance_passes`]); the bundle ships the canonical `T_d→b`
//! and `Pass`, which no stage reads per block. `W` and `OutImp`, which only the transport's propagation reads and which are most of a
//! shape's bytes, are renumbered on use ([`InstanceLightfield`]), so a level's memory holds
//! them once per canonical shape rather than once per (shape, symmetry).
//!
//! Lightfield indices permute like texels because a frame bins positions on the opening's
//! ascending tangent axes and directions by the inverse concentric map of their tangent
//! components, which commutes with the square's reflections and its diagonal swap (tested on
//! rays below). Invariant: called only with `g` from `ShapeSpec::canonical` of the block's spec,
//! so every block opening has a canonical opening and every block texel a canonical texel.

use crate::bake::math::matrix::widen;

use faer::Mat;

use lightfarm_proto::box_symmetry::BoxSymmetry;
use lightfarm_proto::Face;

use crate::bake::mrt::shape::{
    OpeningLightfield, OpeningOperators, ShapeLightfields, ShapeOperators, ShapeSpec, Triplets,
};

/// Per lightfield index of the block's opening `face`, the index on the canonical opening
/// `g.map_face(face)` (`cells × cells` positions × `dirs × dirs` bins, index layout of
/// `LightfieldFrame::index`).
pub fn lightfield_permutation(g: BoxSymmetry, face: Face, cells: usize, dirs: usize) -> Vec<u32> {
    let map = g.grid_map(face);
    let d2 = dirs * dirs;
    let mut out = Vec::with_capacity(cells * cells * d2);
    for cell in 0..cells * cells {
        let image_cell = map.apply_index(cell, cells);
        for bin in 0..d2 {
            out.push((image_cell * d2 + map.apply_index(bin, dirs)) as u32);
        }
    }
    out
}

fn inverse_permutation(p: &[u32]) -> Vec<u32> {
    let mut inv = vec![0u32; p.len()];
    for (i, &j) in p.iter().enumerate() {
        inv[j as usize] = i as u32;
    }
    inv
}

/// One opening of a block as the lightfield propagation reads it: its face and its `Pass`
/// operators, in the block's frame.
pub struct OpeningPasses {
    pub face: Face,
    /// Incoming lightfield at `from` → outgoing lightfield here (LF × LF), as
    /// [`OpeningOperators::pass_from`].
    pub pass_from: Vec<(Face, Triplets)>,
}

/// The openings (ascending by face) of the block with spec `block`, which `g` takes onto
/// `canonical`'s shape, with their `Pass` operators renumbered (the propagation reads nothing
/// else of a block), in the order [`instance_operators`] lists the openings.
pub fn instance_passes(
    canonical: &ShapeOperators,
    block: &ShapeSpec,
    g: BoxSymmetry,
) -> Vec<OpeningPasses> {
    let (cells, dirs) = (block.lightfield_cells, block.lightfield_directions);
    let inverse = g.inverse();
    // Per block opening: its face and π⁻¹.
    let inverses: Vec<(Face, Vec<u32>)> = block
        .open
        .iter()
        .map(|f| {
            let pi = lightfield_permutation(g, *f, cells, dirs);
            (*f, inverse_permutation(&pi))
        })
        .collect();
    let inverse_at = |f: Face| {
        &inverses
            .iter()
            .find(|(b, _)| *b == f)
            .expect("every canonical opening is a block opening")
            .1
    };
    let mut openings: Vec<OpeningPasses> = block
        .open
        .iter()
        .map(|f| {
            let o = canonical
                .opening(g.map_face(*f))
                .expect("the canonical shape has the block's openings");
            let inv_here = inverse_at(*f);
            let pass_from = o
                .pass_from
                .iter()
                .map(|(from_c, triplets)| {
                    let from_b = inverse.map_face(*from_c);
                    let inv_from = inverse_at(from_b);
                    let mut mapped: Triplets = triplets
                        .iter()
                        .map(|&(r, c, v)| (inv_here[r as usize], inv_from[c as usize], v))
                        .collect();
                    mapped.sort_by_key(|&(r, c, _)| (r, c));
                    (from_b, mapped)
                })
                .collect();
            OpeningPasses {
                face: *f,
                pass_from,
            }
        })
        .collect();
    openings.sort_by_key(|o| o.face);
    openings
}

/// The operators of the block with spec `block`, which `g` takes onto `canonical`'s shape, as
/// the stages after the propagation read them: `U_b`, `L_imp` and each opening's `U_r`
/// renumbered. Its `T_d→b` is empty (0 × 0) and its openings carry no `Pass`: no stage reads
/// them per block (the bundle ships the canonical shape's, the propagation reads
/// [`instance_passes`]), and at 1,000 blocks they were half of the instances' bytes.
pub fn instance_operators(
    canonical: &ShapeOperators,
    block: &ShapeSpec,
    g: BoxSymmetry,
) -> ShapeOperators {
    let sigma = g.texel_permutation(&block.closed(), block.texels_per_face);
    let rows_of =
        |m: &Mat<f64>| Mat::from_fn(m.nrows(), m.ncols(), |x, k| m[(sigma[x] as usize, k)]);
    let mut faces = block.open.clone();
    faces.sort();
    let openings = faces
        .into_iter()
        .map(|face| {
            let c = canonical
                .opening(g.map_face(face))
                .expect("the canonical shape has the block's openings");
            OpeningOperators {
                face,
                u_r: rows_of(&c.u_r),
                pass_from: Vec::new(),
                lightfield: None,
            }
        })
        .collect();
    ShapeOperators {
        key: g.instance_key(&canonical.key),
        u_b: rows_of(&canonical.u_b),
        t_db: Mat::new(),
        l_imp: rows_of(&canonical.l_imp),
        openings,
        stats: canonical.stats.clone(),
    }
}

/// One block's openings' `OutImp` and `W` seen through its symmetry, renumbered from its
/// canonical shape's on use (borrowed as they are for a block in the canonical orientation).
/// The values are the canonical's exactly, so the propagation reads the same numbers as from
/// stored instance operators.
pub struct InstanceLightfield<'a> {
    /// Per block opening: its face, the canonical opening's lightfield, and `π_f` (None for
    /// the identity).
    openings: Vec<(Face, &'a OpeningLightfield, Option<Vec<u32>>)>,
}

impl<'a> InstanceLightfield<'a> {
    /// The block with spec `block`, which `g` takes onto the shape whose lightfields are
    /// `canonical` (same invariant as [`instance_operators`]).
    pub fn new(
        canonical: &'a ShapeLightfields,
        block: &ShapeSpec,
        g: BoxSymmetry,
    ) -> InstanceLightfield<'a> {
        let (cells, dirs) = (block.lightfield_cells, block.lightfield_directions);
        let openings = block
            .open
            .iter()
            .map(|f| {
                let image = g.map_face(*f);
                let (_, lightfield) = canonical
                    .iter()
                    .find(|(face, _)| *face == image)
                    .expect("the canonical shape has the block's openings");
                let pi = (!g.is_identity()).then(|| lightfield_permutation(g, *f, cells, dirs));
                (*f, lightfield, pi)
            })
            .collect();
        InstanceLightfield { openings }
    }

    fn of(&self, face: Face) -> Option<(&'a OpeningLightfield, Option<&[u32]>)> {
        self.openings
            .iter()
            .find(|(f, _, _)| *f == face)
            .map(|(_, l, pi)| (*l, pi.as_deref()))
    }

    /// `OutImp_f` (LF × r) of the block's opening `face` in f64, if it has one.
    pub fn out_imp(&self, face: Face) -> Option<Mat<f64>> {
        self.of(face).map(|(l, pi)| {
            let m = &l.out_imp;
            match pi {
                None => widen(m),
                Some(pi) => Mat::from_fn(m.nrows(), m.ncols(), |i, k| {
                    f64::from(m[(pi[i] as usize, k)])
                }),
            }
        })
    }

    /// `W_f` (q × LF) of the block's opening `face` in f64, if it has one.
    pub fn w(&self, face: Face) -> Option<Mat<f64>> {
        self.of(face).map(|(l, pi)| {
            let m = &l.w;
            match pi {
                None => widen(m),
                Some(pi) => Mat::from_fn(m.nrows(), m.ncols(), |j, i| {
                    f64::from(m[(j, pi[i] as usize)])
                }),
            }
        })
    }

    /// The lightfield's length (LF) at the block's opening `face`, if it has one.
    pub fn len(&self, face: Face) -> Option<usize> {
        self.of(face).map(|(l, _)| l.out_imp.nrows())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::math::sampling::sobol_2d;
    use crate::bake::mrt::shape::bake_shape;
    use lightfarm_proto::scene::Settings;

    fn spec(extent: [f64; 3], open: &[Face]) -> ShapeSpec {
        let settings = Settings {
            texels_per_face: 4,
            rays_per_texel: 256,
            tolerance: 0.01,
            lightfield_cells: 2,
            lightfield_directions: 3,
            prior_lights: 48,
            ..Settings::default()
        };
        let aabb = lightfarm_proto::scene::Aabb {
            min: [0.0; 3],
            max: extent,
        };
        ShapeSpec::for_block(&aabb, open, &settings, &[])
    }

    #[test]
    fn lightfield_indices_permute_like_the_rays_they_bin() {
        let block = spec([2.0, 3.0, 5.0], &[Face::NegX, Face::PosY, Face::PosZ]);
        for g in BoxSymmetry::all() {
            let canonical = block.transformed(g);
            for &face in &block.open {
                for outgoing in [false, true] {
                    let fb = block.frame(face, outgoing);
                    let fc = canonical.frame(g.map_face(face), outgoing);
                    let pi = lightfield_permutation(g, face, fb.cells, fb.dirs);
                    for index in 0..fb.len() {
                        for i in 0..8 {
                            let (p, w) = fb.sample(
                                index,
                                sobol_2d(index as u64 + 1, i),
                                sobol_2d(77 + index as u64, i),
                            );
                            let q = g.map_point(p, block.extent);
                            let v = g.map_direction(w);
                            assert_eq!(
                                fc.index(q, v),
                                pi[index] as usize,
                                "{g:?} {face} outgoing={outgoing} index {index}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn canonical_specs_agree_across_an_orbit() {
        let block = spec([2.0, 3.0, 4.0], &[Face::NegX, Face::PosZ]);
        let (canonical, g) = block.canonical();
        for h in BoxSymmetry::all() {
            let (c, k) = block.transformed(h).canonical();
            assert_eq!(c.key(), canonical.key(), "{h:?}");
            // k ∘ h and g take the block to the same canonical spec.
            assert_eq!(block.transformed(h).transformed(k).key(), c.key());
        }
        assert_eq!(block.transformed(g).key(), canonical.key());
    }

    /// A block baked directly and the same block instanced from its canonical shape estimate
    /// the same geometry: per texel, the fraction of its cosine rays leaving through each
    /// opening (row sums of `U_r W ≈ In`), and per lightfield cell and bin, the flux arriving
    /// there from all texels (column sums). Both agree within the Monte Carlo noise of 512 rays
    /// per texel, which checks the texel and the lightfield permutations against independent
    /// rays; the instanced opening operators carry exactly the canonical ones' energy.
    #[test]
    fn instanced_operators_match_a_direct_bake() {
        // A rotation of the shape that is not its own canonical member.
        let shape = spec([2.0, 3.0, 4.0], &[Face::NegX, Face::PosZ]);
        let block = BoxSymmetry::all()
            .map(|h| shape.transformed(h))
            .find(|b| !b.canonical().1.is_identity())
            .expect("some orientation is not canonical");
        let (canonical_spec, g) = block.canonical();
        let block = ShapeSpec {
            rays_per_texel: 512,
            ..block
        };
        let canonical_spec = ShapeSpec {
            rays_per_texel: 512,
            ..canonical_spec
        };
        let mut direct = bake_shape(&block, &|_| {}).unwrap();
        let mut canonical = bake_shape(&canonical_spec, &|_| {}).unwrap();
        let inst = instance_operators(&canonical, &block, g);
        let direct_lightfields = direct.take_lightfields();
        let canonical_lightfields = canonical.take_lightfields();
        let inst_lightfield = InstanceLightfield::new(&canonical_lightfields, &block, g);
        let direct_lightfield =
            InstanceLightfield::new(&direct_lightfields, &block, BoxSymmetry::IDENTITY);
        let relative = |a: &[f64], b: &[f64]| {
            let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
            let n: f64 = a.iter().map(|x| x * x).sum();
            (d / n).sqrt()
        };
        for face in &block.open {
            let (o, d) = (inst.opening(*face).unwrap(), direct.opening(*face).unwrap());
            assert!(o.lightfield.is_none(), "instances store no lightfield");
            let (a, b) = (
                &o.u_r * inst_lightfield.w(*face).unwrap().as_ref(),
                &d.u_r * direct_lightfield.w(*face).unwrap().as_ref(),
            );
            let rows = |m: &Mat<f64>| -> Vec<f64> {
                (0..m.nrows())
                    .map(|i| (0..m.ncols()).map(|j| m[(i, j)]).sum())
                    .collect()
            };
            let cols = |m: &Mat<f64>| -> Vec<f64> {
                (0..m.ncols())
                    .map(|j| (0..m.nrows()).map(|i| m[(i, j)]).sum())
                    .collect()
            };
            let per_texel = relative(&rows(&a), &rows(&b));
            let per_bin = relative(&cols(&a), &cols(&b));
            assert!(
                per_texel < 0.06,
                "{face}: per-texel escape differs by {per_texel}"
            );
            assert!(per_bin < 0.06, "{face}: per-bin flux differs by {per_bin}");
            let (_, oc) = canonical_lightfields
                .iter()
                .find(|(f, _)| *f == g.map_face(*face))
                .unwrap();
            // A permutation: the same values, summed in another order.
            let same = |a: f64, b: f64| (a - b).abs() <= 1e-12 * b.abs();
            let out_imp = inst_lightfield.out_imp(*face).unwrap();
            assert!(same(out_imp.norm_l2(), widen(&oc.out_imp).norm_l2()));
            assert!(same(
                inst_lightfield.w(*face).unwrap().norm_l2(),
                widen(&oc.w).norm_l2()
            ));
            assert_eq!(inst_lightfield.len(*face), Some(oc.out_imp.nrows()));
        }
    }

    /// Scaling a shape never changes the orientation chosen as canonical, even when its extents
    /// come out of `max − min` with another rounding at another scale.
    #[test]
    fn the_canonical_orientation_does_not_depend_on_scale() {
        let shape = spec([3.0, 3.0, 4.0], &[Face::NegX, Face::PosZ]);
        for h in BoxSymmetry::all() {
            let block = shape.transformed(h);
            let g = block.canonical().1;
            for s in [0.0025, 0.01, 3.0, 2500.0] {
                // A block from 4s to 7s along x: 7s − 4s is not always 3s in floating point.
                let scaled = ShapeSpec {
                    extent: block
                        .extent
                        .map(|e| if e == 3.0 { 7.0 * s - 4.0 * s } else { e * s }),
                    ..block.clone()
                };
                assert_eq!(scaled.canonical().1, g, "{h:?} × {s}");
            }
        }
    }
}
