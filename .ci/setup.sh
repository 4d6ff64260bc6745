#!/usr/bin/env bash
# Sets up everything icefarm needs, from nothing: Debian packages (when root), then a
# virtual environment at .venv with icefarm and its Python dependencies.
set -euo pipefail
cd "$(dirname "$0")/.."

SYSTEM_PACKAGES=(libllvm19 povray chromium)

missing=()
for pkg in "${SYSTEM_PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
done
if [ ${#missing[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing Debian packages: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  else
    echo "setup: missing Debian packages: ${missing[*]} (install them as root with apt-get;"
    echo "       without libllvm19 renders fall back to the slower scalar_rgb variant, without"
    echo "       povray POV-Ray renders are refused, without chromium the gallery test is skipped)"
  fi
fi

# npm (for the gallery's 3D viewer, package.json) when the machine has no Node.js of its own
if ! command -v npm >/dev/null; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing Debian packages: nodejs npm"
    apt-get update -qq && apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
  else
    echo "setup: no npm: the gallery's 3D view (@google/model-viewer) is left out"
  fi
fi
if command -v npm >/dev/null; then
  npm install --no-audit --no-fund --silent || echo "setup: npm install failed: the gallery's 3D view is left out"
fi

PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PYTHON" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
# Blender as a Python module (bpy 5.0, Python 3.11), the real client the USD export's import
# hook is tested against (tests/test_export.py); its own environment, as it pins numpy 1.26.
if [ ! -x .venv-blender/bin/python ]; then
  "$PYTHON" -m venv .venv-blender
fi
if ! .venv-blender/bin/python -c "import bpy" 2>/dev/null; then
  .venv-blender/bin/python -m pip install -q "bpy==5.0.*" || echo "setup: bpy could not be installed: the Blender import test is skipped"
fi
# One small job without a render compiles icefarm's kernels (numba caches them beside the
# package): about 30 s on 2 cores, once, so that the first job a newcomer runs takes seconds.
warm=$(mktemp -d)
if .venv/bin/icefarm run generator:sign --no-render -o "$warm/job" >/dev/null 2>"$warm/err"; then
  echo "setup: kernels compiled"
else
  echo "setup: compiling the kernels failed (the first job compiles them instead):"; tail -n 3 "$warm/err"
fi
rm -rf "$warm"
echo "setup: ready (.venv/bin/icefarm)"
