#!/usr/bin/env bash
# The GPU proof of docs/benchmarks.md as one script that fits one 10-minute call on a 16-core H100/H200 machine:
#   bash bench/gpu.sh [--dry] [BINARY]
# Every figure goes to one report file ($OUT/gpu-report.txt when $OUT is set, else bench/out/), each part timed,
# and a part that fails does not stop the others; the last lines list what passed and what failed.
#   1. bench train (fp32, bf16, bf16 + channels-last) beside bench/reference.py (PyTorch eager);
#   2. EGL on the NVIDIA driver: a contact sheet compared with bench/mesa-contact-sheet.png (rendered by Mesa);
#   3. two collections at 240x320, then bench loader with host and device augmentation, frames held decoded and
#      decoded on use, and four batches built at once;
#   4. a short sixteen-task training and evaluation on the GPU (experiments/learn_gpu_quick.toml).
# --dry rehearses every command on the CPU with tiny settings (what CI runs), so that the GPU call cannot fail
# on a typo. BINARY defaults to .gpu-carry/oneshot-lab where bench/gpu-carry.sh packed one (with MuJoCo's
# library, the scene's robosuite files and the EGL loader: what a GPU machine without this build needs), else
# target/release/oneshot-lab. On the GPU, libtorch's CUDA build comes from the machine's PyTorch.
# GPU_DEADLINE_S (default 570) bounds the whole script: the sixteen-task run gets what the other parts left, and
# a run cut short still reports the stages it finished.
set -u
dry=0
if [ "${1:-}" = --dry ]; then dry=1; shift; fi
root=$(cd "$(dirname "$0")/.." && pwd)
carry=$root/.gpu-carry
default_bin=$root/target/release/oneshot-lab
if [ -x "$carry/oneshot-lab" ]; then default_bin=$carry/oneshot-lab; fi
bin=$(realpath "${1:-$default_bin}")
deadline=$(( $(date +%s) + ${GPU_DEADLINE_S:-570} ))
out_dir=${OUT:-$root/bench/out}
mkdir -p "$out_dir"
report="$out_dir/gpu-report.txt"
exec > >(tee "$report") 2>&1
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
passed=() failed=()
echo "binary: $bin"
if [ -d "$carry" ]; then
  # The packed folder: MuJoCo's library beside the binary's, the scene's assets unpacked outside the checkout.
  export LD_LIBRARY_PATH="$carry/lib:${LD_LIBRARY_PATH:-}"
  mkdir -p "$work/assets"
  python3 -c 'import sys, tarfile; tarfile.open(sys.argv[1]).extractall(sys.argv[2], filter="data")' \
    "$carry/assets.tar.xz" "$work/assets" || exit 1
  export ONESHOT_ASSETS=$work/assets
fi

if [ "$dry" = 1 ]; then
  device=cpu steps=1 size=small per_task=2 height=32 width=40 batches=1 profile=(--profile dry)
  launch=("$bin")
  # The build's PyTorch lacks its Python dependencies (it is there for libtorch): the reference is only compiled.
  reference() { python3 -m py_compile "$root/bench/reference.py" && echo "(dry: bench/reference.py compiles)"; }
