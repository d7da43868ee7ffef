#!/usr/bin/env bash
# Regenerates the decode fuzz seeds (tiny bundles in every codec and both transports) from
# seed-scene.json after a bundle-format change. Run from the repository root after
# `cargo build --release`.
# tiny-u8-format1.lfb is kept as it is: a 1.x bundle (kind-3 blocks, CSR gather), so the
# fuzzer still reaches the reader's 1.x paths; tiny-u8-format2.0.lfb likewise: a 2.0 bundle,
# whose DRT section is kind 11 with its index lists as u32s; tiny-u8-format2.7.lfb: a 2.7
# bundle, whose DRT section is kind 22 with its gather in form 2 (2.8 writes kind 23).
set -euo pipefail
out=client/fuzz/corpus/decode
bin=${LIGHTFARM_BIN:-./target/release/lightfarm}
for c in u8 f16 f32; do
  "$bin" bake client/fuzz/seed-scene.json -o "$out/tiny-$c.lfb" --no-cache --codec "$c" -q
done
"$bin" bake client/fuzz/seed-scene.json -o "$out/tiny-traced.lfb" --no-cache --transport traced -q
# The SH responses section (minor 2) in every codec.
sh_scene=$(mktemp --suffix=.json)
jq '.settings.sh_responses = true' client/fuzz/seed-scene.json > "$sh_scene"
for c in u8 f16 f32; do
  "$bin" bake "$sh_scene" -o "$out/tiny-sh-$c.lfb" --no-cache --codec "$c" -q
done
rm -f "$sh_scene"
