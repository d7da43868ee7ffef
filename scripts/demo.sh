#!/usr/bin/env bash
# The main job on embedded defaults: build, bake the maze, apply its lights, compare with the
# brute-force reference. Outputs go to ./out; shape operators are cached in ./lightfarm-data.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -p lightfarm-server
LF=./target/release/lightfarm
mkdir -p out
$LF bake scenes/maze/scene.json -o out/maze.lfb --cache lightfarm-data/shapes
$LF eval out/maze.lfb --lights scenes/maze/lights.json --method mrt -o out/maze-mrt.json
$LF reference scenes/maze/scene.json --lights scenes/maze/lights.json --rays 1024 -o out/maze-reference.json
$LF compare out/maze-mrt.json out/maze-reference.json
