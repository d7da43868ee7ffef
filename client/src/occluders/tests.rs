//! Tests of the occluders: the hierarchy and the box answers against brute force, and the
//! seeded fixtures other modules' tests share.

use super::*;
use lightfarm_proto::face::tangent_axes;

/// A fixed-seed linear congruential generator (no `rand` in this crate).
pub(crate) use lightfarm_proto::testing::Lcg;

/// Random rects and triangles in a 10 m box (seeded).
pub(crate) fn random_scene(
    rng: &mut Lcg,
    n_rects: usize,
    n_tris: usize,
) -> (Vec<Rect>, Vec<[[f32; 3]; 3]>) {
    let rects = (0..n_rects)
        .map(|_| {
            let (a, b) = (rng.range(-5.0, 5.0), rng.range(-5.0, 5.0));
            let (w, h) = (rng.range(0.0, 2.0), rng.range(0.0, 2.0));
            Rect {
                axis: (rng.next_u32() % 3) as u8,
                coord: rng.range(-5.0, 5.0),
                min: [a, b],
                max: [a + w, b + h],
            }
        })
        .collect();
    let tris = (0..n_tris)
        .map(|_| {
            let c = rng.point(-5.0, 5.0);
            let p = |rng: &mut Lcg| {
                let o = rng.point(-1.0, 1.0);
                [c[0] + o[0], c[1] + o[1], c[2] + o[2]]
            };
            [p(rng), p(rng), p(rng)]
        })
        .collect();
    (rects, tris)
}

/// [`random_scene`] with every fourth rect a wall 3-8 m across, which hides whole boxes.
pub(crate) fn scene_with_walls(
    rng: &mut Lcg,
    n_rects: usize,
    n_tris: usize,
) -> (Vec<Rect>, Vec<[[f32; 3]; 3]>) {
    let (mut rects, tris) = random_scene(rng, n_rects, n_tris);
    for r in rects.iter_mut().step_by(4) {
        r.max = [
            r.min[0] + rng.range(3.0, 8.0),
            r.min[1] + rng.range(3.0, 8.0),
        ];
    }
    (rects, tris)
}

/// A random box with f32 corners (so its corners are points a texel can have): half of
/// them flat on a rect's plane, inside it or across its edge (a texel on a wall), the rest
/// solid, from a centimetre to a metre.
pub(crate) fn random_box(rng: &mut Lcg, rects: &[Rect]) -> ([f32; 3], [f32; 3]) {
    let size = rng.range(0.01, 1.0);
    let mut lo = rng.point(-5.0, 5.0);
    let mut hi = [0.0; 3];
    for k in 0..3 {
        hi[k] = lo[k] + rng.range(0.0, size);
    }
    if rng.next_u32() % 2 == 0 && !rects.is_empty() {
        let r = &rects[rng.next_u32() as usize % rects.len()];
        let (u, v) = tangent_axes(r.axis as usize);
        let a = r.axis as usize;
        lo[a] = r.coord;
        hi[a] = r.coord;
        lo[u] = rng.range(r.min[0] - 0.2, r.max[0]);
        lo[v] = rng.range(r.min[1] - 0.2, r.max[1]);
        hi[u] = lo[u] + rng.range(0.0, size);
        hi[v] = lo[v] + rng.range(0.0, size);
    }
    (lo, hi)
}

/// Points of the f32 box `[lo, hi]`: its eight corners and random ones inside.
pub(crate) fn points_in(rng: &mut Lcg, lo: [f32; 3], hi: [f32; 3], n: usize) -> Vec<[f32; 3]> {
    let corners =
        (0..8).map(|c: u32| [0, 1, 2].map(|k| if c >> k & 1 == 0 { lo[k] } else { hi[k] }));
    let inside = (0..n).map(|_| {
        [0, 1, 2].map(|k| (lo[k] + rng.range(0.0, 1.0) * (hi[k] - lo[k])).clamp(lo[k], hi[k]))
    });
    corners.chain(inside).collect()
}

