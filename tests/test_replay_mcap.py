"""What a recording is good for, through the real CLI: `imud replay` publishes it as the daemon
does (a second recorder, `imud echo` and `imud status` take it for a daemon), `imud export`
writes its CSV, `imud calibrate --from FILE.mcap` calibrates from it. The round trip: record the
daemon, replay, record the replay: the native channels are the same bytes, batch for batch.
Expected values come from the test's own decoding of the recorded batches."""

from __future__ import annotations

import itertools
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from imud.recording.schemas import batch_wire
from imud.wire import decode
from tests.daemon_fixture import DaemonProc
from tests.helpers import free_port

CONFIG = """
[[device]]
name = "still0"
chip = "mpu6050"
bus = { kind = "sim", bus = "simP", address = 0x68 }
odr_hz = 500
dlpf_hz = 98
[device.sim]
seed = 9

[[device]]
name = "fast0"
chip = "icm42688p"
bus = { kind = "sim", bus = "spiP", cs = 0 }
odr_hz = 2000
"""


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[DaemonProc, Path]]:
    d = DaemonProc(Path(tmp_path_factory.mktemp("replay")), CONFIG)
    d.wait_started()
    out = d.config.parent / "orig.mcap"
    r = d.cli("record", "--connect", d.endpoint, "-o", str(out), "--duration", "3")
    assert r.returncode == 0, r.stdout + r.stderr
    yield d, out
    code, _ = d.stop()
    assert code == 0, d.log.read_text()


# The slow-turn and wandering-mean tests refuse a still capture with probability --significance
# (0.01 by default): these tests read a recording through the CLI, not the verdict, so they make
# that chance nil.
SURE = ("--significance", "1e-9")


def natives(path: Path) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    with open(path, "rb") as f:
        for _, ch, m in make_reader(f).iter_messages():
            if ch is not None and ch.topic.endswith("/batch"):
                out.setdefault(ch.topic.split("/")[2], []).append(batch_wire(m.data))
    return out


def imud(*args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "imud", *args], capture_output=True, text=True, timeout=timeout
    )


def replay(orig: Path, *args: str) -> tuple[subprocess.Popen[str], str]:
    """`imud replay ORIG ARGS` on a free loopback port: the process and its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    player = subprocess.Popen(
        [sys.executable, "-m", "imud", "replay", str(orig), "--listen", endpoint, *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    return player, endpoint


def answering(endpoint: str) -> subprocess.CompletedProcess[str]:
    """`imud status --json` against a replay, once it listens (a bound for a broken one)."""
    for _ in range(100):
        r = imud("status", "--connect", endpoint, "--json", timeout=30)
        if r.returncode == 0:
            return r
        time.sleep(0.1)
    return r


def replay_recorded(src: Path, again: Path, seconds: float = 4.0) -> str:
    """`imud replay SRC --wait --rate 2` recorded by `imud record -o AGAIN` once it answers as a
    daemon; the replay's stderr (it exited 0)."""
    player, endpoint = replay(src, "--wait", "--rate", "2")
    try:
        assert answering(endpoint).returncode == 0
        r = imud("record", "--connect", endpoint, "-o", str(again), "--duration", str(seconds))
        assert r.returncode == 0, r.stdout + r.stderr
        _, err = player.communicate(timeout=60)
    finally:
        player.kill()
    assert player.returncode == 0, err
    return err


def test_replay_then_record_gives_the_same_native_bytes(
    recording: tuple[DaemonProc, Path], tmp_path: Path
) -> None:
    _, orig = recording
    player, endpoint = replay(orig, "--wait", "--rate", "2")
    try:
        again = tmp_path / "again.mcap"
        r = answering(endpoint)
        assert r.returncode == 0, r.stderr
        assert '"replaying": "' in r.stdout and '"chip": "icm42688p"' in r.stdout
        assert '"state": "running"' in r.stdout  # as a daemon's, so every client takes it
        r = imud("record", "--connect", endpoint, "-o", str(again), "--duration", "4")
        assert r.returncode == 0, r.stdout + r.stderr
        _, err = player.communicate(timeout=60)
    finally:
        player.kill()
    assert player.returncode == 0, err
    a, b = natives(orig), natives(again)
    assert set(a) == set(b) == {"still0", "fast0"}
    for device in a:
        assert b[device] == a[device], device  # batch for batch, byte for byte
    # the replay served the recorded config: the second file has the ROS 2 messages and the
    # config too, the same messages as the first
    with open(orig, "rb") as f1, open(again, "rb") as f2:
        r1, r2 = make_reader(f1), make_reader(f2)
        assert "imud.toml" in [x.name for x in r2.iter_attachments()]
        m1 = [m.data for _, c, m in r1.iter_messages() if c and c.topic == "/still0/imu/data_raw"]
        m2 = [m.data for _, c, m in r2.iter_messages() if c and c.topic == "/still0/imu/data_raw"]
    assert m2 and set(m2) <= set(m1)


