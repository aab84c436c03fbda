#!/usr/bin/env bash
# Idempotent set-up: a project-local .venv holding the native libraries oneshot-lab links against.
#   torch==2.11.0      libtorch (headers + shared libraries) for the `tch` crate
#   mujoco==3.17.0     libmujoco.so for the `mujoco-rs` crate
#   robosuite==1.5.2   robot, gripper, arena and texture assets only (installed without its Python dependencies)
# No Python code from these packages runs in the product. The links under .venv/native are what
# .cargo/config.toml points the builds at.
set -euo pipefail
cd "$(dirname "$0")/.."

# The machine's rendering packages first: without them every rendering command fails after the build.
bash scripts/system-packages.sh

PYTHON=${PYTHON:-python3}
VENV=.venv
stamp=$VENV/.oneshot-setup-v2

if [ ! -f "$stamp" ]; then
  [ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
  # --no-deps: only the native libraries and assets are used. libtorch_cpu.so links the CUDA runtime
  # and CUPTI, so those two small wheels come too; the multi-GB CUDA math libraries are not needed on CPU
  # (on a GPU machine, point LD_LIBRARY_PATH at a CUDA-enabled torch, see docs/guide/gpu.md).
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps \
    torch==2.11.0 mujoco==3.17.0 robosuite==1.5.2 \
    "nvidia-cuda-runtime==13.0.96.*" "nvidia-cuda-cupti==13.0.85.*"
  touch "$stamp"
fi

site=$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
mkdir -p "$VENV/native/mujoco-lib"
ln -sfn "$site/torch" "$VENV/native/libtorch"
ln -sfn "$site/robosuite/models/assets" "$VENV/native/robosuite-assets"
so=$(ls "$site"/mujoco/libmujoco.so.* | head -n 1)
ln -sfn "$so" "$VENV/native/mujoco-lib/libmujoco.so"
ln -sfn "$so" "$VENV/native/mujoco-lib/$(basename "$so")"
echo "setup: .venv ready (libtorch, libmujoco, robosuite assets under $VENV/native)"