/// Where `prim_crosses_from_box` says a primitive crosses no segment from the box to the
/// light, or every one, the per-segment test agrees at every point tried (the corners and
/// random points), with lights anywhere, on rects' planes and on boxes' faces; and both
/// answers occur often.
#[test]
fn box_answers_hold_at_every_point_of_the_box() {
    let mut rng = Lcg(0xb0c5_5eed);
    let (mut never, mut every, mut maybe) = (0usize, 0usize, 0usize);
    for case in 0..40 {
        let (rects, tris) = scene_with_walls(&mut rng, 30, 10);
        let occ = Occluders::new(&rects, &tris);
        for round in 0..25 {
            let (lo, hi) = random_box(&mut rng, &rects);
            let mut light = rng.point(-6.0, 6.0);
            match round % 5 {
                // On a rect's plane, and on the box's own plane.
                0 => {
                    let r = &rects[rng.next_u32() as usize % rects.len()];
                    light[r.axis as usize] = r.coord;
                }
                1 => {
                    let k = rng.next_u32() as usize % 3;
                    light[k] = lo[k];
                }
                _ => {}
            }
            let points = points_in(&mut rng, lo, hi, 24);
            let (blo, bhi) = (lo.map(f64::from), hi.map(f64::from));
            for i in 0..occ.len() {
                let verdict = occ.prim_crosses_from_box(i, light, blo, bhi);
                match verdict {
                    BoxCross::Never => never += 1,
                    BoxCross::Every => every += 1,
                    BoxCross::Maybe => {
                        maybe += 1;
                        continue;
                    }
                }
                for p in &points {
                    let hit = occ
                        .shadow_segment(*p, light)
                        .is_some_and(|seg| occ.prim_crosses(i, &seg));
                    assert_eq!(
                        hit,
                        verdict == BoxCross::Every,
                        "case {case}.{round}: prim {i} {verdict:?}, point {p:?}, light {light:?}"
                    );
                }
            }
        }
    }
    assert!(
        never > 10 * every && every > 100 && maybe > 100,
        "{never} {every} {maybe}"
    );
}

#[test]
fn bvh_matches_brute_force_on_random_scenes() {
    let mut rng = Lcg(0x5eed_1234);
    let mut hits = 0;
    let mut total = 0;
    for scene in 0..40 {
        let (rects, tris) = random_scene(&mut rng, scene * 3, (scene * 7) % 50);
        let occ = Occluders::new(&rects, &tris);
        assert_eq!(occ.len(), rects.len() + tris.len());
        for _ in 0..400 {
            let o = rng.point(-6.0, 6.0);
            let t = rng.point(-6.0, 6.0);
            let got = occ.occluded(o, t);
            assert_eq!(
                got,
                occ.occluded_brute(o, t),
                "scene {scene}: {o:?} → {t:?}"
            );
            hits += got as usize;
            total += 1;
        }
        // Segments that start on a primitive (texel-like origins) and axis-parallel ones.
        for r in &rects {
            let (u, v) = tangent_axes(r.axis as usize);
            let mut o = [0.0; 3];
            o[r.axis as usize] = r.coord;
            o[u] = rng.range(r.min[0], r.max[0]);
            o[v] = rng.range(r.min[1], r.max[1]);
            let mut t = rng.point(-6.0, 6.0);
            assert_eq!(occ.occluded(o, t), occ.occluded_brute(o, t));
            t = o;
            t[(rng.next_u32() % 3) as usize] += rng.range(-8.0, 8.0);
            assert_eq!(occ.occluded(o, t), occ.occluded_brute(o, t));
        }
    }
    // The test is only meaningful if both answers occur often.
    assert!(
        hits > total / 10 && hits < total * 9 / 10,
        "{hits} of {total}"
    );
}

