#!/usr/bin/env bash
# Bundle and client-runtime figures (issue 6): bytes per scene and section, the error each codec
# adds against f32, and frame time on 1 and 2 threads next to the memory-traffic bound.
# Usage: scripts/bundle_figures.sh [OUT_DIR]   (needs `cargo build --release` first)
# Writes OUT_DIR/bundle-figures.md (default out/). Run on an otherwise idle machine: frame times
# are medians of 1000 frames, measured side by side in this one run.
set -euo pipefail
cd "$(dirname "$0")/.."
LF=./target/release/lightfarm
out=${1:-out}
mkdir -p "$out"
md="$out/bundle-figures.md"
cache="$out/shape-cache"

# The maze at 8 texels per face and tolerance 0.01: an accuracy-equivalent cheaper setting.
python3 - "$out" <<'EOF'
import json, sys
s = json.load(open("scenes/maze/scene.json"))
s["settings"].update({"texels_per_face": 8, "tolerance": 0.01})
json.dump(s, open(f"{sys.argv[1]}/maze8.json", "w"), indent=1)
EOF
cp scenes/maze/lights.json "$out/maze8-lights.json"

{
  echo "# Bundle figures"
  echo
  echo "Machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs). Commit $(git rev-parse --short HEAD)."
  echo
  echo "## Bytes per scene and section (default codec: auto, zstd)"
  echo
  echo '| scene | bytes | sections (stored/raw) | codecs |'
  echo '|---|---:|---|---|'
} > "$md"
for s in cornell corridor maze; do
  log=$($LF bake "scenes/$s/scene.json" -o "$out/$s.lfb" --cache "$cache" 2>&1)
  bytes=$(echo "$log" | sed -n 's/.*bytes=\([0-9]*\).*/\1/p')
  sections=$(echo "$log" | sed -n 's/^sections (stored\/raw bytes): \(.*\);.*/\1/p')
  codecs=$(echo "$log" | sed -n 's/^codecs: //p')
  echo "| $s | $bytes | $sections | $codecs |" >> "$md"
done
log=$($LF bake "$out/maze8.json" -o "$out/maze8.lfb" --cache "$cache" 2>&1)
echo "| maze, 8 texels/face, tolerance 0.01 | $(echo "$log" | sed -n 's/.*bytes=\([0-9]*\).*/\1/p') | $(echo "$log" | sed -n 's/^sections (stored\/raw bytes): \(.*\);.*/\1/p') | $(echo "$log" | sed -n 's/^codecs: //p') |" >> "$md"

{
  echo
  echo "## Error each codec adds against f32 (maze, its lights, DRT, relative L2 / p95 over texels)"
  echo
  echo '| codec | bytes | added error |'
  echo '|---|---:|---|'
} >> "$md"
for c in f32 f16 u8 auto; do
  log=$($LF bake scenes/maze/scene.json -o "$out/maze-$c.lfb" --cache "$cache" --codec "$c" 2>&1)
  $LF eval "$out/maze-$c.lfb" --lights scenes/maze/lights.json -o "$out/maze-$c.json"
  err=$([ "$c" = f32 ] && echo "0 (reference)" || $LF compare "$out/maze-$c.json" "$out/maze-f32.json" | tail -1)
  echo "| $c | $(echo "$log" | sed -n 's/.*bytes=\([0-9]*\).*/\1/p') | $err |" >> "$md"
done

{
  echo
  echo "## Frame time (median of 1000 frames, release) next to the memory-traffic bound"
  echo
  echo '| bundle | method | threads | median ms | p90 ms | operator bytes/frame | read GB/s | bound ms |'
  echo '|---|---|---:|---:|---:|---:|---:|---:|'
} >> "$md"
for b in maze maze8; do
  lights=scenes/maze/lights.json
  for m in mrt drt; do
    for t in 1 2; do
      line=$($LF frame-time "$out/$b.lfb" --lights "$lights" --method "$m" --frames 1000 --threads "$t")
      get() { echo "$line" | sed -n "s/.*$1=\([^ ]*\).*/\1/p"; }
      echo "| $b | $m | $t | $(get median_ms) | $(get p90_ms) | $(get operator_bytes) | $(get read_bandwidth_gbs) | $(get bound_ms) |" >> "$md"
    done
  done
done
echo "wrote $md"
