#!/usr/bin/env bash
# Whole-machine CPU seconds (user + nice + system, from /proc/stat) spent while a command runs.
# Counts every process the command starts, however it was forked (rusage loses a grandchild
# its parent never waited for, as bus processes forked by the daemon's zygote are).
# Usage: bench/cpu_window.sh timeout -s INT 3 .venv/bin/imud run --config configs/sim.toml
set -u
read -r _ u n s _ < /proc/stat
"$@" >/dev/null 2>&1
read -r _ u2 n2 s2 _ < /proc/stat
hz=$(getconf CLK_TCK)
awk -v t=$(( u2 + n2 + s2 - u - n - s )) -v hz="$hz" 'BEGIN { printf "cpu %.2f s\n", t / hz }'
