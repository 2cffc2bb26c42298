"""Bus errors counted by kind in status: a NAK (no ACK: wiring, pull-ups, a chip that reset)
is told from an adapter's EIO and a timeout, from the errno Linux's i2c-dev and spidev report."""

from __future__ import annotations

import errno

import pytest
from rich.console import Console

from imud.cli.status_view import status_view
from imud.errors import BUS_ERROR_KEYS, BusError, ErrorKind, error_kind
from tests.helpers import make_rig


@pytest.mark.parametrize(
    ("exc", "kind"),
    [
        (BusError(errno.EREMOTEIO, "Remote I/O error"), ErrorKind.NAK),  # i2c-dev: no ACK
        (OSError(errno.ENXIO, "No such device or address"), ErrorKind.NAK),  # some adapters
        (OSError(errno.EAGAIN, "arbitration lost"), ErrorKind.NAK),
        (BusError(errno.EIO, "Input/output error"), ErrorKind.EIO),
        (OSError(errno.ETIMEDOUT, "Connection timed out"), ErrorKind.TIMEOUT),
        (TimeoutError("serial read"), ErrorKind.TIMEOUT),
        (BusError(0, "short read"), ErrorKind.OTHER),
        (ValueError("not an OSError"), ErrorKind.OTHER),
    ],
)
def test_error_kind_from_errno(exc: BaseException, kind: ErrorKind) -> None:
    assert error_kind(exc) == kind


def test_a_nak_prone_bus_counts_its_naks_as_such() -> None:
    # the simulated I2C bus NAKs a fraction of transfers (errno EREMOTEIO, as i2c-dev does)
    rig = make_rig({"odr_hz": 200}, {"motion": {"kind": "still"}, "nak_rate": 0.02})
    rig.run(5.0)
    st = rig.runner.status().to_json()
    assert st["bus_errors"] > 0
    assert st["bus_errors_nak"] == st["bus_errors"]
    assert st["bus_errors_eio"] == st["bus_errors_timeout"] == st["bus_errors_other"] == 0
    assert set(BUS_ERROR_KEYS.values()) <= st.keys() and "garbled_transfers" in st
    console = Console(width=200, record=True)
    for r in status_view({"devices": [st]}, "tcp/127.0.0.1:7450", console):
        console.print(r)
    assert f"bus errors by kind: nak {st['bus_errors_nak']}" in console.export_text()
