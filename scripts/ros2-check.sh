#!/usr/bin/env bash
# On a ROS 2 machine with imud running (README, "ROS 2"): what ROS 2's own tools must show.
#   scripts/ros2-check.sh [NAMESPACE] [DEVICE]     (defaults: /imud imu0, configs/sim-ros2.toml's)
# Needs a sourced ROS 2 (Jazzy or later; Humble with [ros2] distro = "humble") with
# rmw_zenoh_cpp, and its router running (`ros2 run rmw_zenoh_cpp rmw_zenohd`).
set -uo pipefail
ns="${1:-/imud}"
dev="${2:-imu0}"
topic="$ns/$dev/imu/data_raw"
fail=0
step() { printf '\n== %s\n' "$1"; }
bad() { printf 'NOT OK: %s\n' "$1"; fail=1; }

if ! command -v ros2 >/dev/null 2>&1; then
  echo "ros2 not found: source your ROS 2 install first (source /opt/ros/\$ROS_DISTRO/setup.bash)" >&2
  exit 2
fi
if [ "${RMW_IMPLEMENTATION:-}" != "rmw_zenoh_cpp" ]; then
  echo "RMW_IMPLEMENTATION is '${RMW_IMPLEMENTATION:-unset}': export RMW_IMPLEMENTATION=rmw_zenoh_cpp" >&2
  exit 2
fi

step "ros2 node list: must list $ns/imud ([ros2] namespace and node)"
nodes=$(timeout 10 ros2 node list 2>&1); echo "$nodes"
grep -qx "$ns/imud" <<<"$nodes" || bad "no $ns/imud: is imud running with [ros2] enabled, and the router?"

step "ros2 topic list -t: must list $topic [sensor_msgs/msg/Imu]"
topics=$(timeout 10 ros2 topic list -t 2>&1); echo "$topics"
grep -qF "$topic [sensor_msgs/msg/Imu]" <<<"$topics" || bad "no $topic of type sensor_msgs/msg/Imu"

step "ros2 topic echo --once $topic: frame_id imu_link, orientation_covariance[0] -1, +9.8 on z lying flat"
timeout 10 ros2 topic echo --once "$topic" || bad "no message in 10 s (a type hash mismatch is silent: check [ros2] distro)"

step "ros2 topic hz $topic (5 s): about [ros2] rate_hz (200), or the chip's rate if lower"
# ros2 topic hz under-reports fast topics (ros2/ros2cli#871); trust it to a few percent at 200 Hz
timeout 6 ros2 topic hz "$topic" || true

step "ros2 topic info -v $topic: a publisher on node imud, RELIABLE, KEEP_LAST 5"
timeout 10 ros2 topic info -v "$topic" || bad "topic info failed"

step "ros2 topic echo --once /diagnostics: a status 'imud: $dev', level 0 (OK) and 'running at ... Hz'"
diag=$(timeout 10 ros2 topic echo --once /diagnostics 2>&1); echo "$diag"
grep -qF "imud: $dev" <<<"$diag" || bad "no status for $dev on /diagnostics ([ros2] diagnostics = true?)"

[ "$fail" -eq 0 ] && printf '\nall checks OK\n' || printf '\nsome checks NOT OK (above)\n'
exit "$fail"
