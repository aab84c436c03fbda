#!/usr/bin/env bash
# The Debian packages oneshot-lab needs on the machine, in one place: headless EGL rendering through Mesa's
# software driver for every command that renders, and (with `--slurm`, as CI runs it) Slurm and munge for the
# Slurm executor's test and procps, whose pgrep and pkill the test scripts use to find and stop processes.
# Installs what is missing when it can (root and apt-get); otherwise stops, before any build, with the exact
# command to run.
#   scripts/system-packages.sh            rendering packages
#   scripts/system-packages.sh --slurm    rendering, Slurm and process-tool packages
set -euo pipefail
pkgs="libegl1 libegl-mesa0 libgl1-mesa-dri"
if [ "${1:-}" = "--slurm" ]; then
  pkgs="$pkgs slurm-wlm munge procps"
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
  echo "setup: this machine lacks$missing (headless rendering needs them). Install them with:" >&2
  echo "  sudo apt-get install -y$missing" >&2
  exit 1
fi
