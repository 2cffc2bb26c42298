"""What the docs show must work: every TOML block in the README and docs/ is a config, a config
fragment or a calibration file that imud accepts, and the standalone decoder in
docs/wire-format.md decodes what the daemon really publishes, the same as `imud.client`."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import imud.client as ic
from imud.calib.file import load_calibration
from imud.channels import CHANNELS
from imud.config import parse_config
from tests.daemon_fixture import DaemonProc

REPO = Path(__file__).resolve().parent.parent
DOCS = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
FENCE = re.compile(r"^```(\w+)\n(.*?)^```", re.M | re.S)


def blocks(lang: str) -> list[tuple[str, str]]:
    out = []
    for doc in DOCS:
        text = doc.read_text()
        for m in FENCE.finditer(text):
            if m.group(1) == lang:
                line = text[: m.start()].count("\n") + 1
                out.append((f"{doc.relative_to(REPO)}:{line}", m.group(2)))
    return out


MINIMAL_DEVICE = {"name": "doc0", "chip": "mpu6050", "bus": {"kind": "sim"}}


@pytest.mark.parametrize(("where", "body"), blocks("toml"), ids=lambda x: str(x)[:40])
def test_every_toml_block_in_the_docs_is_accepted(where: str, body: str, tmp_path: Path) -> None:
    raw: dict[str, Any] = tomllib.loads(body)
    if raw.get("format") == "imud-calibration" or ("version" in raw and "device" not in raw):
        path = tmp_path / "cal.toml"
        path.write_text(body)
        load_calibration(path)
        return
    if "device" not in raw:  # a fragment ([daemon], [zenoh]): it must fit a whole config
        raw = {**raw, "device": [MINIMAL_DEVICE]}
    for d in raw["device"]:
        cal = d.get("calibration")
        if cal is not None:
            assert not Path(cal).is_absolute(), f"{where}: use a relative calibration path"
            (tmp_path / cal).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / cal).write_text("version = 1\n")
    parse_config(raw, tmp_path)


def test_the_docs_have_toml_blocks_to_check() -> None:
    assert len(blocks("toml")) >= 2


def _doc_decoder() -> Any:
    (code,) = [
        body
        for where, body in blocks("python")
        if where.startswith("docs/wire-format.md") and "def decode" in body
    ]
    namespace: dict[str, Any] = {}
    exec(compile(code, "docs/wire-format.md", "exec"), namespace)
    return namespace["decode"]


CONFIG = """
[[device]]
name = "m0"
chip = "mpu6050"
bus = { kind = "sim", bus = "simA", address = 0x68 }
odr_hz = 500
[device.sim]
truth = true
motion = { kind = "tumble", rate_dps = [10.0, 20.0, 30.0] }

[[device]]
name = "b0"
chip = "bmi088"
bus = { kind = "sim", bus = "spiB", transport = "spi", cs = 0 }
gyro_bus = { kind = "sim", bus = "spiB", transport = "spi", cs = 1 }
odr_hz = 400
accel_odr_hz = 400
"""


def test_the_docs_decoder_decodes_what_the_daemon_sends(tmp_path: Path) -> None:
    decode = _doc_decoder()
    d = DaemonProc(tmp_path, CONFIG)
    try:
        d.wait_started()
        payloads = {
            key: d.collect(key, 0.8) for key in ("imud/m0/imu", "imud/m0/sim/truth", "imud/b0/imu")
        }
    finally:
        code, _ = d.stop()
    assert code == 0, d.log.read_text()
    for key, raw in payloads.items():
        assert raw, key
        for buf in raw:
            ours, theirs = ic.decode(buf), decode(buf)
            assert theirs["device"] == ours.device and theirs["kind"] == ours.kind
            assert theirs["first_seq"] == ours.first_seq
            assert (theirs["flags"], theirs["lost_before"]) == (ours.flags, ours.lost_before)
            np.testing.assert_array_equal(theirs["t_ns"], ours.t_ns)
            np.testing.assert_array_equal(theirs["sample_flags"], ours.sample_flags)
            assert {k for k in theirs if k in {i.key for i in CHANNELS.values()}} == {
                CHANNELS[c].key for c in ours.channels
            }
            for c, arr in ours.channels.items():
                np.testing.assert_array_equal(theirs[CHANNELS[c].key], arr)
    assert ic.decode(payloads["imud/m0/sim/truth"][0]).kind == 1


# a repository path with a file extension, not part of an absolute path (/etc/imud/imud.toml)
PATH_REF = re.compile(
    r"(?<![/\w.])((?:docs|imud|tests|bench|configs|systemd)/[\w/<>*.-]*\.(?:py|md|toml|service|rules|conf))\b"
)
# what points outside: a parent folder's files, the workspace's absolute paths, the notes the
# project started from (by their names); spelled as patterns so this file does not cite them
OUTSIDE = re.compile(r"(?<!\.)\.\./[a-z]|(?<![\w.])/w[o]rk/|seed-f[a]cts|chips-inv[e]nsense")
TEXT_FILES = [
    *DOCS,
    *sorted((REPO / "imud").rglob("*.py")),
    *sorted((REPO / "tests").glob("*.py")),
    *sorted((REPO / "bench").glob("*.py")),
    *sorted((REPO / "configs").glob("*.toml")),
    *sorted((REPO / "systemd").iterdir()),
]


@pytest.mark.parametrize("path", TEXT_FILES, ids=lambda p: str(p.relative_to(REPO)))
def test_code_and_docs_cite_only_files_inside_the_repository(path: Path) -> None:
    text = path.read_text()
    found = OUTSIDE.search(text)
    assert found is None, f"{path.name} cites {found and found.group()!r}, outside the repository"
    missing = []
    for ref in PATH_REF.findall(text):
        if "<" in ref or "*" in ref or ref.startswith("imud/chips/<"):
            continue  # a pattern, not a file
        if not (REPO / ref).exists():
            missing.append(ref)
    assert not missing, f"{path.name} cites files that do not exist: {missing}"
