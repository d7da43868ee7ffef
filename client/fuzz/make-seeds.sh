#!/usr/bin/env bash
# Regenerates the decode fuzz seeds (tiny bundles in every codec and both transports) from
# seed-scene.json after a bundle-format change. Run from the repository root after
# `cargo build --release`.
set -euo pipefail
out=client/fuzz/corpus/decode
bin=./target/release/lightfarm
for c in u8 f16 f32; do
  "$bin" bake client/fuzz/seed-scene.json -o "$out/tiny-$c.lfb" --no-cache --codec "$c" -q
done
"$bin" bake client/fuzz/seed-scene.json -o "$out/tiny-traced.lfb" --no-cache --transport traced -q
