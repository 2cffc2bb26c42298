"""The BNO055 UART protocol, byte by byte, against a scripted port at virtual time.

Expected bytes are the data sheet's (BST-BNO055-DS000-14 rev 1.4 §4.7, p. 94): a write is
`AA 00 reg len data...` answered `EE 01`; a read is `AA 01 reg len` answered `BB len data...` or
`EE status`. Status codes: 01 WRITE_SUCCESS, 02 READ_FAIL, 03 WRITE_FAIL, 04
REGMAP_INVALID_ADDRESS, 05 REGMAP_WRITE_DISABLED, 06 WRONG_START_BYTE, 07 BUS_OVER_RUN_ERROR,
08 MAX_LENGTH_ERROR, 09 MIN_LENGTH_ERROR, 0A RECEIVE_CHARACTER_TIMEOUT."""

from __future__ import annotations

from collections import deque

import pytest

from imud.chips.api import DriverCounters
from imud.chips.bno055.uart import Bno055Uart, UartError
from imud.clock import VirtualClock

CHAR_NS = 10e9 / 115_200  # 8N1: ten bits a byte


class ScriptedPort:
    """A serial port whose chip answers each complete request with the next scripted answer
    (None: no answer), delivered at the link's rate after the request's last byte."""

    def __init__(self, clock: VirtualClock, answers: list[bytes | None]) -> None:
        self.clock = clock
        self.port = "scripted"
        self.baudrate = 115_200
        self.timeout: float | None = 0
        self.answers = deque(answers)
        self.writes: list[tuple[int, bytes]] = []
        self.requests: list[bytes] = []
        self.pending = bytearray()
        self.inbox = bytearray()
        self.flushes = 0

    @property
    def in_waiting(self) -> int:
        return len(self.inbox)

    def write(self, data: bytes, /) -> int:
        self.writes.append((self.clock.now_ns(), bytes(data)))
        self.pending += data
        if len(self.pending) >= 4:
            need = 4 if self.pending[1] == 0x01 else 4 + self.pending[3]
            if len(self.pending) >= need:
                self.requests.append(bytes(self.pending[:need]))
                del self.pending[:need]
                answer = self.answers.popleft() if self.answers else None
                if answer is not None:
                    self.inbox += answer
        return len(data)

    def read(self, size: int = 1) -> bytes:
        got = bytes(self.inbox[:size])
        del self.inbox[:size]
        if len(got) < size:  # pyserial waits out its timeout for what never comes
            self.clock.advance(int((self.timeout or 0) * 1e9))
        else:
            self.clock.advance(int(len(got) * CHAR_NS))
        return got

    def reset_input_buffer(self) -> None:
        self.inbox.clear()
        self.flushes += 1

    def close(self) -> None:
        pass


def make(answers: list[bytes | None], tries: int = 5) -> tuple[Bno055Uart, ScriptedPort]:
    clock = VirtualClock()
    port = ScriptedPort(clock, answers)
    return Bno055Uart(port, clock, DriverCounters(), tries=tries), port


def test_a_read_request_goes_out_two_bytes_at_a_time_and_its_answer_is_the_data() -> None:
    data = bytes(range(46))
    uart, port = make([bytes([0xBB, 46]) + data])
    assert uart.read(0x08, 46) == data
    assert port.requests == [bytes([0xAA, 0x01, 0x08, 0x2E])]
    (t0, c0), (t1, c1) = port.writes
    assert (c0, c1) == (b"\xaa\x01", b"\x08\x2e")
    assert t1 - t0 >= 2_000_000  # Linux's 2-3 ms between chunks: the chip's RX buffer is small


