#!/usr/bin/env bash
# DRT figures (issue 3): mrt vs drt (the paper's deltas) vs exact (drt with `scene_gather:
# exact`) relative L2 (scene texels, texels within 1 m of clutter,
# clutter texels) over 10 random light sets against a 16k-ray reference, for the Cornell box and
# the maze with four pillars at T=8, 1024 rays, tolerance 0.01; the bake logs hold the operator
# build time ("clutter operators" stage) and the DRT section's bytes.
# Usage: scripts/drt_figures.sh [OUT_DIR]   (needs `cargo build --release` first; ~30 min)
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD
LF=$repo/target/release/lightfarm
out=${1:-out/drt-figures}
mkdir -p "$out"
cd "$out"
rm -f results.txt
for scene in cornell maze; do
python3 - "$scene" "$repo" <<'PY'
import json, sys
name = sys.argv[1]
s = json.load(open(f"{sys.argv[2]}/scenes/{name}/scene.json"))
s["settings"].update({"texels_per_face": 8, "rays_per_texel": 1024, "tolerance": 0.01, "probe_volume": "always"})
json.dump(s, open(f"{name}.json", "w"), indent=1)
s["settings"]["scene_gather"] = "exact"
json.dump(s, open(f"{name}-exact.json", "w"), indent=1)
del s["settings"]["scene_gather"]
PY
python3 "$repo/scripts/light_sets.py" "$scene.json" "$scene" 10 "$scene-lights"
cp -r "$repo/scenes/$scene/"* . 2>/dev/null || true
$LF bake $scene.json -o $scene.lfb --no-cache > $scene.bake.log 2>&1
$LF bake $scene-exact.json -o $scene-exact.lfb --no-cache > $scene-exact.bake.log 2>&1
for i in $(seq 0 9); do
  $LF reference $scene.json --lights $scene-lights$i.json --rays 16384 -o $scene-ref$i.json > /dev/null 2>&1
  for m in mrt drt exact; do
    if [ $m = exact ]; then
      $LF eval $scene-exact.lfb --lights $scene-lights$i.json --method drt -o $scene-$m$i.json
    else
      $LF eval $scene.lfb --lights $scene-lights$i.json --method $m -o $scene-$m$i.json
    fi
    all=$($LF compare $scene-$m$i.json $scene-ref$i.json --only block: | tail -1)
    near=$($LF compare $scene-$m$i.json $scene-ref$i.json --scene $scene.json --near-clutter 1 | tail -1)
    clut=$($LF compare $scene-$m$i.json $scene-ref$i.json --only clutter: | tail -1)
    echo "$scene set=$i method=$m scene_texels: $all | near1m: $near | clutter: $clut" >> results.txt
  done
done
done
echo finished >> results.txt
python3 - <<'PY'
import re, statistics as S, collections
rows = collections.defaultdict(list)
pat = r"(\w+) set=\d+ method=(\w+) scene_texels: relative_l2=([\d.]+).*near1m: relative_l2=([\d.]+).*clutter: relative_l2=([\d.]+)"
for line in open("results.txt"):
    m = re.match(pat, line)
    if m:
        rows[m.group(1), m.group(2)].append([float(x) for x in m.groups()[2:]])
for (scene, method), r in sorted(rows.items()):
    print(f"{scene} {method}: mean relative L2 scene {S.mean(x[0] for x in r):.4f}, "
          f"within 1 m of clutter {S.mean(x[1] for x in r):.4f}, clutter {S.mean(x[2] for x in r):.4f}")
PY
