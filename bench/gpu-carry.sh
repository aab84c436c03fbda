#!/usr/bin/env bash
# Packs what bench/gpu.sh needs on a GPU machine that has PyTorch but neither this build nor its .venv, into the
# git-ignored folder .gpu-carry/ (about 36 MB, under the device call's 64 MiB):
#   bash bench/gpu-carry.sh [BINARY]
# - the release binary (default target/release/oneshot-lab);
# - lib/: MuJoCo's shared library from the .venv (libtorch comes from the GPU machine's PyTorch);
# - assets.tar.xz: the robosuite files the scene loads (the robot, gripper and arena MJCF and every mesh and
#   texture they name: 81 MB of text meshes, 10 MB packed), not robosuite's whole 525 MB assets folder;
# - gl/: the EGL loader's Debian packages (glvnd), unpacked there before anything renders.
# bench/gpu.sh uses the folder when it is there; `bash bench/gpu.sh --dry` rehearses with it on the CPU.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bin=$(realpath "${1:-$root/target/release/oneshot-lab}")
venv_assets=$(ls -d "$root"/.venv/lib/python3*/site-packages/robosuite/models/assets)
carry="$root/.gpu-carry"
staged=$(mktemp -d)
trap 'rm -rf "$staged"' EXIT
rm -rf "$carry"
mkdir -p "$carry/lib" "$carry/gl" "$staged/assets" "$staged/apt/partial"
cp "$bin" "$carry/oneshot-lab"
cp -L "$root/.venv/native/mujoco-lib/libmujoco.so.3.17.0" "$carry/lib/"

# The MJCF files scene.rs loads, then every file="..." they name (paths relative to the file naming them).
python3 - "$venv_assets" "$staged/assets" <<'PY'
import os, re, shutil, sys
src, dst = sys.argv[1], sys.argv[2]
todo = ["robots/sawyer/robot.xml", "robots/panda/robot.xml", "grippers/rethink_gripper.xml",
        "grippers/panda_gripper.xml", "arenas/bins_arena.xml"]
seen = set()
while todo:
    rel = os.path.normpath(todo.pop())
    if rel in seen:
        continue
    seen.add(rel)
    os.makedirs(os.path.dirname(os.path.join(dst, rel)), exist_ok=True)
    shutil.copy(os.path.join(src, rel), os.path.join(dst, rel))
    if rel.endswith(".xml"):
        for name in re.findall(r'\bfile="([^"]+)"', open(os.path.join(src, rel)).read()):
            todo.append(os.path.join(os.path.dirname(rel), name))
print(f"{len(seen)} asset files")
PY
tar -cJf "$carry/assets.tar.xz" -C "$staged/assets" .

# The EGL loader (glvnd) for the NVIDIA driver's EGL, as the device guide lists it.
apt_opts=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 "-oDir::State::Lists=$staged/apt")
apt-get "${apt_opts[@]}" update -qq
(cd "$carry/gl" && apt-get "${apt_opts[@]}" download -qq libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2 2>/dev/null)
du -sh "$carry"