def test_a_write_request_and_its_acknowledgement() -> None:
    uart, port = make([b"\xee\x01", b"\xee\x01"])
    uart.write_u8(0x3D, 0x0C)  # OPR_MODE = NDOF
    uart.write(0x55, bytes([0xE8, 0xFF, 0xA5, 0x00]))
    assert port.requests == [
        bytes([0xAA, 0x00, 0x3D, 0x01, 0x0C]),
        bytes([0xAA, 0x00, 0x55, 0x04, 0xE8, 0xFF, 0xA5, 0x00]),
    ]
    assert [c for _, c in port.writes[:3]] == [b"\xaa\x00", b"\x3d\x01", b"\x0c"]


@pytest.mark.parametrize(
    ("code", "name"),
    [
        (0x04, "REGMAP_INVALID_ADDRESS"),
        (0x05, "REGMAP_WRITE_DISABLED"),
        (0x08, "MAX_LENGTH_ERROR"),
        (0x09, "MIN_LENGTH_ERROR"),
    ],
)
def test_an_answer_that_the_request_is_wrong_is_raised_at_once_naming_it(
    code: int, name: str
) -> None:
    uart, port = make([bytes([0xEE, code])] * 5)
    with pytest.raises(UartError) as e:
        uart.read_u8(0x70)
    assert len(port.requests) == 1  # no retry: the same request would fail the same way
    assert e.value.status == code
    assert f"0x{code:02x} {name}" in str(e.value) and "register 0x70" in str(e.value)


@pytest.mark.parametrize(
    ("code", "name", "meaning"),
    [
        (0x02, "READ_FAIL", "could not read"),
        (0x03, "WRITE_FAIL", "could not write"),
        (0x06, "WRONG_START_BYTE", "0xAA"),
        (0x07, "BUS_OVER_RUN_ERROR", "busy"),
        (0x0A, "RECEIVE_CHARACTER_TIMEOUT", "30 ms"),
    ],
)
def test_a_busy_or_garbled_answer_is_retried_then_raised_naming_it(
    code: int, name: str, meaning: str
) -> None:
    uart, port = make([bytes([0xEE, code])] * 5)
    with pytest.raises(UartError) as e:
        uart.read(0x08, 46)
    assert len(port.requests) == 5  # bounded
    assert e.value.status == code
    msg = str(e.value)
    assert f"0x{code:02x} {name}" in msg and meaning in msg and "after 5 tries" in msg
    assert uart.stats.status_answers == {name: 5}


def test_bus_overrun_is_retried_until_the_chip_answers() -> None:
    data = bytes(range(6))
    uart, port = make([b"\xee\x07", b"\xee\x07", bytes([0xBB, 6]) + data])
    t0 = port.clock.now_ns()
    assert uart.read(0x08, 6) == data
    assert len(port.requests) == 3 and uart.stats.retries == 2
    assert uart.stats.status_answers == {"BUS_OVER_RUN_ERROR": 2}
    assert port.clock.now_ns() - t0 < 30_000_000  # short waits: the chip clears 0x07 itself


def test_no_answer_times_out_and_says_so() -> None:
    uart, port = make([None] * 5, tries=2)
    t0 = port.clock.now_ns()
    with pytest.raises(UartError) as e:
        uart.read_u8(0x00)
    assert "no answer within 100 ms" in str(e.value) and "after 2 tries" in str(e.value)
    assert uart.stats.timeouts == 2
    assert port.clock.now_ns() - t0 >= 2 * 100_000_000


def test_an_answer_out_of_step_is_a_bad_transfer_and_the_link_resyncs() -> None:
    counters = DriverCounters()
    clock = VirtualClock()
    port = ScriptedPort(clock, [b"\x12\x34\x56", b"\xbb\x01\xa0"])
    uart = Bno055Uart(port, clock, counters)
    assert uart.read_u8(0x00) == 0xA0
    assert counters.bad_transfers == 1 and uart.stats.bad_frames == 1
    assert port.flushes == 2  # the stale tail is dropped before the retry


def test_stale_input_is_flushed_before_each_request() -> None:
    uart, port = make([b"\xbb\x01\xa0"])
    port.inbox += b"\xee\x07"  # a late answer to something earlier
    assert uart.read_u8(0x00) == 0xA0


