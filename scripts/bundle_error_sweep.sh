#!/usr/bin/env bash
# Bytes against error for the maze with its four pillars at 8 texels per face (issue 6): bakes
# it at several rank tolerances and codec budgets (`codec_error`, and `transport_codec_error` for
# the transport matrices) and prints each bundle's bytes per section and
# its mean relative L2 (all texels, texels within 1 m of clutter, clutter texels) over seeded
# random light sets (the generator of scripts/drt_figures.sh) against brute-force references.
# Usage: scripts/bundle_error_sweep.sh [OUT_DIR] [SETS] [NAME] [RAYS]   (needs `cargo build
# --release`; about 1 min per set for the references, then seconds per variant). NAME seeds the
# light sets (default `maze`, the sets the defaults were chosen on; any other name gives sets
# to validate them on), RAYS is the references' rays per texel (default 16384).
set -euo pipefail
cd "$(dirname "$0")/.."
repo=$PWD
LF=$repo/target/release/lightfarm
out=${1:-out/bundle-error-sweep}
sets=${2:-7}
name=${3:-maze}
rays=${4:-16384}
mkdir -p "$out"
cd "$out"
python3 - "$repo" <<'PY'
import json, sys
repo = sys.argv[1]
s = json.load(open(f"{repo}/scenes/maze/scene.json"))
s["settings"].update({"texels_per_face": 8, "rays_per_texel": 1024, "tolerance": 0.01})
json.dump(s, open("maze.json", "w"), indent=1)
# (tolerance, codec_error, transport_codec_error): the default (0.01 at this scene, 0.04, 0.02),
# both budgets tighter and looser, the transport budget alone looser, and coarser tolerances.
for tol, budget, transport in [("0.01", "0.02", "0.02"), ("0.01", "0.04", "0.02"),
                               ("0.01", "0.05", "0.02"), ("0.01", "0.06", "0.02"),
                               ("0.01", "0.04", "0.05"), ("0.01", "0.05", "0.05"),
                               ("0.02", "0.04", "0.02"), ("0.03", "0.04", "0.02")]:
    v = json.loads(json.dumps(s))
    v["settings"].update({"tolerance": float(tol), "codec_error": float(budget),
                          "transport_codec_error": float(transport)})
    json.dump(v, open(f"maze-t{tol}-c{budget}-x{transport}.json", "w"), indent=1)
PY
python3 "$repo/scripts/light_sets.py" maze.json "$name" "$sets" lights
for i in $(seq 0 $((sets - 1))); do
  [ -f "ref$i.json" ] || $LF reference maze.json --lights "lights$i.json" --rays "$rays" -o "ref$i.json" > /dev/null 2>&1
done
echo "| tolerance | codec_error | transport_codec_error | bytes | shapes | transport | drt | all texels | within 1 m of clutter | clutter texels |"
echo "|---|---|---|---:|---:|---:|---:|---:|---:|---:|"
for v in maze-t*.json; do
  log=$($LF bake "$v" -o "${v%.json}.lfb" --cache cache 2>&1)
  bytes=$(echo "$log" | sed -n 's/.*bytes=\([0-9]*\).*/\1/p')
  sec() { echo "$log" | sed -n "s/.*[ ,]$1 \([0-9]*\)\/.*/\1/p"; }
  errs=$(for i in $(seq 0 $((sets - 1))); do
    $LF eval "${v%.json}.lfb" --lights "lights$i.json" -o "res$i.json" > /dev/null
    a=$($LF compare "res$i.json" "ref$i.json" | tail -1 | sed 's/relative_l2=\([^ ]*\).*/\1/')
    n=$($LF compare "res$i.json" "ref$i.json" --scene maze.json --near-clutter 1 | tail -1 | sed 's/relative_l2=\([^ ]*\).*/\1/')
    c=$($LF compare "res$i.json" "ref$i.json" --only clutter: | tail -1 | sed 's/relative_l2=\([^ ]*\).*/\1/')
    echo "$a $n $c"
  done | awk '{a+=$1; n+=$2; c+=$3} END {printf "%.4f | %.4f | %.4f", a/NR, n/NR, c/NR}')
  t=$(echo "$v" | sed 's/maze-t\(.*\)-c\(.*\)-x\(.*\).json/\1 | \2 | \3/')
  echo "| $t | $bytes | $(sec shapes) | $(sec transport) | $(sec drt) | $errs |"
done
