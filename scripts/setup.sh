#!/usr/bin/env bash
# Creates/refreshes .venv with rsrd_jax and its extras, and installs the Debian packages MuJoCo's
# offscreen (EGL) rendering needs when they are missing. Idempotent; used by `make demo/test`.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}

"$PYTHON" - <<'PY'
import sys
if sys.version_info < (3, 11):
    sys.exit(f"rsrd_jax needs Python >= 3.11, found {sys.version.split()[0]}")
PY

# MuJoCo renders offscreen through EGL (Mesa llvmpipe on CPU-only machines).
if ! ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1' || ! ldconfig -p 2>/dev/null | grep -q 'libGL.so.1'; then
  echo "setup: installing EGL/Mesa for MuJoCo offscreen rendering"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  $SUDO env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libegl1 libgl1 libgles2 libegl-mesa0 libgl1-mesa-dri >/dev/null
fi

stamp="$VENV/.rsrd_jax_installed"
if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
fi
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing rsrd_jax[dev] into $VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  "$VENV/bin/python" -m pip install -q -e '.[dev]'
  touch "$stamp"
fi
MUJOCO_GL=egl "$VENV/bin/python" -c "import mujoco; ctx = mujoco.GLContext(8, 8); ctx.make_current(); ctx.free()" \
  || { echo "setup: MuJoCo cannot create an EGL context (MUJOCO_GL=egl)"; exit 1; }
