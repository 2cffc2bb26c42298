"""The host side of the BNO055 UART protocol, as a `RegisterDevice` (docs/chips/bno055.md).

Requests: `AA 00 reg len data...` (write) and `AA 01 reg len` (read). Answers: `EE status` to a
write (01 = done), `BB len data...` to a read, or `EE status` when a read failed. The chip's
receiver is fragile: requests go out two bytes at a time with ~2 ms between chunks (Linux's
bno055_ser_core does the same after seeing the chip overflow), stale input is dropped before each
request, and a busy or garbled answer is retried a bounded number of times. An answer that says
the request itself is wrong (no such register, read-only, length) is raised at once, naming the
status code and what it means.

A read also records when the chip took its snapshot (`latch`): not before the request's last
byte could have reached it, and no later than the answer's head (or the whole answer) could
have taken on the wire before it arrived. The driver gives these brackets to the sample grid.
`prepare_read` sends the next read's first chunk ahead (the chip waits up to 30 ms for the
rest), so the read itself is one chunk and its snapshot follows its start by two characters,
not 2 ms: what lets the driver place reads between the chip's samples.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from imud.buses.serial import SerialPort, char_time_ns
from imud.chips.api import DriverCounters
from imud.chips.bno055.registers import UART_MAX_LENGTH, Uart, UartStatus
from imud.clock import Clock
from imud.errors import BusError

CHUNK_BYTES = 2
CHUNK_GAP_NS = 2_000_000  # Linux: usleep_range(2000, 3000) between 2-byte chunks
RESPONSE_TIMEOUT_NS = 100_000_000  # Linux: 100 ms
TRIES = 5  # Linux: retry_max = 5
BUSY_RETRY_NS = 2_000_000  # after 0x07: the chip clears it itself once its fusion step is done
QUIET_NS = 40_000_000  # > 30 ms: the chip's receiver drops a half-received request
PREPARED_MAX_NS = 20_000_000  # a read's first chunk sent ahead is completed within this

MEANING: dict[int, str] = {
    UartStatus.WRITE_SUCCESS: "write done",
    UartStatus.READ_FAIL: "the chip could not read the register",
    UartStatus.WRITE_FAIL: "the chip could not write the register",
    UartStatus.REGMAP_INVALID_ADDRESS: "no such register on the selected page",
    UartStatus.REGMAP_WRITE_DISABLED: "the register is read-only (or writable only in CONFIG mode)",
    UartStatus.WRONG_START_BYTE: "the request did not start with 0xAA: bytes were lost or "
    "garbled on the line",
    UartStatus.BUS_OVER_RUN_ERROR: "the chip's receive buffer overran while it was busy "
    "(fusion); it recovers by itself",
    UartStatus.MAX_LENGTH_ERROR: f"more than {UART_MAX_LENGTH} bytes asked",
    UartStatus.MIN_LENGTH_ERROR: "a length of 0 bytes",
    UartStatus.RECEIVE_CHARACTER_TIMEOUT: "more than 30 ms between two bytes of the request: "
    "the chip dropped it",
}
# the request itself is wrong: retrying cannot help
FATAL = frozenset(
    {
        UartStatus.REGMAP_INVALID_ADDRESS,
        UartStatus.REGMAP_WRITE_DISABLED,
        UartStatus.MAX_LENGTH_ERROR,
        UartStatus.MIN_LENGTH_ERROR,
    }
)
_START, _WRITE, _READ = int(Uart.START), int(Uart.WRITE), int(Uart.READ)
_READ_OK, _STATUS = int(Uart.READ_RESPONSE), int(Uart.STATUS_RESPONSE)
_DONE, _BUSY = int(UartStatus.WRITE_SUCCESS), int(UartStatus.BUS_OVER_RUN_ERROR)


def describe_status(code: int) -> str:
    """`0x07 BUS_OVER_RUN_ERROR (the chip's receive buffer overran ...)`."""
    try:
        name = UartStatus(code).name
    except ValueError:
        return f"0x{code:02x} (not a status the datasheet defines)"
    return f"0x{code:02x} {name} ({MEANING[code]})"


class UartError(BusError):
    """A request the chip refused or never answered; `status` is its last status code, if any."""

    def __init__(self, message: str, status: int | None = None) -> None:
        super().__init__(0, message)
        self.status = status


@dataclass
class UartStats:
    """What the link went through, for `imud status`."""

    requests: int = 0
    retries: int = 0
    timeouts: int = 0
    bad_frames: int = 0
    status_answers: dict[str, int] = field(default_factory=dict)  # error answers by name

    def as_dict(self) -> dict[str, object]:
        return {
            "requests": self.requests,
            "retries": self.retries,
            "timeouts": self.timeouts,
            "bad_frames": self.bad_frames,
            "error_answers": dict(self.status_answers),
        }


class Bno055Uart:
    """Register reads and writes over the BNO055's UART. Blocking; owned by the bus worker."""

    address = 0  # a UART has no bus address; kept for the RegisterDevice interface

    def __init__(
        self,
        port: SerialPort,
        clock: Clock,
        counters: DriverCounters,
        tries: int = TRIES,
        response_timeout_ns: int = RESPONSE_TIMEOUT_NS,
    ) -> None:
        self.port = port
        self.clock = clock
        self.counters = counters
        self.tries = tries
        self.char_ns = char_time_ns(port.baudrate)
        port.timeout = response_timeout_ns / 1e9  # a read waits this long for its bytes
        self.timeout_ms = response_timeout_ns / 1e6
        self.stats = UartStats()
        self.latch: tuple[int, int] = (0, 0)  # host-time brackets of the last read's snapshot
        self._prepared: int | None = None  # when a read request's first chunk went out ahead

    def prepare_read(self) -> None:
        """Send the next read request's first chunk (start byte and read op) now: the next read
        then sends only its register and length, so the 2 ms pause between chunks is over
        before it starts and the chip's snapshot follows the read's start by a few character
        times instead (what lets a poller place it). Within PREPARED_MAX_NS, or it is dropped."""
        self._drop_prepared()
        self.port.reset_input_buffer()
        self.port.write(bytes([_START, _READ]))
        self._prepared = self.clock.now_ns()

    def _drop_prepared(self) -> None:
        """A first chunk sent ahead and not completed in time (or a write coming instead): wait
        until the chip's receiver has dropped it, and drop its status answer."""
        if self._prepared is None:
            return
        wait = self._prepared + QUIET_NS - self.clock.now_ns()
        self._prepared = None
        if wait > 0:
            self.clock.sleep_ns(wait)
        self.port.reset_input_buffer()

    # --- RegisterDevice ---------------------------------------------------------------------
    def read(self, register: int, length: int) -> bytes:
        if not 1 <= length <= UART_MAX_LENGTH:
            raise ValueError(f"a BNO055 UART read takes 1 to {UART_MAX_LENGTH} bytes, not {length}")
        return self._transact(_READ, register, length, b"")

    def read_u8(self, register: int) -> int:
        return self.read(register, 1)[0]

    def write_u8(self, register: int, value: int) -> None:
        self._transact(_WRITE, register, 1, bytes([value & 0xFF]))

    def write(self, register: int, data: bytes) -> None:
        """A burst write to consecutive registers (at most 128 bytes)."""
        if not 1 <= len(data) <= UART_MAX_LENGTH:
            raise ValueError(f"a BNO055 UART write takes 1 to {UART_MAX_LENGTH} bytes")
        self._transact(_WRITE, register, len(data), data)

    def write_no_answer(self, register: int, value: int) -> None:
        """A write the chip does not answer: setting RST_SYS resets it before it can."""
        self._drop_prepared()
        self.port.reset_input_buffer()
        self._send(bytes([_START, _WRITE, register, 1, value & 0xFF]))

    def flush(self) -> None:
        """Drop whatever the chip sent that nobody asked for (boot noise, a late answer)."""
        self._drop_prepared()
        self.port.reset_input_buffer()

    # --- protocol ---------------------------------------------------------------------------
    def _send(self, frame: bytes, ahead: int | None = None) -> int:
        """Send in 2-byte chunks (the first already sent at `ahead`, if given); returns the
        earliest instant the chip can have the whole request (the last chunk's start plus its
        bytes' time on the wire)."""
        t_last = 0
        first = 0 if ahead is None else CHUNK_BYTES
        for i in range(first, len(frame), CHUNK_BYTES):
            if i == first and ahead is not None:  # the pause after the chunk sent ahead
                self.clock.sleep_ns(max(0, ahead + CHUNK_GAP_NS - self.clock.now_ns()))
            elif i:
                self.clock.sleep_ns(CHUNK_GAP_NS)
            chunk = frame[i : i + CHUNK_BYTES]
            t_last = self.clock.now_ns() + int(len(chunk) * self.char_ns)
            self.port.write(chunk)
        return t_last

    def _transact(self, op: int, register: int, length: int, data: bytes) -> bytes:
        what = f"{'read' if op == _READ else 'write'} of register 0x{register:02x} ({length} B)"
        last = "no attempt"
        last_status: int | None = None
        prepared = self._prepared
        if prepared is not None and (
            op != _READ or self.clock.now_ns() - prepared > PREPARED_MAX_NS
        ):
            self._drop_prepared()
            prepared = None
        for attempt in range(self.tries):
            if attempt:
                self.stats.retries += 1
            self.stats.requests += 1
            frame = bytes([_START, op, register, length]) + data
            if prepared is not None and not attempt:  # its first chunk is out: nothing stale
                self._prepared = None
                t_sent = self._send(frame, ahead=prepared)
            else:
                self.port.reset_input_buffer()  # stale input would be taken for the answer
                t_sent = self._send(frame)
            head = self.port.read(2)
            t_head = self.clock.now_ns()
            if len(head) < 2:
                self.stats.timeouts += 1
                got = f" (only {head.hex()})" if head else ""
                last = f"no answer within {self.timeout_ms:g} ms{got}"
                continue  # that wait outlasted the chip's 30 ms receive timeout
            kind, value = head[0], head[1]
            if kind == _STATUS and not (op == _READ and value == _DONE):
                if op == _WRITE and value == _DONE:
                    return b""
                last_status, last = value, f"answered {describe_status(value)}"
                name = UartStatus(value).name if value in MEANING else f"0x{value:02x}"
                self.stats.status_answers[name] = self.stats.status_answers.get(name, 0) + 1
                if value in FATAL:
                    raise UartError(f"BNO055 UART {what}: {last}", value)
                self.clock.sleep_ns(BUSY_RETRY_NS if value == _BUSY else QUIET_NS)
                continue
            if kind == _READ_OK and op == _READ and value == length:
                body = self.port.read(length)
                t_done = self.clock.now_ns()
                if len(body) == length:
                    # the answer began no later than its head's and its whole length's time
                    # on the wire before each arrived: the head bounds it tighter when the
                    # tail came late (a USB adapter's frames, a busy host)
                    t_after = min(
                        t_head - int(2 * self.char_ns), t_done - int((2 + length) * self.char_ns)
                    )
                    self.latch = (t_sent, max(t_sent, t_after))
                    return body
                self.stats.timeouts += 1
                last = f"answer cut short: {len(body)} of {length} data bytes"
                continue
            # line noise, a lost byte, or an answer to some other request: out of step
            self.counters.bad_transfers += 1
            self.stats.bad_frames += 1
            last = f"unexpected answer {head.hex(' ')} (expected BB {length:02x} or EE xx)"
            self.clock.sleep_ns(QUIET_NS)  # let the rest of it arrive, then drop it
        raise UartError(f"BNO055 UART {what}: {last}, after {self.tries} tries", last_status)
