#!/bin/bash
# Warm rebuild of the test binaries after a one-line change (what `make test` recompiles before running), at two
# commits, in worktrees sharing one copy of this checkout's build folder so that dependencies are already built.
# Usage: bench/warm_test_build.sh OLD_COMMIT NEW_COMMIT   (run with nothing else on the cores)
set -euo pipefail
root=$(git rev-parse --show-toplevel)
work=$(mktemp -d)
trap 'git -C "$root" worktree remove --force "$work/old" 2>/dev/null; git -C "$root" worktree remove --force "$work/new" 2>/dev/null; rm -rf "$work"' EXIT
cp -r "$root/target" "$work/target"
export LIBTORCH="$root/.venv/native/libtorch" MUJOCO_DYNAMIC_LINK_DIR="$root/.venv/native/mujoco-lib"
export ONESHOT_ASSETS_DEFAULT="$root/.venv/native/robosuite-assets" CARGO_TARGET_DIR="$work/target"
for side in old new; do
  commit=$1; [ "$side" = new ] && commit=$2
  git -C "$root" worktree add -q -f "$work/$side" "$commit"
  cd "$work/$side"
  cargo test --release --no-run > "$work/$side.log" 2>&1
  for i in 1 2; do
    echo "// touched $i" >> src/lib.rs
    start=$(date +%s.%N)
    cargo test --release --no-run > "$work/$side.log" 2>&1
    end=$(date +%s.%N)
    git checkout -q src/lib.rs
    echo "$side ($commit) warm rebuild $i: $(echo "$end - $start" | bc) s, $(grep -c Executable "$work/$side.log") test binaries"
  done
done
