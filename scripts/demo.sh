#!/usr/bin/env bash
# The main job on embedded defaults: build, bake the maze (MRT + DRT), apply its lights
# with DRT and with plain MRT, and compare both with the brute-force reference. Outputs go to
# ./out; shape operators are cached in ./lightfarm-data (a second run reuses them).
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -p lightfarm-server
LF=./target/release/lightfarm
mkdir -p out
$LF bake scenes/maze/scene.json -o out/maze.lfb --cache lightfarm-data/shapes
$LF eval out/maze.lfb --lights scenes/maze/lights.json --method drt -o out/maze-drt.json --png out/maze-indirect.png --png-lit out/maze-lit.png
$LF eval out/maze.lfb --lights scenes/maze/lights.json --method mrt -o out/maze-mrt.json
$LF reference scenes/maze/scene.json --lights scenes/maze/lights.json --rays 1024 -o out/maze-reference.json
echo "MRT (blocks only: MRT ignores clutter) against the reference:"
$LF compare out/maze-mrt.json out/maze-reference.json --scene scenes/maze/scene.json
echo "DRT against the reference:"
$LF compare out/maze-drt.json out/maze-reference.json --scene scenes/maze/scene.json
