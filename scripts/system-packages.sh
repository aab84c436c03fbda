#!/usr/bin/env bash
# The Debian packages oneshot-lab needs on the machine, in one place: headless EGL rendering through Mesa's
# software driver for every command that renders, procps (`pgrep`/`pkill`, which the test scripts use to stop
# or find their processes), and (with `--slurm`) Slurm and munge for the Slurm executor's test. Installs what is missing when it can (root and apt-get); otherwise stops, before any build, with the
# exact command to run.
#   scripts/system-packages.sh            rendering packages
#   scripts/system-packages.sh --slurm    rendering and Slurm packages
set -euo pipefail
pkgs="libegl1 libegl-mesa0 libgl1-mesa-dri procps"
if [ "${1:-}" = "--slurm" ]; then
  pkgs="$pkgs slurm-wlm munge"
fi
missing=""
for p in $pkgs; do
  dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
[ -z "$missing" ] && exit 0
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "setup: installing$missing"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq $missing
else
  echo "setup: this machine lacks$missing (rendering and the test scripts need them). Install them with:" >&2
  echo "  sudo apt-get install -y$missing" >&2
  exit 1
fi
