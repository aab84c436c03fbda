#!/usr/bin/env bash
# Runs the integration tests (tests/it) in two processes side by side, one test at a time in each, with one
# libtorch thread apiece: the tests that drive the world and the pipeline end to end in one, the rest in the other.
#
# Why two processes rather than `--test-threads=2`: tests in one process that seed libtorch's generator (process-wide)
# take a lock and so run one after another anyway, and concurrent tests in one process once crashed in Mesa's
# software renderer (SIGSEGV, 2026-12-02). Extra arguments go to both test binaries (e.g. `--nocapture`).
set -euo pipefail
cd "$(dirname "$0")/.."

# The end-to-end modules; every other module runs in the second process, so a new module is never left out.
end_to_end=(pipeline:: smoke:: world:: slurm::)
skips=()
for module in "${end_to_end[@]}"; do skips+=(--skip "$module"); done

binary=$(cargo test --release --test it --no-run 2>&1 | grep -o 'target/release/deps/it-[0-9a-f]*' | tail -1)
if [[ -z "$binary" || ! -x "$binary" ]]; then
    echo "integration-tests.sh: could not find the integration test binary (cargo test --release --test it --no-run)" >&2
    exit 1
fi

export OMP_NUM_THREADS=1
# Each line is prefixed with its process's name; libtest prints a test's line whole once the test ends.
"$binary" --test-threads=1 "${end_to_end[@]}" "$@" 2>&1 | sed -u 's/^/[end-to-end] /' &
first=$!
"$binary" --test-threads=1 "${skips[@]}" "$@" 2>&1 | sed -u 's/^/[components] /' &
second=$!

status=0
wait "$first" || status=1
wait "$second" || status=1
if [[ $status -ne 0 ]]; then
    echo "integration-tests.sh: a test failed (see the FAILED lines above)" >&2
fi
exit $status