/// Leaving one object's triangles out ([`Occluders::occluded_except`] over every object
/// numbered, [`Occluders::with_objects_triangles`]) answers what occluders made with the
/// other objects' triangles alone answer, for every object, segments through and from
/// inside the objects included.
#[test]
fn leaving_one_object_out_answers_what_the_others_alone_answer() {
    let mut rng = Lcg(0x0b_1ec7);
    let (mut differ, mut total) = (0, 0);
    for scene in 0..12 {
        let (rects, tris) = random_scene(&mut rng, 8 + scene, 36);
        let (level_tris, posed) = tris.split_at(6);
        let level = Occluders::new(&rects, level_tris);
        // Five objects of six triangles each, in order.
        let owners: Vec<u32> = (0..posed.len() as u32).map(|k| k / 6).collect();
        let all = level.with_objects_triangles(posed, &owners);
        assert_eq!(all.len(), level.len() + posed.len());
        for object in 0..5u32 {
            let others: Vec<_> = (posed.iter().zip(&owners))
                .filter(|&(_, &o)| o != object)
                .map(|(t, _)| *t)
                .collect();
            let want_from = level.with_triangles(&others);
            for _ in 0..150 {
                // From a vertex of the object half the time: a ray leaving its surface.
                let o = if rng.next_u32().is_multiple_of(2) {
                    posed[(object as usize) * 6][0]
                } else {
                    rng.point(-6.0, 6.0)
                };
                let t = rng.point(-6.0, 6.0);
                let got = all.occluded_except(o, t, object);
                assert_eq!(
                    got,
                    want_from.occluded(o, t),
                    "scene {scene} object {object}"
                );
                differ += (got != all.occluded(o, t)) as usize;
                total += 1;
            }
        }
        // An object no triangle has leaves nothing out.
        for _ in 0..50 {
            let (o, t) = (rng.point(-6.0, 6.0), rng.point(-6.0, 6.0));
            assert_eq!(all.occluded_except(o, t, 99), all.occluded(o, t));
        }
    }
    assert!(
        differ * 200 > total,
        "the object's own triangles matter: {differ}/{total}"
    );
}

/// Triangles added in a hierarchy of their own ([`Occluders::with_triangles`], twice, as
/// objects placed in two calls) answer every segment as one hierarchy over all the
/// primitives does, keep the level's scale and numbers, and find the same primitives in a
/// box.
#[test]
fn triangles_in_a_second_hierarchy_answer_what_one_hierarchy_answers() {
    let mut rng = Lcg(0x2_1e7e1);
    let (mut hits, mut total) = (0, 0);
    for scene in 0..20 {
        let (rects, tris) = random_scene(&mut rng, 10 + scene * 3, 40);
        let (level_tris, posed) = tris.split_at(10);
        let (first, second) = posed.split_at(scene % 30);
        let level = Occluders::new(&rects, level_tris);
        let two = level.with_triangles(first).with_triangles(second);
        // One hierarchy over all of them, with the level's margins.
        let one = two.subset(&(0..two.len() as u32).collect::<Vec<_>>());
        assert_eq!(two.len(), one.len());
        assert_eq!(two.len(), rects.len() + tris.len());
        assert_eq!(two.scale(), level.scale());
        assert_eq!(two.bounds(), Occluders::new(&rects, &tris).bounds());
        for i in 0..level.len() {
            assert_eq!(
                two.prim_bounds(i),
                level.prim_bounds(i),
                "the level's numbers"
            );
        }
        for _ in 0..400 {
            let (o, t) = (rng.point(-6.0, 6.0), rng.point(-6.0, 6.0));
            let got = two.occluded(o, t);
            assert_eq!(
                got,
                two.occluded_brute(o, t),
                "scene {scene}: {o:?} → {t:?}"
            );
            assert_eq!(got, one.occluded(o, t), "scene {scene}: {o:?} → {t:?}");
            hits += got as usize;
            total += 1;
        }
        let (lo, hi) = random_box(&mut rng, &rects);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        two.prims_in_box(lo, hi, &mut a);
        one.prims_in_box(lo, hi, &mut b);
        assert_eq!(a.len(), b.len(), "scene {scene}");
        assert!(a.iter().all(|&i| (i as usize) < two.len()));
    }
    assert!(
        hits > total / 10 && hits < total * 9 / 10,
        "{hits} of {total}"
    );
}

#[test]
fn build_is_a_proper_tree() {
    let mut rng = Lcg(7);
    let (rects, tris) = random_scene(&mut rng, 300, 300);
    let occ = Occluders::new(&rects, &tris);
    let mut seen = vec![0u32; occ.level.prims.len()];
    for n in &occ.level.nodes {
        if n.count > 0 {
            assert!(n.count as usize <= LEAF_SIZE);
            for s in &mut seen[n.first as usize..(n.first + n.count) as usize] {
                *s += 1;
            }
        }
    }
    assert!(
        seen.iter().all(|&s| s == 1),
        "every primitive in exactly one leaf"
    );
}

#[test]
fn empty_scene_never_occludes() {
    let occ = Occluders::new(&[], &[]);
    assert!(occ.is_empty());
    assert!(!occ.occluded([0.0; 3], [1.0, 2.0, 3.0]));
}

