#!/usr/bin/env bash
# The GPU measurements of docs/benchmarks.md, on one CUDA machine:
#   bash bench/gpu.sh [BINARY]
# BINARY defaults to target/release/oneshot-lab. libtorch's CUDA build is taken from the machine's PyTorch
# (`python3 -c "import torch"` must work); robosuite's assets from ONESHOT_ASSETS or the build's .venv.
set -u
bin=${1:-target/release/oneshot-lab}
torch_dir=$(python3 -c "import torch, os; print(os.path.dirname(torch.__file__))") || exit 1
export LD_LIBRARY_PATH="$torch_dir/lib:$torch_dir/../nvidia/cu13/lib:${LD_LIBRARY_PATH:-}"
# The binary links libtorch_cpu only; preloading the CUDA library registers libtorch's CUDA backend.
lab() { LD_PRELOAD=libtorch_cuda.so "$bin" "$@"; }
say() { echo; echo "\$ $*"; }
data=$(mktemp -d)
trap 'rm -rf "$data"' EXIT

nvidia-smi -L
say "bench world --robot panda --episodes 4 --height 240 --width 320"
lab bench world --robot panda --episodes 4 --height 240 --width 320
for setting in "fp32 contiguous" "bf16 contiguous" "bf16 channels_last"; do
  set -- $setting
  say "bench train --config paper --device cuda --steps 20 --precision $1 --memory-format $2"
  lab bench train --config paper --device cuda --steps 20 --precision "$1" --memory-format "$2"
  for tune in "" --cudnn-benchmark; do
    say "python3 bench/reference.py --device cuda --steps 20 --precision $1 --memory-format $2 $tune"
    python3 bench/reference.py --device cuda --steps 20 --precision "$1" --memory-format "$2" $tune
  done
done
say "bench train --config paper --device cuda --steps 10 --precision bf16 --memory-format channels_last --architectures all"
lab bench train --config paper --device cuda --steps 10 --precision bf16 --memory-format channels_last --architectures all
for robot in sawyer panda; do
  say "collect --robot $robot --per-task 8 --height 240 --width 320 (16 tasks, all cores)"
  start=$(date +%s%N)
  lab collect --robot "$robot" --out "$data/$robot" --per-task 8 --height 240 --width 320
  echo "$robot: $(( ($(date +%s%N) - start) / 1000000 )) ms for 128 trajectories"
done
for at in host device; do
  for decode in "" --decode-on-use; do
    say "bench loader --device cuda --augment-on $at $decode"
    lab bench loader --demos "$data/sawyer" --agents "$data/panda" --device cuda --augment-on "$at" $decode
  done
done
