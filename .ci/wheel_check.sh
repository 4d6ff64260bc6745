#!/usr/bin/env bash
# CI: a plain (non-editable) install renders. Builds icefarm's wheel, installs it with its
# dependencies into a fresh virtual environment outside the repo (pip's cache keeps this
# quick after setup.sh) and renders one preview job from a folder outside the repo, so
# nothing can be found through the source tree (render configs are package data).
set -euo pipefail
cd "$(dirname "$0")/.."
work=$(mktemp -d "${TMPDIR:-/tmp}/icefarm-wheel-XXXXXX")
trap 'rm -rf "$work"' EXIT
.venv/bin/python -m pip wheel -q --no-deps -w "$work/dist" .
python3 -m venv "$work/venv"
"$work/venv/bin/python" -m pip install -q --upgrade pip
"$work/venv/bin/python" -m pip install -q "$work"/dist/icefarm-*.whl
cd "$work"
"$work/venv/bin/icefarm" run generator:roof --size-m 0.5 --set storm.max_icicles=4 -o "$work/job" >/dev/null
test -s "$work/job/render.png" || { echo "wheel check: no render.png from the installed wheel" >&2; exit 1; }
echo "wheel check: the installed wheel rendered $work/job/render.png"
