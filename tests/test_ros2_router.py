"""The README's ROS 2 set-up, as it is, in a private network namespace (`unshare -n`: ports 7447
and 7450 there are this test's alone): configs/sim-ros2.toml unchanged, a Zenoh router on 7447
standing in for `rmw_zenohd` and started after the daemon (imud keeps trying to reach it), and
a "ROS node": a Zenoh peer that knows only the router, subscribed the way rmw_zenoh subscribes.
It receives imud's messages with their attachment and sees imud's node and publishers."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # the quick start's five devices for ~10 s of real time

REPO = Path(__file__).resolve().parent.parent

SCRIPT = r"""
import json, signal, subprocess, sys, time, zenoh

def conf(**kw):
    base = {"scouting": {"multicast": {"enabled": False}}}
    return zenoh.Config.from_json5(json.dumps({**base, **kw}))

log = open(sys.argv[1], "wb")
run = [sys.executable, "-m", "imud", "run", "--config", "configs/sim-ros2.toml"]
daemon = subprocess.Popen(run, stderr=log)
time.sleep(2.0)  # the daemon runs without the router, then the router comes
router = zenoh.open(conf(mode="router", listen={"endpoints": ["tcp/127.0.0.1:7447"]}))
node = zenoh.open(conf(mode="peer", connect={"endpoints": ["tcp/127.0.0.1:7447"]}))
key = ("0/imud/imu0/imu/data_raw/sensor_msgs::msg::dds_::Imu_/"
       "RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b")
sub = node.declare_subscriber(key, zenoh.handlers.FifoChannel(10000))
got, end = [], time.monotonic() + 30
while len(got) < 50 and time.monotonic() < end:
    s = sub.try_recv()
    if s is None:
        time.sleep(0.01)
        continue
    got.append(len(s.attachment.to_bytes()) if s.attachment is not None else 0)
tokens, end = [], time.monotonic() + 30  # tokens reach the node through the router: ask again
DEVICES = ("imu0", "imu1", "icm0", "bmi0", "bno0")
def complete(tokens):
    return any("/NN/" in t for t in tokens) and all(
        any(f"%imud%{d}%imu%" in t for t in tokens) for d in DEVICES)
while not complete(tokens) and time.monotonic() < end:
    tokens = [str(r.ok.key_expr) for r in node.liveliness().get("@ros2_lv/0/**", timeout=5)
              if r.ok]
    time.sleep(0.2)
daemon.send_signal(signal.SIGTERM)
code = daemon.wait(timeout=20)
print(json.dumps({"attachments": got, "tokens": tokens, "code": code}))
"""


@pytest.mark.skipif(shutil.which("unshare") is None, reason="needs unshare (util-linux)")
def test_a_ros_node_behind_the_router_receives_the_quick_start(tmp_path: Path) -> None:
    log = tmp_path / "daemon.log"
    r = subprocess.run(
        ["unshare", "-n", "sh", "-c", 'ip link set lo up && exec "$0" -c "$1" "$2"',
         sys.executable, SCRIPT, str(log)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr + log.read_text()
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["code"] == 0, log.read_text()
    assert len(out["attachments"]) == 50 and set(out["attachments"]) == {33}
    tokens = out["tokens"]
    assert any(t.endswith("/NN/%/%imud/imud") for t in tokens), tokens
    for device in ("imu0", "imu1", "icm0", "bmi0", "bno0"):
        assert any(f"/MP/%/%imud/imud/%imud%{device}%imu%" in t for t in tokens), (device, tokens)
