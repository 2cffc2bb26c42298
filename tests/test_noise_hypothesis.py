"""`imud noise` on any CSV the documented format allows, and some it does not: any length (0, 1,
2, ... rows), stamp gaps, NaN or empty fields. Always an answer (exit 0) or a clear message
(exit 2, naming the file), never a traceback."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imud.cli.noise import noise

HEADER = "timestamp_ns,ax,ay,az,gx,gy,gz\n"


@st.composite
def recordings(draw: st.DrawFn) -> str:
    n = draw(st.integers(0, 60))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    steps = np.full(n, 10_000_000, dtype=np.int64)
    for i in draw(st.lists(st.integers(0, max(n - 1, 0)), max_size=4)):
        if n:
            steps[i] *= draw(st.integers(2, 50))  # a stamp gap
    t = 10**18 + np.cumsum(steps)
    rows = []
    bad = set(draw(st.lists(st.integers(0, max(n - 1, 0)), max_size=5))) if n else set()
    for i in range(n):
        v = [f"{x:.6g}" for x in rng.normal(0.0, 0.01, 6) + np.array([0, 0, 9.81, 0, 0, 0])]
        if i in bad:
            v[draw(st.integers(0, 5))] = draw(st.sampled_from(["nan", "", "NaN", "inf"]))
        rows.append(f"{t[i]}," + ",".join(v))
    return HEADER + "".join(r + "\n" for r in rows)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(text=recordings())
def test_any_csv_gives_an_answer_or_a_message(tmp_path: Path, text: str) -> None:
    path = tmp_path / "r.csv"
    path.write_text(text)
    r = CliRunner().invoke(noise, [str(path), "--json"])
    assert r.exit_code in (0, 2), (r.exit_code, r.output, r.exception)
    assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
    assert "Traceback" not in r.output
    if r.exit_code == 2:
        assert str(path) in r.output or "r.csv" in r.output, r.output


def test_short_clean_recordings_answer_or_say_why(tmp_path: Path) -> None:
    """3 .. 12 clean rows: the fit has one or two taus; it answers (N from them)."""
    rng = np.random.default_rng(0)
    for n in range(3, 13):
        path = tmp_path / f"s{n}.csv"
        rows = [f"{10**18 + i * 10**7}," + ",".join(f"{x:.6g}" for x in rng.normal(0.0, 0.01, 6)
                + np.array([0, 0, 9.81, 0, 0, 0])) for i in range(n)]  # fmt: skip
        path.write_text(HEADER + "\n".join(rows) + "\n")
        r = CliRunner().invoke(noise, [str(path), "--json"])
        assert r.exit_code in (0, 2), (n, r.output)
        assert r.exception is None or isinstance(r.exception, SystemExit), (n, r.exception)
