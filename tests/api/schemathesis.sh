#!/usr/bin/env bash
# The API against its own OpenAPI document: schemathesis (PyPI, v4) generates requests from
# /openapi.json and runs every check against an open server and a team server (with a token),
# each with small limits so the bakes it submits stay quick. Ends non-zero on any failure.
#
# Usage: tests/api/schemathesis.sh [path/to/lightfarm] [seconds per mode]   (run by .ci/run)
set -euo pipefail
cd "$(dirname "$0")/../.."
binary=${1:-target/release/lightfarm}
seconds=${2:-120}
if ! command -v schemathesis >/dev/null 2>&1; then
  echo "SKIP: schemathesis not installed (pip install schemathesis)"
  exit 0
fi
work=$(mktemp -d)
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

limits='[limits]
max_body_bytes = 1048576
max_triangles = 20000
max_texels = 3000
max_rays_per_bake = 300000
queue_capacity = 8
concurrent_bakes = 1
worker_threads = 1
request_timeout_seconds = 30'
printf 'open = true\n%s\n' "$limits" > "$work/open.toml"
printf '%s\n[[teams]]\nname = "fuzz"\ntoken = "fuzz-token"\n[[teams]]\nname = "other"\ntoken = "other-token"\n' \
  "$limits" > "$work/team.toml"

start() { # config, log → prints the base URL
  "$binary" serve --addr 127.0.0.1:0 --data "$work/data-$1" --config "$work/$1.toml" \
    > "$work/$1.out" 2> "$work/$1.log" &
  pids+=($!)
  for _ in $(seq 1 100); do
    if grep -q 'listening on' "$work/$1.out" 2>/dev/null; then
      sed -n 's/.*listening on \(http:\/\/[^ ]*\).*/\1/p' "$work/$1.out" | head -1
      return
    fi
    sleep 0.1
  done
  echo "server ($1) did not start" >&2
  cat "$work/$1.log" >&2
  exit 1
}

status=0
for mode in open team; do
  url=$(start "$mode")
  auth=()
  [ "$mode" = team ] && auth=(-H "Authorization: Bearer fuzz-token")
  echo "== schemathesis, $mode mode ($url, ${seconds} s)"
  schemathesis run "$url/openapi.json" --checks all --max-time "$seconds" \
    --generation-deterministic --no-color "${auth[@]}" > "$work/$mode.txt" 2>&1 || status=$?
  # The summary: the tail of the report from its "SUMMARY" banner on.
  sed -n '/SUMMARY/,$p' "$work/$mode.txt" | grep -v '^\s*$' || tail -30 "$work/$mode.txt"
  if grep -q "panicked\|internal error" "$work/$mode.log"; then
    echo "server log ($mode) shows internal errors:" >&2
    grep -m5 "panicked\|internal error" "$work/$mode.log" >&2
    status=1
  fi
  [ "$status" -eq 0 ] || { sed -n '/FAILURES/,/SUMMARY/p' "$work/$mode.txt" | head -150; }
done
exit "$status"
