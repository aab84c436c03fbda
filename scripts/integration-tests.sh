#!/usr/bin/env bash
# Runs the integration tests (tests/it) in two processes side by side, one test at a time in each, with one
# libtorch thread apiece: the tests that drive the world and the pipeline end to end in one, the rest in the other.
#
# Why two processes rather than `--test-threads=2`: tests in one process that seed libtorch's generator (process-wide)
# take a lock and so run one after another anyway, and concurrent tests in one process once crashed in Mesa's
# software renderer (SIGSEGV, 2026-12-02). Extra flags go to both test binaries (`--nocapture`, `--list`); a name
# filter would join the first process's filters, so run `cargo test --release --test it -- NAME` for one test.
set -euo pipefail
cd "$(dirname "$0")/.."

# The end-to-end modules; every other module runs in the second process.
end_to_end=(pipeline:: smoke:: world:: slurm::)
skips=()
for module in "${end_to_end[@]}"; do skips+=(--skip "$module"); done

# Build in the open (so a compiler error shows), then ask cargo where the test binary is.
cargo test --release --test it --no-run
binary=$(cargo test --release --test it --no-run --message-format=json 2>/dev/null |
    grep -o '"executable":"[^"]*/it-[0-9a-f]*"' | tail -1 | cut -d'"' -f4) || true
if [[ -z "$binary" || ! -x "$binary" ]]; then
    echo "integration-tests.sh: cargo named no integration test binary (cargo test --release --test it --no-run)" >&2
    exit 1
fi

export OMP_NUM_THREADS=1
# Each line is prefixed with its process's name; libtest prints a test's line whole once the test ends.
(set -o pipefail; "$binary" --test-threads=1 "${end_to_end[@]}" "$@" 2>&1 | sed -u 's/^/[end-to-end] /') &
first=$!
(set -o pipefail; "$binary" --test-threads=1 "${skips[@]}" "$@" 2>&1 | sed -u 's/^/[components] /') &
second=$!
# Stopped (Ctrl-C, or CI's timeout), the script stops both test processes (the subshells' children) too.
trap 'pkill -TERM -P "$first" 2>/dev/null; pkill -TERM -P "$second" 2>/dev/null; exit 130' INT TERM

status=0
wait "$first" || status=1
wait "$second" || status=1
if [[ $status -ne 0 ]]; then
    echo "integration-tests.sh: a test failed (see the FAILED lines above)" >&2
fi
exit $status
