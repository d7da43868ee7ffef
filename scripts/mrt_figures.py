#!/usr/bin/env python3
"""Measure MRT against the brute-force reference over seeded random light sets.

  scripts/mrt_figures.py SCENE.json [--sets 10] [--rays 16384] [--seed 1] [--out DIR] [--no-clutter]

For one scene: bakes (lightfield transport with the dense operator, then traced transport),
draws `--sets` random light sets (1-4 point lights inside random blocks, 0.25 m from the
walls, 2-20 W/sr), runs the reference at `--rays` rays per texel for each, applies full,
mrt-lightfield and mrt-traced through `lightfarm eval` and prints the mean `compare` figures,
bake times and eval times. Uses target/release/lightfarm (build it first).
"""
import argparse, json, os, random, re, subprocess, sys, time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LF = os.path.join(ROOT, 'target', 'release', 'lightfarm')


STAGES = []


def run(args):
    t = time.time()
    out = subprocess.run([LF] + args, check=True, capture_output=True, text=True)
    for line in out.stderr.splitlines():
        if line.startswith('stages:') or line.startswith('baked') or line.startswith('drt:'):
            STAGES.append(' '.join(args[:1]) + ' ' + ' '.join(a for a in args if a in ('lightfield', 'traced')) + ': ' + line)
    return out.stdout, time.time() - t


def random_lights(scene, rng):
    lights = []
    boxes = [c['box'] for c in scene.get('clutter', []) if 'box' in c]
    def clear(p):  # not inside (or within 0.25 m of) a clutter box
        return all(any(p[k] < b['min'][k] - 0.25 or p[k] > b['max'][k] + 0.25 for k in range(3)) for b in boxes)
    for _ in range(rng.randint(1, 4)):
        while True:
            b = rng.choice(scene['blocks'])
            pos = [rng.uniform(b['min'][k] + 0.25, b['max'][k] - 0.25) for k in range(3)]
            if clear(pos):
                break
        base = rng.uniform(2, 20)
        lights.append({"kind": "point", "position": pos, "intensity": [base * rng.uniform(0.8, 1.0) for _ in range(3)]})
    return {"lights": lights, "poses": []}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('scene'); ap.add_argument('--sets', type=int, default=10)
    ap.add_argument('--rays', type=int, default=16384); ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--out', default='/tmp/lf-figures'); ap.add_argument('--no-clutter', action='store_true')
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    scene = json.load(open(a.scene))
    name = scene['name'] + ('-noclutter' if a.no_clutter else '')
    if a.no_clutter:
        scene['clutter'] = []
    # Mesh paths stay relative to the original scene directory.
    scene_path = os.path.join(os.path.dirname(os.path.abspath(a.scene)), f'.{name}.figures.json')
    json.dump(scene, open(scene_path, 'w'))
    cache = os.path.join(a.out, 'cache')
    lf_bundle = os.path.join(a.out, f'{name}-lightfield.lfb'); tr_bundle = os.path.join(a.out, f'{name}-traced.lfb')
    out, t_lf = run(['bake', scene_path, '-o', lf_bundle, '--no-cache', '--full', '--transport', 'lightfield'])
    bytes_lf = int(re.search(r'bytes=(\d+)', out).group(1))
    out, t_tr = run(['bake', scene_path, '-o', tr_bundle, '--cache', cache, '--transport', 'traced'])
    out, t_tr_cached = run(['bake', scene_path, '-o', tr_bundle, '--cache', cache, '--transport', 'traced'])
    bytes_tr = int(re.search(r'bytes=(\d+)', out).group(1))
    out, t_lf_only = run(['bake', scene_path, '-o', lf_bundle + '.nofull', '--no-cache', '--transport', 'lightfield'])
    bytes_lf_only = int(re.search(r'bytes=(\d+)', out).group(1))
    methods = [('full', lf_bundle, 'full'), ('mrt-lightfield', lf_bundle, 'mrt'), ('mrt-traced', tr_bundle, 'mrt')]
    if scene.get('clutter'):
        face = dict(scene); face['settings'] = dict(scene.get('settings', {}), clutter_basis='face_constant')
        face_path = scene_path + '.face.json'
        json.dump(face, open(face_path, 'w'))
        face_bundle = os.path.join(a.out, f'{name}-face.lfb')
        run(['bake', face_path, '-o', face_bundle, '--cache', cache, '--transport', 'lightfield'])
        os.remove(face_path)
        methods += [('drt-lightfield', lf_bundle, 'drt'), ('drt-traced', tr_bundle, 'drt'), ('drt-face-constant', face_bundle, 'drt')]
    rng = random.Random(a.seed)
    sums = {}
    evals = {}
    t_ref = 0.0
    for k in range(a.sets):
        lights = os.path.join(a.out, f'{name}-lights{k}.json')
        json.dump(random_lights(scene, rng), open(lights, 'w'))
        ref = os.path.join(a.out, f'{name}-ref{k}.json')
        _, t = run(['reference', scene_path, '--lights', lights, '--rays', str(a.rays), '-o', ref]); t_ref += t
        for label, bundle, method in methods:
            res = os.path.join(a.out, f'{name}-{label}{k}.json')
            _, t = run(['eval', bundle, '--lights', lights, '--method', method, '-o', res])
            evals.setdefault(label, []).append(t)
            filters = [('all', [])]
            if scene.get('clutter'):
                # --scene leaves out block texels buried inside clutter boxes (never seen).
                filters = [('all', ['--scene', scene_path]), ('scene', ['--only', 'block:', '--scene', scene_path]),
                           ('near1m', ['--scene', scene_path, '--near-clutter', '1.0']), ('clutter', ['--only', 'clutter:'])]
            for fname, extra in filters:
                try:
                    out, _ = run(['compare', res, ref] + extra)
                except subprocess.CalledProcessError:
                    continue  # no texels after the filter (e.g. mrt has no clutter texels)
                m = re.search(r'relative_l2=([\d.eE+-]+) p95=([\d.eE+-]+)', out.strip().splitlines()[-1])
                s = sums.setdefault((label, fname), [0.0, 0.0, 0]); s[0] += float(m.group(1)); s[1] += float(m.group(2)); s[2] += 1
        print(f'set {k}: ' + ' '.join(f'{l}/{f}={v[0] / v[2]:.4f}' for (l, f), v in sums.items()), file=sys.stderr, flush=True)
    os.remove(scene_path)
    print(f'## {name}: {a.sets} random light sets, reference {a.rays} rays/texel')
    print('| method | texels | relative L2 (mean) | p95 (mean) | eval wall time (median, s) |')
    print('|---|---|---|---|---|')
    for (label, fname), (l2, p95, n) in sums.items():
        ts = sorted(evals[label]); med = ts[len(ts) // 2]
        print(f'| {label} | {fname} | {l2 / n:.4f} | {p95 / n:.4f} | {med:.3f} |')
    print(f'bake (lightfield, with dense operator, no cache): {t_lf:.2f} s, {bytes_lf} bytes')
    print(f'bake (lightfield, no dense operator, no cache): {t_lf_only:.2f} s, {bytes_lf_only} bytes')
    print(f'bake (traced, cold cache): {t_tr:.2f} s; warm cache: {t_tr_cached:.2f} s, {bytes_tr} bytes')
    print(f'reference: {t_ref / a.sets:.1f} s per light set')
    print('```'); print('\n'.join(STAGES)); print('```')


if __name__ == '__main__':
    main()