def test_export_writes_the_recorded_samples(
    recording: tuple[DaemonProc, Path], tmp_path: Path
) -> None:
    _, orig = recording
    out = tmp_path / "still0.csv"
    r = imud("export", str(orig), "--csv", str(out), "--device", "still0")
    assert r.returncode == 0, r.stdout + r.stderr
    rows = np.loadtxt(out, delimiter=",", comments="#", skiprows=1 + 6)
    batches = [decode(p) for p in natives(orig)["still0"]]
    t = np.concatenate([b.t_ns for b in batches])
    accel = np.concatenate([b.accel for b in batches])
    assert rows.shape[0] == t.size
    np.testing.assert_array_equal(rows[:, 1:4].astype(np.float32), accel)
    assert "# samples: raw (uncorrected)" in out.read_text()[:400]


def test_calibrate_reads_a_device_of_the_recording(
    recording: tuple[DaemonProc, Path], tmp_path: Path
) -> None:
    """The still device's gyro bias from the MCAP file is its recorded samples' mean; the same
    as from the CSV export (the other route into the same estimator)."""
    import json

    _, orig = recording
    r = imud("calibrate", "gyro", "--from", str(orig), "--device", "still0", "--dry-run",
             "--json", *SURE)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    bias = np.array(json.loads(r.stdout)["bias"])
    gyro = np.concatenate([decode(p).gyro for p in natives(orig)["still0"]]).astype(np.float64)
    np.testing.assert_allclose(bias, gyro.mean(axis=0), rtol=0, atol=1e-12)
    csv = tmp_path / "still0.csv"
    assert imud("export", str(orig), "--csv", str(csv), "--device", "still0").returncode == 0
    r = imud("calibrate", "gyro", "--from", str(csv), "--dry-run", "--json", *SURE)
    # the CSV holds each float32 as 9 digits, read back as float64: equal to 1e-9 rad/s
    np.testing.assert_allclose(json.loads(r.stdout)["bias"], bias, rtol=0, atol=1e-9)
    r = imud("calibrate", "gyro", "--from", str(orig), "--dry-run")
    assert r.returncode == 2 and "give --device NAME" in r.stderr


