#!/usr/bin/env python3
"""Multi-bounce accuracy figures behind tests/data/multibounce_accuracy.md.

For each scene: bake once at T texels per face (with the dense operator, for `full`), draw N
seeded light sets (1-4 point lights inside random blocks, clear of walls and clutter), trace an
all-bounce reference per light set (`lightfarm reference --bounces all`, every K-th texel), and
evaluate full, mrt and drt at one bounce and at all bounces (`lightfarm eval --bounces 1|all`)
against it (`lightfarm compare`). Prints a markdown table (mean and worst relative L2 over the
light sets) and the iterations `eval` reports.

Usage: scripts/multibounce_accuracy.py [--lightfarm target/release/lightfarm] [--out DIR]
       [--sets 10] [--rays 16384] [--texels 8] [--seed 1] [--set KEY=VALUE ...]
       [SCENE[:STRIDE] ...]
`--set` overrides a bake setting (JSON value, e.g. `--set tolerance=1e-4`); the bundles go to
their own folder, the references (which do not depend on bake settings) are shared.
Default scenes: cornell:1 corridor:2 maze:4 (maze with its four pillars).
"""

import argparse
import json
import random
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
WALL = 0.3  # metres a light keeps from every wall and clutter box


def light_sets(scene, seed, count):
    """`count` seeded LIGHTS.json dicts for `scene`."""
    rng = random.Random(seed)
    boxes = [c["box"] for c in scene.get("clutter", []) if "box" in c]

    def clear(p):
        return all(
            any(p[k] < b["min"][k] - WALL or p[k] > b["max"][k] + WALL for k in range(3))
            for b in boxes
        )

    def point():
        block = rng.choice(scene["blocks"])
        return [
            rng.uniform(block["min"][k] + WALL, block["max"][k] - WALL)
            if block["max"][k] - block["min"][k] > 2 * WALL
            else 0.5 * (block["min"][k] + block["max"][k])
            for k in range(3)
        ]

    sets = []
    for _ in range(count):
        lights = []
        for _ in range(rng.randint(1, 4)):
            p = point()
            for _ in range(1000):
                if clear(p):
                    break
                p = point()
            base = rng.uniform(2.0, 20.0)
            lights.append(
                {
                    "kind": "point",
                    "position": p,
                    "intensity": [base * rng.uniform(0.8, 1.0) for _ in range(3)],
                }
            )
        sets.append({"lights": lights, "poses": []})
    return sets


def run(cmd):
    out = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return out.stdout + out.stderr


def rel_l2(lightfarm, ours, reference):
    text = run([lightfarm, "compare", str(ours), str(reference)])
    m = re.search(r"relative[_ ]l2[=: ]+([0-9.eE+-]+)", text)
    if not m:
        sys.exit(f"cannot read the relative L2 from: {text}")
    return float(m.group(1))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--lightfarm", default=str(ROOT / "target/release/lightfarm"))
    ap.add_argument("--out", default="/tmp/lightfarm-multibounce")
    ap.add_argument("--sets", type=int, default=10)
    ap.add_argument("--rays", type=int, default=16384)
    ap.add_argument("--texels", type=int, default=8)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("scenes", nargs="*", default=["cornell:1", "corridor:2", "maze:4"])
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for spec in a.scenes:
        name, _, stride = spec.partition(":")
        stride = stride or "1"
        scene = json.loads((ROOT / "scenes" / name / "scene.json").read_text())
        scene["settings"]["texels_per_face"] = a.texels
        refs = out / name
        refs.mkdir(exist_ok=True)
        scene_path = refs / "scene.json"
        scene_path.write_text(json.dumps(scene, indent=1))
        overrides = [kv.split("=", 1) for kv in a.set]
        work = refs / "+".join(f"{k}={v}" for k, v in overrides) if overrides else refs
        work.mkdir(exist_ok=True)
        baked_scene = work / "scene.json"
        for key, value in overrides:
            scene["settings"][key] = json.loads(value)
        baked_scene.write_text(json.dumps(scene, indent=1))
        bundle = work / "bundle.lfb"
        if not bundle.exists():
            t = time.time()
            run([a.lightfarm, "bake", str(baked_scene), "--out", str(bundle), "--full",
                 "--no-cache", "--quiet"])
            print(f"{name}: baked in {time.time() - t:.0f} s, {bundle.stat().st_size} bytes",
                  file=sys.stderr)
        errors = {}
        iterations = []
        for k, lights in enumerate(light_sets(scene, a.seed * 1000 + k0(name), a.sets)):
            lp = refs / f"lights_{k}.json"
            lp.write_text(json.dumps(lights, indent=1))
            ref = refs / f"reference_{k}.json"
            if not ref.exists():
                t = time.time()
                run([a.lightfarm, "reference", str(scene_path), "--lights", str(lp),
                     "--rays", str(a.rays), "--bounces", "all", "--texel-stride", stride,
                     "--out", str(ref)])
                print(f"{name} set {k}: reference in {time.time() - t:.0f} s", file=sys.stderr)
            for method in ["full", "mrt", "drt"]:
                for bounces in ["1", "all"]:
                    res = work / f"{method}_{bounces}_{k}.json"
                    text = run([a.lightfarm, "eval", str(bundle), "--lights", str(lp),
                                "--method", method, "--bounces", bounces, "--out", str(res)])
                    m = re.search(r"bounces: (?:all, )?(\d+) applied", text)
                    if bounces == "all" and m:
                        iterations.append(int(m.group(1)))
                    errors.setdefault((method, bounces), []).append(rel_l2(a.lightfarm, res, ref))
        for (method, bounces), e in sorted(errors.items()):
            rows.append((name, method, "one" if bounces == "1" else "all", statistics.mean(e),
                         max(e), len(e)))
        rows.append((name, "iterations", "all", statistics.mean(iterations) if iterations else
                     float("nan"), max(iterations, default=0), len(iterations)))
    print(f"| scene | method | bounces | mean rel. L2 vs all-bounce reference | worst | light sets |")
    print("|---|---|---|---|---|---|")
    for name, method, bounces, mean, worst, n in rows:
        if method == "iterations":
            print(f"| {name} | (Converged iterations) | all | {mean:.1f} | {worst} | {n} |")
        else:
            print(f"| {name} | {method} | {bounces} | {mean:.4f} | {worst:.4f} | {n} |")


def k0(name):
    return sum(ord(c) for c in name)


if __name__ == "__main__":
    main()
