#!/usr/bin/env bash
# Load figures for `lightfarm serve` (issue 5's closing note), on one machine over loopback:
#  1. requests per second for a cached bundle fetch (wrk, 2 threads, 32 connections, 10 s;
#     identity and a conditional If-None-Match → 304);
#  2. peak memory (VmHWM) of the server under a burst of 200 bake submissions (distinct seeds,
#     20 at a time; the queue takes limits.queue_capacity, the rest get 429).
# Needs: a release build (target/release/lightfarm), curl, wrk (apt-get install wrk).
# Usage: scripts/service_load.sh [scene-name]   (default maze)
set -euo pipefail
cd "$(dirname "$0")/.."
scene=${1:-maze}
bin=target/release/lightfarm
data=$(mktemp -d)
port=18181
base=http://127.0.0.1:$port
"$bin" serve --addr 127.0.0.1:$port --data "$data" >"$data.log" 2>&1 &
pid=$!
trap 'kill $pid 2>/dev/null; rm -rf "$data" "$data.log"' EXIT
for _ in $(seq 50); do curl -sf $base/healthz >/dev/null && break; sleep 0.1; done
json() { python3 -c "import json,sys; print(json.load(sys.stdin)$1)"; }

scene_id=$(curl -sf -XPOST --data-binary @scenes/$scene/scene.json $base/v1/scenes | json '["id"]')
bake=$(curl -sf -XPOST -H 'content-type: application/json' \
  -d "{\"scene\":\"$scene_id\",\"settings\":{\"texels_per_face\":8,\"rays_per_texel\":256}}" $base/v1/bakes | json '["id"]')
while :; do
  state=$(curl -sf $base/v1/bakes/$bake | json '["state"]')
  [ "$state" = succeeded ] && break
  [ "$state" = failed ] && { echo "bake failed" >&2; exit 1; }
  sleep 0.5
done
hash=$(curl -sf $base/v1/bakes/$bake | json '["bundle"]')
bytes=$(curl -sf $base/v1/bakes/$bake | json '["bundle_bytes"]')
echo "== bundle $hash: $bytes bytes ($scene, T=8, 256 rays)"
echo "== RSS after one bake: $(grep VmRSS /proc/$pid/status)"
echo "== wrk: cached bundle fetch (200, full body)"
wrk -t2 -c32 -d10s --latency $base/v1/bundles/$hash | grep -E 'Requests/sec|Transfer/sec|50%|99%'
echo "== wrk: revalidation (If-None-Match → 304)"
wrk -t2 -c32 -d10s --latency -H "If-None-Match: \"$hash\"" $base/v1/bundles/$hash | grep -E 'Requests/sec|50%|99%'

echo "== burst: 200 submissions, 20 concurrent"
seq 1 200 | xargs -P 20 -I{} curl -s -o /dev/null -w '%{http_code}\n' -XPOST -H 'content-type: application/json' \
  -d "{\"scene\":\"$scene_id\",\"settings\":{\"texels_per_face\":8,\"rays_per_texel\":256,\"seed\":{}}}" \
  $base/v1/bakes | sort | uniq -c
curl -s $base/metrics | grep -E '^lightfarm_(queue_depth|bakes)'
echo "== peak memory: $(grep VmHWM /proc/$pid/status)"