/// A 4 m room: floor z = 0 and ceiling z = 4, walls at x = 0 and x = 4.
fn room() -> Occluders {
    let wall = |axis, coord| Rect {
        axis,
        coord,
        min: [0.0, 0.0],
        max: [4.0, 4.0],
    };
    Occluders::new(
        &[wall(2, 0.0), wall(2, 4.0), wall(0, 0.0), wall(0, 4.0)],
        &[],
    )
}

#[test]
fn ray_leaving_a_wall_texel_does_not_hit_the_wall() {
    let occ = room();
    // Texel centres on the floor and the wall, light inside the room.
    assert!(!occ.occluded([1.3, 2.1, 0.0], [2.0, 2.0, 3.0]));
    assert!(!occ.occluded([0.0, 1.7, 2.9], [3.0, 2.0, 1.0]));
    // Grazing, but still leaving the floor.
    assert!(!occ.occluded([0.1, 2.0, 0.0], [3.9, 2.0, 0.05]));
}

#[test]
fn light_near_or_on_a_surface_still_lights() {
    let occ = room();
    // On the ceiling, and a hair below it.
    assert!(!occ.occluded([1.0, 1.0, 0.0], [2.0, 2.0, 4.0]));
    assert!(!occ.occluded([1.0, 1.0, 0.0], [2.0, 2.0, 4.0 - 1e-5]));
    // A hair inside the ceiling (the light's own surface is within the end margin).
    assert!(!occ.occluded([1.0, 1.0, 0.0], [2.0, 2.0, 4.0 + 1e-5]));
    // ...but a light clearly beyond the ceiling is shadowed.
    assert!(occ.occluded([1.0, 1.0, 0.0], [2.0, 2.0, 4.1]));
    // Near the wall the texel is on.
    assert!(!occ.occluded([0.0, 1.0, 1.0], [1e-4, 2.0, 2.0]));
}

#[test]
fn a_blocker_between_occludes() {
    let mut rects = vec![Rect {
        axis: 2,
        coord: 2.0,
        min: [1.0, 1.0],
        max: [3.0, 3.0],
    }];
    let occ = Occluders::new(&rects, &[]);
    assert!(occ.occluded([2.0, 2.0, 0.0], [2.0, 2.0, 4.0]));
    assert!(!occ.occluded([0.5, 2.0, 0.0], [0.5, 2.0, 4.0]));
    assert!(
        !occ.occluded([2.0, 2.0, 0.0], [2.0, 2.0, 1.5]),
        "blocker beyond the target"
    );
    // Inclusive edges: two rects sharing the edge x = 2 leave no crack.
    rects = vec![
        Rect {
            axis: 2,
            coord: 2.0,
            min: [1.0, 1.0],
            max: [2.0, 3.0],
        },
        Rect {
            axis: 2,
            coord: 2.0,
            min: [2.0, 1.0],
            max: [3.0, 3.0],
        },
    ];
    let occ = Occluders::new(&rects, &[]);
    assert!(occ.occluded([2.0, 2.0, 0.0], [2.0, 2.0, 4.0]));
    assert!(occ.occluded([1.0, 2.0, 0.0], [3.0, 2.0, 4.0]));
    // Edge of a lone rect counts too.
    let occ = Occluders::new(&rects[..1], &[]);
    assert!(occ.occluded([1.0, 1.0, 0.0], [1.0, 1.0, 4.0]));
}

#[test]
fn triangles_occlude() {
    let tri = [[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 2.0, 1.0]];
    let occ = Occluders::new(&[], &[tri]);
    assert!(occ.occluded([0.5, 0.5, 0.0], [0.5, 0.5, 2.0]));
    assert!(
        occ.occluded([0.5, 0.5, 2.0], [0.5, 0.5, 0.0]),
        "either winding"
    );
    assert!(
        !occ.occluded([1.5, 1.5, 0.0], [1.5, 1.5, 2.0]),
        "outside the hypotenuse"
    );
    assert!(
        !occ.occluded([0.5, 0.5, 0.0], [0.5, 0.5, 0.9]),
        "stops short"
    );
    // A shared edge between two triangles has no crack (the diagonal x + y = 2).
    let other = [[2.0, 0.0, 1.0], [2.0, 2.0, 1.0], [0.0, 2.0, 1.0]];
    let occ = Occluders::new(&[], &[tri, other]);
    assert!(occ.occluded([1.0, 1.0, 0.0], [1.0, 1.0, 2.0]));
}
