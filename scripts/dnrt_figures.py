#!/usr/bin/env python3
"""Measure DNRT against the brute-force reference on scenes/ball_corridor.

  scripts/dnrt_figures.py [--lf PATH] [--out DIR] [--rays 16384] [--variant "32 9 u8 regular intermediate 256"]...

For each variant (grid resolution, SH count, codec, placement, normals, rays per grid point)
bakes the scene with those DNRT settings, applies its lights with and without the poses through
`lightfarm eval`, and prints the relative L2 of the DNRT delta (eval with − eval without)
against the reference delta (reference with − reference without, `--rays` per texel) on the
texels within two ball radii of the ball's centre, plus the grid bytes and bake seconds the
bake reports (the bake runs without a warm cache only the first time: the cache under --out is
keyed by content, so delete it to time bakes again). Each variant's bundle stays in --out
(b_<variant>.lfb) for the dnrt_apply_time example. Indirect light only. Defaults reproduce
tests/data/dnrt_accuracy.md.
"""
import argparse, json, math, os, re, subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE = os.path.join(ROOT, 'scenes', 'ball_corridor')
DEFAULT_VARIANTS = [
    '16 4 u8 regular intermediate 256', '32 4 u8 regular intermediate 256',
    '64 4 u8 regular intermediate 256', '16 9 u8 regular intermediate 256',
    '32 9 u8 regular intermediate 256', '64 9 u8 regular intermediate 256',
    '32 9 f16 regular intermediate 256', '32 9 f32 regular intermediate 256',
    '32 4 f32 regular intermediate 256', '32 9 u8 quadratic intermediate 256',
    '32 9 u8 regular intermediate 1024', '16 9 u8 regular convolution 256',
    '32 9 u8 regular convolution 256', '32 4 u8 regular convolution 256',
]


def load(path):
    return {(t['surface'], t['index']): t for t in json.load(open(path))['texels']}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--lf', default=os.path.join(ROOT, 'target', 'release', 'lightfarm'))
    ap.add_argument('--out', default=os.path.join(ROOT, 'out', 'dnrt'))
    ap.add_argument('--rays', type=int, default=16384)
    ap.add_argument('--variant', action='append')
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    out = lambda name: os.path.join(args.out, name)
    run = lambda *a: subprocess.run([args.lf, *a], check=True, capture_output=True, text=True)
    scene = json.load(open(os.path.join(SCENE, 'scene.json')))
    lights = json.load(open(os.path.join(SCENE, 'lights.json')))
    json.dump({**lights, 'poses': []}, open(out('noposes.json'), 'w'))
    with_lights = os.path.join(SCENE, 'lights.json')
    pose = lights['poses'][0]['translation']
    radius = 0.35
    for name, lf in (('ref_with.json', with_lights), ('ref_without.json', out('noposes.json'))):
        if not os.path.exists(out(name)):
            run('reference', os.path.join(SCENE, 'scene.json'), '--lights', lf,
                '--rays', str(args.rays), '-o', out(name))
    rw, ro = load(out('ref_with.json')), load(out('ref_without.json'))
    for v in args.variant or DEFAULT_VARIANTS:
        res, sh, codec, placement, normals, rays = v.split()
        s = dict(scene)
        s['settings'] = {**scene['settings'], 'dnrt': {
            'resolution': int(res), 'sh': int(sh), 'codec': codec, 'placement': placement,
            'normals': normals, 'rays': int(rays)}}
        # Keep the mesh path valid: write the variant next to the scene's own files.
        path = os.path.join(SCENE, '.variant.json')
        bundle = out('b_' + '_'.join(v.split()) + '.lfb')
        json.dump(s, open(path, 'w'))
        try:
            bake = run('bake', path, '-o', bundle, '--cache', out('cache'))
        finally:
            os.remove(path)
        m = re.search(r'dnrt: "\S+" grid (\d+) bytes in ([0-9.]+)s', bake.stderr)
        run('eval', bundle, '--lights', with_lights, '-o', out('eval_with.json'))
        run('eval', bundle, '--lights', out('noposes.json'), '-o', out('eval_without.json'))
        ew, eo = load(out('eval_with.json')), load(out('eval_without.json'))
        num = den = 0.0
        n = 0
        for k, t in rw.items():
            if math.dist(t['position'], pose) > 2 * radius:
                continue
            n += 1
            for c in range(3):
                ref = t['indirect'][c] - ro[k]['indirect'][c]
                ours = ew[k]['indirect'][c] - eo[k]['indirect'][c]
                num += (ours - ref) ** 2
                den += ref ** 2
        print(f'{v}: rel L2 {math.sqrt(num / den):.4f} on {n} texels; '
              f'grid {m.group(1)} bytes, bake {m.group(2)} s')


if __name__ == '__main__':
    main()