def test_a_read_answer_of_the_wrong_length_is_not_taken() -> None:
    uart, _ = make([b"\xbb\x02\x00\x00", b"\xbb\x01\xa0"])
    assert uart.read_u8(0x00) == 0xA0
    assert uart.stats.bad_frames == 1


def test_the_snapshot_brackets_come_from_the_request_and_answer_times() -> None:
    """The chip latches after the request's last byte is in (last chunk sent + 2 characters)
    and before its answer starts (answer complete - 48 characters for 46 data bytes)."""
    uart, port = make([bytes([0xBB, 46]) + bytes(46)])
    uart.read(0x08, 46)
    t_last_chunk = port.writes[-1][0]
    t_done = port.clock.now_ns()
    assert uart.latch == (
        t_last_chunk + int(2 * CHAR_NS),
        max(t_last_chunk + int(2 * CHAR_NS), t_done - int(48 * CHAR_NS)),
    )


def test_the_reset_write_expects_no_answer() -> None:
    uart, port = make([])
    uart.write_no_answer(0x3F, 0x20)  # SYS_TRIGGER RST_SYS: the chip resets before answering
    assert port.requests == [bytes([0xAA, 0x00, 0x3F, 0x01, 0x20])]


def test_lengths_beyond_the_protocol_are_refused_before_sending() -> None:
    uart, port = make([])
    with pytest.raises(ValueError, match="1 to 128"):
        uart.read(0x08, 129)
    assert port.requests == []


def test_a_first_chunk_sent_ahead_leaves_only_the_last_two_bytes_to_the_read() -> None:
    """`prepare_read` sends `AA 01` at once; a read 5 ms later sends `08 2E` at once (the 2 ms
    pause is over), so the chip's snapshot follows the read's start by two characters."""
    uart, port = make([bytes([0xBB, 46]) + bytes(46)])
    uart.prepare_read()
    t_ahead = port.clock.now_ns()
    port.clock.advance(5_000_000)
    t_read = port.clock.now_ns()
    uart.read(0x08, 46)
    assert port.writes == [(t_ahead, b"\xaa\x01"), (t_read, b"\x08\x2e")]
    assert port.requests == [bytes([0xAA, 0x01, 0x08, 0x2E])]
    assert uart.latch[0] == t_read + int(2 * CHAR_NS)


def test_a_read_soon_after_its_first_chunk_still_waits_the_pause() -> None:
    uart, port = make([bytes([0xBB, 1, 0x0C])])
    uart.prepare_read()
    t_ahead = port.clock.now_ns()
    assert uart.read_u8(0x3D) == 0x0C
    assert port.writes[1][0] - t_ahead >= 2_000_000


def test_a_first_chunk_not_completed_in_time_is_waited_out_before_a_new_request() -> None:
    """A read 25 ms after its first chunk (the chip drops a request whose bytes are 30 ms
    apart), or a write: the half request is left to time out at the chip (40 ms from it), its
    status answer flushed, and the whole request sent afresh."""
    for late_ns, call in ((25_000_000, "read"), (0, "write")):
        uart, port = make([bytes([0xBB, 1, 0x0C]), b"\xee\x01"])
        uart.prepare_read()
        t_ahead = port.clock.now_ns()
        port.clock.advance(late_ns)
        port.inbox += b"\xee\x0a"  # RECEIVE_CHARACTER_TIMEOUT for the half request
        flushes = port.flushes
        if call == "read":
            assert uart.read_u8(0x3D) == 0x0C
        else:
            uart.write_u8(0x3D, 0x0C)
        t_fresh, chunk = port.writes[1]
        assert chunk == bytes([0xAA, 0x01 if call == "read" else 0x00])
        assert t_fresh - t_ahead >= 40_000_000, call
        assert port.flushes > flushes, call