def foreign(path: Path) -> None:
    """An MCAP file of someone else's: one JSON topic, no imud batches."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="test")
        sid = w.register_schema("Pose", "jsonschema", b"{}")
        cid = w.register_channel("/pose", "json", sid)
        w.add_message(cid, 1, b"{}", 1)
        w.finish()


@pytest.mark.parametrize(
    ("make", "args", "says"),
    [
        (lambda p: p.write_bytes(b""), ("replay", "{f}"), "is empty"),
        (lambda p: p.write_text("a,b\n1,2\n"), ("replay", "{f}"), "is not an MCAP file"),
        (foreign, ("replay", "{f}"), "holds no imud batches (its topics: /pose)"),
        (foreign, ("export", "{f}", "--csv", "{d}/x.csv"), "holds no imud batches"),
        (None, ("replay", "{orig}", "--device", "nope"), "has no device 'nope'"),
        (None, ("replay", "{orig}", "--devices", "still0,nope"), "has no device 'nope' (it"),
        (None, ("export", "{orig}", "--csv", "{d}/x.csv"), "give --device NAME"),
        (None, ("replay", "{orig}", "--listen", "{taken}"), "cannot listen on"),
        (None, ("replay", "{d}/none.mcap"), "does not exist (nor split parts of it"),
        (None, ("export", "{orig}", "{orig}", "--csv", "{d}/x.csv"), "is named twice"),
    ],
)
def test_bad_input_is_said(
    recording: tuple[DaemonProc, Path], tmp_path: Path, make: object, args: tuple[str, ...],
    says: str,
) -> None:  # fmt: skip
    d, orig = recording
    f = tmp_path / "in.mcap"
    if callable(make):
        make(f)
    argv = [a.format(f=f, d=tmp_path, orig=orig, taken=d.endpoint) for a in args]
    r = imud(*argv, timeout=60)
    assert r.returncode == 2, r.stdout + r.stderr
    assert says in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_a_file_without_its_summary_is_read_with_a_warning(
    recording: tuple[DaemonProc, Path], tmp_path: Path
) -> None:
    _, orig = recording
    cut = tmp_path / "cut.mcap"
    data = orig.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    out = tmp_path / "cut.csv"
    r = imud("export", str(cut), "--csv", str(out), "--device", "still0")
    assert r.returncode == 0, r.stderr
    assert "has no summary" in r.stderr and "imud record --recover" in r.stderr


def test_a_split_recording_replays_and_exports_as_one(
    recording: tuple[DaemonProc, Path], tmp_path: Path
) -> None:
    """`-o NAME.mcap --split-duration 1` writes NAME_000.mcap, ...; `export NAME.mcap` and
    `replay NAME.mcap` take the parts as one recording: every part's batches, in order."""
    d, _ = recording
    split = tmp_path / "split.mcap"
    r = d.cli("record", "--connect", d.endpoint, "-o", str(split), "--duration", "3.5",
              "--split-duration", "1")  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    parts = sorted(tmp_path.glob("split_*.mcap"))
    assert len(parts) >= 3 and not split.exists()
    whole: dict[str, list[bytes]] = {}
    for p in parts:
        for device, batches in natives(p).items():
            whole.setdefault(device, []).extend(batches)
    out = tmp_path / "still0.csv"
    r = imud("export", str(split), "--csv", str(out), "--device", "still0")
    assert r.returncode == 0, r.stdout + r.stderr
    rows = np.loadtxt(out, delimiter=",", comments="#", skiprows=1 + 6)
    t = np.concatenate([decode(b).t_ns for b in whole["still0"]])
    assert rows.shape[0] == t.size
    # the parts named one by one (a shell's glob) are the same recording
    out2 = tmp_path / "still0-glob.csv"
    r = imud("export", *map(str, parts), "--csv", str(out2), "--device", "still0")
    assert r.returncode == 0, r.stdout + r.stderr
    rows2 = np.loadtxt(out2, delimiter=",", comments="#", skiprows=1 + 6)
    np.testing.assert_array_equal(rows2, rows)
    # named out of order: put in time order
    out3 = tmp_path / "still0-reversed.csv"
    r = imud("export", *map(str, parts[::-1]), "--csv", str(out3), "--device", "still0")
    assert r.returncode == 0, r.stdout + r.stderr
    np.testing.assert_array_equal(np.loadtxt(out3, delimiter=",", comments="#", skiprows=7), rows)
    again = tmp_path / "again.mcap"
    err = replay_recorded(split, again)
    assert f"{parts[-1].name} ({len(parts)} parts)" in err
    b = natives(again)
    for device in whole:
        assert b[device] == whole[device], device
    # a part and a copy of it overlap in time; a part gone from the series is named
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(parts[1].read_bytes())
    r = imud("export", str(parts[0]), str(parts[1]), str(copy), "--csv", str(tmp_path / "o.csv"),
             "--device", "still0")  # fmt: skip
    assert r.returncode == 2 and "overlap in time" in r.stderr, r.stderr
    parts[1].rename(tmp_path / "elsewhere.mcap")
    r = imud("replay", str(split))
    assert r.returncode == 2 and f"split part {parts[1].name} is missing" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.slow