else
  device=cuda steps=20 size=paper per_task=8 height=240 width=320 batches=10 profile=()
  torch_dir=$(python3 -c "import torch, os; print(os.path.dirname(torch.__file__))") || exit 1
  export LD_LIBRARY_PATH="$torch_dir/lib:$torch_dir/../nvidia/cu13/lib:${LD_LIBRARY_PATH:-}"
  # EGL through the NVIDIA driver (docs/benchmarks.md): the loader's packages, if carried, and the vendor file.
  for f in "$carry"/gl/*.deb; do [ -f "$f" ] && dpkg -x "$f" /; done
  ldconfig
  vendor=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  if [ -f "$vendor" ]; then export __EGL_VENDOR_LIBRARY_FILENAMES=$vendor; fi
  # The binary links libtorch_cpu only; preloading the CUDA library registers libtorch's CUDA backend.
  launch=(env LD_PRELOAD=libtorch_cuda.so "$bin")
  reference() { python3 "$root/bench/reference.py" "$@"; }
  nvidia-smi -L
fi

lab() { "${launch[@]}" "$@"; }

# part NAME COMMAND...: runs one part, timed; its status joins the summary.
part() {
  local name=$1 start rc
  shift
  echo
  echo "== $name: $*"
  start=$(date +%s)
  "$@"
  rc=$?
  echo "== $name: exit $rc after $(( $(date +%s) - start )) s"
  if [ "$rc" = 0 ]; then passed+=("$name"); else failed+=("$name"); fi
}

train_settings() {
  for setting in "fp32 contiguous" "bf16 contiguous" "bf16 channels_last"; do
    set -- $setting
    echo "-- bench train --precision $1 --memory-format $2"
    lab bench train --config "$size" --device "$device" --steps "$steps" --precision "$1" --memory-format "$2" || return
    echo "-- bench/reference.py --precision $1 --memory-format $2"
    reference --device "$device" --steps "$steps" --precision "$1" --memory-format "$2" || return
  done
}

collections() {
  for robot in sawyer panda; do
    lab collect --robot "$robot" --out "$work/$robot" --tasks 1,14 --per-task "$per_task" \
      --height "$height" --width "$width" || return
  done
}

loader() {
  for at in host device; do
    for decode in "" --decode-on-use; do
      echo "-- bench loader --augment-on $at $decode"
      lab bench loader --demos "$work/sawyer" --agents "$work/panda" --device "$device" --batches "$batches" \
        --augment-on "$at" $decode || return
    done
  done
  # Four batches built at once, as a training with train.prefetch = 4 builds them.
  echo "-- bench loader --augment-on device --at-once 4"
  lab bench loader --demos "$work/sawyer" --agents "$work/panda" --device "$device" --batches "$batches" \
    --augment-on device --at-once 4
}

egl() {
  if [ "$dry" = 1 ]; then
    # Mesa against the sheet it rendered when the reference was made: the comparison itself is rehearsed.
    lab contact-sheet --out "$work/sheet.png" --instances 2 --height 120 --width 160 \
      --compare "$root/bench/mesa-contact-sheet.png"
  else
    lab contact-sheet --out "$out_dir/nvidia-contact-sheet.png" --instances 2 --height 120 --width 160 \
      --compare "$root/bench/mesa-contact-sheet.png"
  fi
}

learning() {
  local left=$(( deadline - $(date +%s) )) rc
  echo "-- $left s left for the run"
  timeout --signal=INT --kill-after=10 "$left" \
    "${launch[@]}" run "$root/experiments/learn_gpu_quick.toml" --store "$work/runs" --jobs 2 "${profile[@]}"
  rc=$?
  # What finished, also when the deadline cut the run short: every stage's time and metrics.
  lab query stages --store "$work/runs"
  lab report "$root/experiments/learn_gpu_quick.toml" --store "$work/runs" >/dev/null 2>&1 &&
    sed -n 1,30p "$work/runs/reports/learn_gpu_quick/index.md"
  # A device call brings back at most 8 files: the report page, its loss curves and the results store.
  cp "$work/runs/reports/learn_gpu_quick/index.md" "$out_dir/learn_gpu_quick.md" 2>/dev/null
  cp "$work/runs/reports/learn_gpu_quick/loss_curves.png" "$out_dir/learn_gpu_quick_loss_curves.png" 2>/dev/null
  cp "$work/runs/oneshot.sqlite" "$out_dir/learn_gpu_quick.sqlite" 2>/dev/null
  return "$rc"
}

part "bench train" train_settings
part "EGL" egl
part "collections" collections
part "bench loader" loader
part "sixteen tasks" learning
echo
echo "passed: ${passed[*]:-none}"
echo "failed: ${failed[*]:-none}"
echo "report: $report"
[ "${#failed[@]}" = 0 ]
