#!/usr/bin/env bash
# Runs the Blender add-on's headless tests (plugins/blender/tests) with Blender's own Python
# module, bpy 4.5.4 (tests/requirements.txt), against a lightfarm binary:
#   bash plugins/blender/tests/run.sh [path/to/lightfarm]      (default target/release/lightfarm)
# bpy is installed once into a venv ($LF_BPY_VENV, default ~/.cache/lightfarm/bpy-4.5.4; about
# 950 MB installed) and reused. bpy 4.5 wheels exist for CPython 3.11 only: without a Python
# 3.11 the tests are skipped with the reason printed (exit 0) — unless LF_BPY_REQUIRED=1 (CI),
# which makes that a failure; a failed install fails.
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
repo="$(cd "$here/../../.." && pwd)"
lightfarm="$(realpath "${1:-$repo/target/release/lightfarm}")"
venv="${LF_BPY_VENV:-$HOME/.cache/lightfarm/bpy-4.5.4}"

python=""
for candidate in python3.11 python3; do
  if command -v "$candidate" >/dev/null 2>&1 &&
     [ "$("$candidate" -c 'import sys; print("%d.%d" % sys.version_info[:2])')" = "3.11" ]; then
    python="$candidate"
    break
  fi
done
if [ -z "$python" ]; then
  if [ "${LF_BPY_REQUIRED:-0}" = 1 ]; then
    echo "Blender add-on tests FAILED: bpy 4.5.4 needs Python 3.11, and none is on PATH" >&2
    exit 1
  fi
  echo "Blender add-on tests SKIPPED: bpy 4.5.4 needs Python 3.11, and none is on PATH" >&2
  exit 0
fi
if [ ! -x "$lightfarm" ]; then
  echo "no lightfarm binary at $lightfarm (cargo build --release -p lightfarm-server)" >&2
  exit 1
fi
if ! "$venv/bin/python" -c 'import bpy, sys; sys.exit(bpy.app.version[:3] != (4, 5, 4))' \
     >/dev/null 2>&1; then
  echo "installing bpy 4.5.4 into $venv"
  "$python" -m venv "$venv"
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check \
    -r "$here/requirements.txt"
fi
cd "$repo"
"$venv/bin/python" "$here/test_install_zip.py"
"$venv/bin/python" "$here/test_addon.py" --lightfarm "$lightfarm"
