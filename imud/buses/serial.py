"""Serial links (UART, RS422 through a USB adapter) over the `serial.Serial` (pyserial) subset.

A serial chip has no register convention of its own on the wire: its driver gets the port itself
and speaks the chip's protocol (request/response frames, or a datagram stream it must find the
boundaries of). Simulated serial chips sit behind a real pseudo-terminal (`imud.sim.pty`), which
the same function opens, so the driver under test is the driver that runs on `/dev/ttyUSB0`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from imud.errors import BusError, open_error


@runtime_checkable
class SerialPort(Protocol):
    """What drivers may call on a `serial.Serial`. Opened non-blocking (`timeout = 0`): a read
    returns what has arrived; a driver waiting for an answer sets `timeout` itself."""

    port: str | None
    baudrate: int
    timeout: float | None
    is_open: bool

    @property
    def in_waiting(self) -> int: ...

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes, /) -> int | None: ...

    def reset_input_buffer(self) -> None: ...

    def open(self) -> None:
        """Open the port again (same path and settings): a USB adapter that was unplugged and
        plugged back in is a new device node."""

    def close(self) -> None: ...


def char_time_ns(baud: int, bits_per_char: int = 10) -> float:
    """Time one character takes on the wire (8N1: start + 8 data + stop = 10 bits)."""
    return bits_per_char * 1e9 / baud


def open_serial(port: str, baud: int) -> SerialPort:
    """Open a serial port at `baud`, 8N1, no flow control, raw, non-blocking, exclusive."""
    import serial

    try:
        s = serial.Serial(port, baudrate=baud, timeout=0, write_timeout=1.0, exclusive=True)
    except serial.SerialException as e:
        cause = e.__cause__ or e.__context__  # pyserial wraps the OSError of open()
        if isinstance(cause, FileNotFoundError | PermissionError):
            hint = "check the port name (ls /dev/serial/by-id/) or enable the UART"
            raise open_error(port, cause, hint, "dialout") from e
        raise BusError(e.errno or 0, f"cannot open {port}: {e}") from e
    except ValueError as e:  # pyserial's own check of the settings
        raise BusError(0, f"cannot open {port}: {e}") from e
    port_: SerialPort = s
    return port_