def test_thirty_seconds_of_the_quick_start_round_trip(tmp_path: Path) -> None:
    """The issue's own check: 30 s of configs/sim.toml recorded, replayed (at twice the pace),
    the replay recorded: every device's native channel is the same bytes, batch for batch."""
    import re

    text = (Path(__file__).parent.parent / "configs" / "sim.toml").read_text()
    body = re.sub(r"(?ms)^\[zenoh\].*?(?=^\[)", "", text)  # DaemonProc writes its own [zenoh]
    d = DaemonProc(tmp_path, body)
    try:
        d.wait_started()
        orig = tmp_path / "sim.mcap"
        r = d.cli("record", "--connect", d.endpoint, "-o", str(orig), "--duration", "30",
                  timeout=120)  # fmt: skip
        assert r.returncode == 0, r.stdout + r.stderr
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    again = tmp_path / "again.mcap"
    replay_recorded(orig, again, 20.0)
    a, b = natives(orig), natives(again)
    assert set(a) == set(b) and len(a) == 5
    for device in a:
        assert b[device] == a[device], device


ROS_CONFIG = """
[ros2]
enabled = true
profiles = ["bridge"]

[[device]]
name = "imu0"
chip = "mpu6050"
bus = { kind = "sim", bus = "simQ", address = 0x68 }
odr_hz = 1000
dlpf_hz = 188
[device.sim]
seed = 12
motion = { kind = "poses", hold_s = 0.5, move_s = 0.5, sweep_s = 0.0 }
"""


def test_a_replay_has_the_recorded_configs_ros2_output(tmp_path: Path) -> None:
    """Recorded from a daemon whose [ros2] was on (the bridge profile): its replay publishes the
    ROS 2 messages again, on the bridge's keys, the same bytes as the recording holds."""
    import zenoh

    import imud.client as ic
    from imud.ros2 import bridge

    d = DaemonProc(tmp_path, ROS_CONFIG)
    try:
        d.wait_started()
        orig = tmp_path / "ros.mcap"
        r = d.cli("record", "--connect", d.endpoint, "-o", str(orig), "--duration", "3")
        assert r.returncode == 0, r.stdout + r.stderr
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    with open(orig, "rb") as f:
        recorded = {m.data for _, ch, m in make_reader(f).iter_messages()
                    if ch and ch.topic == "/imu0/imu/data_raw"}  # fmt: skip
    player, endpoint = replay(orig, "--wait")
    got: list[bytes] = []
    try:
        assert answering(endpoint).returncode == 0  # it listens (however loaded the machine)
        with ic.open_session(endpoint) as s:
            ros = s.declare_subscriber(
                bridge.data_key("/imu0/imu/data_raw"), lambda x: got.append(x.payload.to_bytes())
            )
            native = s.declare_subscriber(ic.data_key("imu0"), zenoh.handlers.RingChannel(1))
            _, err = player.communicate(timeout=60)  # --wait: it starts now, ends with the file
            time.sleep(0.5)
            ros.undeclare()
            native.undeclare()
    finally:
        player.kill()
    assert player.returncode == 0, err
    assert "ROS 2 output (bridge)" in err, err
    assert len(got) > 300  # 200 Hz for 3 s, less what the recording held back at its end
    assert all(p in recorded for p in got)


def test_apply_corrects_a_device_of_the_recording_as_of_its_csv(
    recording: tuple[DaemonProc, Path], tmp_path: Path
) -> None:
    """`calibrate apply --from FILE.mcap --device` writes what the same calibration applied to
    the device's exported CSV writes: the recording read the same way."""
    _, orig = recording
    cal = tmp_path / "still0.cal.toml"
    r = imud("calibrate", "gyro", "--from", str(orig), "--device", "still0", "--out", str(cal),
             *SURE)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    csv = tmp_path / "still0.csv"
    assert imud("export", str(orig), "--csv", str(csv), "--device", "still0").returncode == 0
    outs = []
    for src in (("--from", str(orig), "--device", "still0"), ("--from", str(csv))):
        out = tmp_path / f"corrected{len(outs)}.csv"
        r = imud("calibrate", "apply", "--calibration", str(cal), *src, "--out", str(out))
        assert r.returncode == 0, r.stdout + r.stderr
        rows = [x for x in out.read_text().splitlines() if not x.startswith("#")][1:]
        outs.append(np.loadtxt(rows, delimiter=","))
    assert outs[0].shape == outs[1].shape
    # the CSV route reads each float32 back as its 9 digits: equal to that
    np.testing.assert_allclose(outs[0][:, 1:7], outs[1][:, 1:7], rtol=0, atol=1e-6)
    assert abs(outs[0][:, 4:7].mean(axis=0)).max() < 1e-6  # the still gyro's bias taken out


