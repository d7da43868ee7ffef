#!/usr/bin/env python3
"""Trace the rays `lightfarm bench` exported against the same triangles with Embree (embreex).

  scripts/embree_throughput.py DIR

DIR holds (written by `lightfarm bench`): triangles.f32 (n x 3 x 3 little-endian f32),
rays.f32 (m x 6: origin, unit direction) and obvhs_t.f32 (m: our closest-hit distance, inf on
a miss). Prints one JSON line: Embree's closest-hit rays/s (best of --repeats runs of
EmbreeScene.run over all rays, primitive ids only; embreex traces one ray at a time on one
thread), the BVH build time, and the fraction of rays whose hit distance agrees with ours.
Exits with status 3 when embreex is not installed (`pip install embreex`).
"""
import argparse, json, sys, time

try:
    import numpy as np
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh
except ImportError as e:  # the caller reports this as "not measured"
    print(json.dumps({"error": f"embreex not available: {e}"}))
    sys.exit(3)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('dir')
    ap.add_argument('--repeats', type=int, default=3)
    a = ap.parse_args()
    triangles = np.fromfile(f'{a.dir}/triangles.f32', dtype='<f4').reshape(-1, 3, 3)
    rays = np.fromfile(f'{a.dir}/rays.f32', dtype='<f4').reshape(-1, 6)
    ours = np.fromfile(f'{a.dir}/obvhs_t.f32', dtype='<f4')
    origins = np.ascontiguousarray(rays[:, :3])
    directions = np.ascontiguousarray(rays[:, 3:])
    start = time.perf_counter()
    scene = rtcs.EmbreeScene()
    TriangleMesh(scene, triangles)
    scene.run(origins[:1], directions[:1])  # commits the scene (builds the BVH)
    build = time.perf_counter() - start
    best = float('inf')
    for _ in range(a.repeats):
        start = time.perf_counter()
        scene.run(origins, directions)
        best = min(best, time.perf_counter() - start)
    hits = scene.run(origins, directions, output=1)
    t = np.where(hits['primID'] >= 0, hits['tfar'], np.inf)
    both_miss = np.isinf(t) & np.isinf(ours)
    both_hit = np.isfinite(t) & np.isfinite(ours)
    close = both_hit & (np.abs(t - ours) <= 1e-3 * np.maximum(1.0, np.abs(ours)))
    print(json.dumps({
        "rays": int(len(rays)),
        "triangles": int(len(triangles)),
        "rays_per_second": len(rays) / best,
        "seconds": best,
        "build_seconds": build,
        "agreement": float((both_miss | close).mean()),
        "embree_hits": int(np.isfinite(t).sum()),
    }))


if __name__ == '__main__':
    main()