def test_a_loop_goes_on_as_one_stream_stamped_now(
    recording: tuple[DaemonProc, Path], tmp_path: Path
) -> None:
    """--loop at 4x: the second pass's sequence numbers and stamps continue the first's (one
    stream to a subscriber, no seq gap between passes), stamped from now (--restamp is implied)."""
    import zenoh

    import imud.client as ic

    _, orig = recording
    player, endpoint = replay(orig, "--wait", "--loop", "--rate", "4", "--device", "still0")
    try:
        assert answering(endpoint).returncode == 0  # it listens (however loaded the machine)
        started = time.time_ns()
        file_samples = sum(decode(p).count for p in natives(orig)["still0"])
        got = []
        with ic.open_session(endpoint) as s:
            sub = s.declare_subscriber(ic.data_key("still0"), zenoh.handlers.RingChannel(100000))
            end = time.monotonic() + 60  # a bound for a broken replay, not a pace
            while sum(b.count for b in got) <= file_samples:  # into the second pass
                assert time.monotonic() < end, len(got)
                x = sub.try_recv()
                if x is None:
                    time.sleep(0.02)
                else:
                    got.append(decode(x.payload.to_bytes()))
            sub.undeclare()
    finally:
        player.terminate()
        player.wait(20)
    for a, b in itertools.pairwise(got):
        # no gap but what the recording announced, not even between passes
        assert b.first_seq == a.first_seq + a.count + b.lost_before
        assert b.t_ns[0] > a.t_ns[-1]
    assert abs(int(got[0].t_ns[0]) - started) < 5 * 10**9  # stamped about now, not as recorded


def test_live_calibration_runs_against_a_replay(
    recording: tuple[DaemonProc, Path], tmp_path: Path
) -> None:
    """`imud calibrate gyro --device` reads a replay's uncorrected stream as a daemon's: the
    bias of the looped still recording is its recorded samples' mean, near enough."""
    import json

    _, orig = recording
    player, endpoint = replay(orig, "--loop", "--device", "still0")
    try:
        assert answering(endpoint).returncode == 0
        out_file = str(tmp_path / "c.toml")
        r = imud("calibrate", "gyro", "--device", "still0", "--connect", endpoint,
                 "--out", out_file, "--duration", "4", "--dry-run", "--json", *SURE)  # fmt: skip
    finally:
        player.terminate()
        player.wait(20)
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)
    gyro = np.concatenate([decode(p).gyro for p in natives(orig)["still0"]]).astype(np.float64)
    np.testing.assert_allclose(out["bias"], gyro.mean(axis=0), atol=5e-4)


@pytest.mark.extra  # allantools (the dev extra)
def test_noise_reads_a_device_of_the_recording(recording: tuple[DaemonProc, Path]) -> None:
    """`imud noise FILE.mcap --device`: the Allan deviation of the samples the file holds,
    allantools' on the same numbers (one stretch: the recording lost nothing)."""
    import json

    allantools = pytest.importorskip("allantools")
    _, orig = recording
    batches = [decode(p) for p in natives(orig)["still0"]]
    assert all(b.lost_before == 0 for b in batches[1:])
    r = imud("noise", str(orig), "--device", "still0", "--json")
    assert r.returncode == 0, r.stdout + r.stderr
    out = json.loads(r.stdout)
    gyro = np.concatenate([b.gyro for b in batches]).astype(np.float64)
    t = np.concatenate([b.t_ns for b in batches])
    assert out["samples"] == gyro.shape[0] and out["stretches"] == 1
    rate = (t.size - 1) / ((t[-1] - t[0]) / 1e9)
    assert out["rate_hz"] == pytest.approx(rate)
    full = np.array(out["stride"]) == 1
    got = np.array(out["gyro_adev_rad_s"])[full]
    for ax in range(3):
        _, dev, _, _ = allantools.oadev(gyro[:, ax], rate=rate, data_type="freq",
                                        taus=np.array(out["tau_s"])[full])  # fmt: skip
        np.testing.assert_allclose(got[:, ax], dev, rtol=1e-9)
    r = imud("noise", str(orig))
    assert r.returncode == 2 and "give --device NAME" in r.stderr, r.stderr
