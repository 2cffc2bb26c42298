"""BNO055 driver: identity, reset, units, mode, calibration offsets, and one burst read a poll
(docs/chips/bno055.md).

The chip has no FIFO and no sample counter: its data registers hold the newest 100 Hz output.
Over I2C the device runner spreads polls over each period; over the UART the poller says when
(uartpoll.py). A full read is one burst of ACC ... GRV, TEMP and CALIB_STAT (46 bytes from
0x08); a read whose data bytes equal the previous read's found no new sample (n = 0). Which
sample a read found follows from the read brackets, on the chip's sample grid (grid.py); the
driver counts the samples it delivers from that numbering (count.py), so every gap the grid
followed is counted exactly. A new sample whose read straddled a grid point is held until the
next read tells which of the two it was.

Calibration: CALIB_STAT is in every burst. The first time the chip reports itself fully
calibrated, the driver switches to CONFIG mode, reads the 22-byte profile, switches back and
saves the profile to a file (a thread does the file work, so the bus worker never waits on a
disk); at every start it writes a saved profile back in CONFIG mode and reads it back to check.
The mode switches wait out across polls instead of sleeping: the bus stays free meanwhile.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from imud.buses.registers import RegisterDevice
from imud.channels import Channel
from imud.chips.api import DriverCounters, FifoRead, RawBatch, RawChannel
from imud.chips.bno055 import registers as R
from imud.chips.bno055.config import MODES, Bno055Config, parse_axis_remap
from imud.chips.bno055.count import SampleCount
from imud.chips.bno055.grid import SampleGrid
from imud.chips.bno055.offsets import Offsets, OffsetsError, load_offsets, write_atomic
from imud.chips.bno055.uart import Bno055Uart
from imud.chips.bno055.uartpoll import PROBE_LEN, UartPoller
from imud.chips.fifotiming import FifoTiming
from imud.chips.regplan import RegisterPlan, RegisterSetting
from imud.clock import Clock
from imud.errors import BusError, DeviceIdentityError, RegisterMismatch
from imud.units import STANDARD_GRAVITY

log = logging.getLogger("imud.chips.bno055")

P0, P1 = R.Page0, R.Page1
CLOCK_TOLERANCE = 0.03  # the chip's own oscillator, assumed within 3 %
BOOT_POLLS = 5  # CHIP_ID reads after the reset wait before giving up
BOOT_POLL_NS = 100_000_000
STALE_NS = 250_000_000  # no new sample for this long: the chip reset or stalled
ACCEL_FULL_SCALE = math.floor(R.ACCEL_FUSION_RANGE_G * STANDARD_GRAVITY * R.ACC_LSB_PER_MS2)
UNIT_SEL = int(R.UnitSel.ORI_ANDROID | R.UnitSel.GYR_RPS)  # m/s^2, rad/s, deg C, Android
_FUSION = frozenset(int(m) for m in R.FUSION_MODES)
_WITH_MAG = frozenset({int(R.OprMode.NDOF), int(R.OprMode.NDOF_FMC_OFF), int(R.OprMode.AMG)})
_CALIB_ALL = int(R.CALIB_FULL)
_CALIB_NO_MAG = R.CALIB_SYS.mask | R.CALIB_GYR.mask | R.CALIB_ACC.mask
_DATA_BYTES = 45  # ACC ... GRV and TEMP: the bytes that change with each new sample
QUAT_NORM_RANGE = (0.9, 1.1)  # a valid fusion quaternion has |q| = 1 within a few LSB


def scales(mode: R.OprMode, gyro_range_dps: int) -> dict[Channel, float]:
    """SI units per LSB of each output the mode gives (UNIT_SEL m/s^2, rad/s, deg C)."""
    accel = 1.0 / R.ACC_LSB_PER_MS2
    out = {Channel.ACCEL: accel, Channel.TEMPERATURE: 1.0 / R.TEMP_LSB_PER_C}
    if int(mode) in _FUSION:
        out[Channel.GYRO] = 1.0 / R.GYR_LSB_PER_RPS
        out[Channel.ORIENTATION] = 1.0 / R.QUA_LSB_PER_UNIT
        out[Channel.LINEAR_ACCEL] = accel
        out[Channel.GRAVITY] = accel
    else:  # firmware 3.11 scales raw gyro data by its range (Linux bno055.c)
        out[Channel.GYRO] = math.radians(gyro_range_dps) / R.GYR_RAW_FULL_SCALE_COUNTS
    if int(mode) in _WITH_MAG:
        out[Channel.MAG] = 1e-6 / R.MAG_LSB_PER_UT
    return out


def decode_calib(stat: int) -> dict[str, int]:
    return {
        "sys": R.CALIB_SYS.get(stat),
        "gyro": R.CALIB_GYR.get(stat),
        "accel": R.CALIB_ACC.get(stat),
        "mag": R.CALIB_MAG.get(stat),
    }


def config_plan(cfg: Bno055Config) -> list[RegisterSetting]:
    """Page-0 settings written in CONFIG mode: power mode, units, axis remap."""
    fs = RegisterSetting.fields
    U = R.UnitSel
    (ax, sx), (ay, sy), (az, sz) = parse_axis_remap(cfg.axis_remap)
    signs = [(R.AxisSign.X, sx), (R.AxisSign.Y, sy), (R.AxisSign.Z, sz)]
    return [
        fs(P0.PWR_MODE, (R.PWR_MODE_FIELD, R.PwrMode.NORMAL)),
        RegisterSetting(P0.UNIT_SEL, set_bits=UNIT_SEL, clear_bits=U.ACC_MG | U.TEMP_F),
        fs(P0.AXIS_MAP_CONFIG, (R.AXIS_REMAP_X, ax), (R.AXIS_REMAP_Y, ay), (R.AXIS_REMAP_Z, az)),
        RegisterSetting(
            P0.AXIS_MAP_SIGN,
            set_bits=sum(int(b) for b, s in signs if s < 0),
            clear_bits=sum(int(b) for b, s in signs if s > 0),
        ),
    ]


def _alike(a: bytes, b: bytes) -> bool:
    """The same sample, as far as the shorter of the two reads tells (a probe reads the first
    PROBE_LEN bytes of a full read's)."""
    n = min(len(a), len(b))
    return a[:n] == b[:n]


@dataclass(frozen=True, slots=True)
class Held:
    """A new sample read, with what its read said of it: its bracket and the grid's range of
    indices it may have (in that grid epoch)."""

    body: bytes
    stat: int
    tb: int
    ta: int
    epoch: int
    seen: tuple[int, int]


class Bno055Driver:
    """Polled burst reads of a BNO055 over I2C or UART. Blocking; owned by its bus's worker."""

    fifo_capacity = 1  # no FIFO: a sample survives one period in the data registers
    poll_interval_ns = 0  # the runner adds a sweeping fraction of a period

    def __init__(
        self,
        cfg: Bno055Config,
        dev: RegisterDevice,
        clock: Clock,
        uart: Bno055Uart | None = None,
        counters: DriverCounters | None = None,
    ) -> None:
        self.cfg = cfg
        self.dev = dev
        self.clock = clock
        self.uart = uart
        self.counters = counters or DriverCounters()
        self.mode = MODES[cfg.mode]
        self.fusion = int(self.mode) in _FUSION
        self.nominal_period_ns = 1e9 / R.FUSION_RATE_HZ
        self.group_delay_ns = 0  # the filters' delay is not published (docs/timestamps.md)
        self.grid = SampleGrid(self.nominal_period_ns, CLOCK_TOLERANCE)
        self.poller = UartPoller(self.grid) if uart is not None else None
        self.next_poll_ns: int | None = None  # over a UART: the poller's plan
        self.calib_mask = _CALIB_ALL if int(self.mode) in _WITH_MAG else _CALIB_NO_MAG
        self.plan = RegisterPlan(dev, config_plan(cfg))
        self.mode_plan = RegisterPlan(
            dev, [RegisterSetting.fields(P0.OPR_MODE, (R.OPR_MODE_FIELD, self.mode))]
        )
        self.offsets_path = cfg.offsets_path
        self._gyro_range_dps = R.GYRO_DEFAULT_RANGE_DPS  # read back from the chip at start
        self.scale = scales(self.mode, self._gyro_range_dps)
        self.uid = b""
        self.firmware = ""
        self.bootloader = -1
        self.sys_status: int | None = None
        self.sys_err: int | None = None
        self.offsets_restored = "not yet"
        self.restored: Offsets | None = None
        self.saved: Offsets | None = None
        self.offsets_saved_at: str | None = None
        self.offsets_error: str | None = None
        self._lock = threading.Lock()  # the save thread reports through it
        self._reset_state()

    def _reset_state(self) -> None:
        self.grid.reset()
        self._prev: bytes | None = None  # the sample delivered last
        self._last_prefix = b""  # the previous read's first PROBE_LEN bytes (UART)
        self._last_body = b""  # the previous read's data bytes (I2C)
        self.count = SampleCount(self.grid)
        self._held: Held | None = None  # a new sample whose index the next read pins
        self.timing = FifoTiming()  # a break in the chip's output (its mode restarted)
        self._last_new_ns = self.clock.now_ns()
        self.calib: dict[str, int] | None = None
        self.calib_stat = 0
        self.repeated_reads = 0
        self.empty_reads = 0
        self.skipped_polls = 0
        self.invalid_quaternions = 0
        self.partial_samples = 0  # delivered from a probe: the motion sensors alone
        self._save_phase = 0  # 1: going to CONFIG, 2: back to the operating mode
        self._save_due_ns = 0
        self._save_tried = False

    # --- start ------------------------------------------------------------------------------
    def start(self) -> Iterator[int]:
        self._reset_state()
        if self.uart is not None:
            self.uart.flush()
        self.dev.write_u8(P0.PAGE_ID, 0)  # CHIP_ID is on page 0
        ids = self.dev.read(P0.CHIP_ID, 7)
        if not any(ids):  # booting (a chip that reset itself reads zeros for 650 ms): wait
            yield from self._await_boot(BOOT_POLLS + R.RESET_WAIT_NS // BOOT_POLL_NS)
            self.dev.write_u8(P0.PAGE_ID, 0)
            ids = self.dev.read(P0.CHIP_ID, 7)
        self._check_identity(ids)
        if self.uart is not None:
            self.uart.write_no_answer(P0.SYS_TRIGGER, R.SysTrigger.RST_SYS)
        else:
            with contextlib.suppress(BusError):  # the chip may not acknowledge: it resets
                self.dev.write_u8(P0.SYS_TRIGGER, R.SysTrigger.RST_SYS)
        self.counters.soft_resets += 1
        yield R.RESET_WAIT_NS
        yield from self._await_boot()
        self.dev.write_u8(P0.PAGE_ID, 0)
        if R.OPR_MODE_FIELD.get(self.dev.read_u8(P0.OPR_MODE)) != R.OprMode.CONFIG:
            self.dev.write_u8(P0.OPR_MODE, R.OprMode.CONFIG)  # the reset did not happen
            yield R.MODE_TO_CONFIG_WAIT_NS
        self.plan.write_all()
        crystal = R.SysTrigger.CLK_SEL if self.cfg.external_crystal else 0
        self.dev.write_u8(P0.SYS_TRIGGER, crystal)
        self._read_page1()
        self.scale = scales(self.mode, self._gyro_range_dps)
        self._restore_offsets()
        self.dev.write_u8(P0.OPR_MODE, self.mode)
        yield R.CONFIG_TO_MODE_WAIT_NS
        self.mode_plan.verify_all()
        self.sys_status, self.sys_err = self.dev.read(P0.SYS_STATUS, 2)
        self._last_new_ns = self.clock.now_ns()

    def _check_identity(self, ids: bytes) -> None:
        if ids[0] != R.CHIP_ID_VALUE:
            raise DeviceIdentityError(
                f"CHIP_ID (0x00) reads 0x{ids[0]:02x}, expected 0x{R.CHIP_ID_VALUE:02x} for a "
                "BNO055: check the wiring, the address (0x28/0x29, COM3) or the protocol pins "
                "(PS1 high for UART); a chip powered up less than 650 ms ago is still booting"
            )
        for reg, want, what in (
            (P0.ACC_ID, R.ACC_ID_VALUE, "accelerometer"),
            (P0.MAG_ID, R.MAG_ID_VALUE, "magnetometer"),
            (P0.GYR_ID, R.GYR_ID_VALUE, "gyroscope"),
        ):
            if ids[reg] != want:
                raise DeviceIdentityError(
                    f"{reg.name} (0x{reg:02x}) reads 0x{ids[reg]:02x}, expected 0x{want:02x}: "
                    f"the BNO055's {what} did not answer its microcontroller (still booting, "
                    "or a damaged chip)"
                )
        self.firmware = f"{ids[P0.SW_REV_ID_MSB]:x}.{ids[P0.SW_REV_ID_LSB]:02x}"
        self.bootloader = ids[P0.BL_REV_ID]

    def _await_boot(self, polls: int = BOOT_POLLS) -> Iterator[int]:
        for _ in range(polls):
            if self.uart is not None:
                self.uart.flush()  # whatever the chip said while it booted
            with contextlib.suppress(BusError):
                if self.dev.read_u8(P0.CHIP_ID) == R.CHIP_ID_VALUE:
                    return
            yield BOOT_POLL_NS
        raise DeviceIdentityError(
            f"the BNO055 did not answer CHIP_ID 0x{R.CHIP_ID_VALUE:02x} within "
            f"{(R.RESET_WAIT_NS + BOOT_POLLS * BOOT_POLL_NS) / 1e9:g} s of its reset"
        )

    def _read_page1(self) -> None:
        self.dev.write_u8(P0.PAGE_ID, 1)
        try:
            self.uid = self.dev.read(P1.UNIQUE_ID, R.UID_LEN)
            code = R.GYR_RANGE.get(self.dev.read_u8(P1.GYR_CONFIG_0))
        finally:
            self.dev.write_u8(P0.PAGE_ID, 0)
        if code >= len(R.GYRO_RANGES_DPS):
            raise DeviceIdentityError(f"GYR_CONFIG_0 range code {code} is reserved")
        self._gyro_range_dps = R.GYRO_RANGES_DPS[code]

    # --- calibration profile ----------------------------------------------------------------
    def _restore_offsets(self) -> None:
        """Write the saved profile back (CONFIG mode), and read it back to check."""
        self.restored = None
        try:
            offs = load_offsets(self.offsets_path, UNIT_SEL, self.uid)
        except OffsetsError as e:
            self.offsets_restored = f"error: {e}"
            log.warning("%s: not restoring calibration offsets: %s", self.cfg.name, e)
            return
        if offs is None:
            self.offsets_restored = "no file"
            return
        data = offs.to_bytes()
        if self.uart is not None:
            self.uart.write(P0.ACC_OFFSET_X_LSB, data)
        else:
            for i, b in enumerate(data):  # LSB before MSB: a field applies on its MSB
                self.dev.write_u8(P0.ACC_OFFSET_X_LSB + i, b)
        back = self.dev.read(P0.ACC_OFFSET_X_LSB, R.OFFSETS_LEN)
        if back != data:
            self.offsets_restored = (
                f"error: wrote {data.hex()} to 0x55-0x6A, read back {back.hex()}"
            )
            return
        self.offsets_restored = "ok"
        self.restored = offs

    def _begin_save(self) -> None:
        self.dev.write_u8(P0.OPR_MODE, R.OprMode.CONFIG)  # the profile reads only in CONFIG
        self._save_tried = True
        self._save_phase, self._save_due_ns = 1, self.clock.now_ns() + R.MODE_TO_CONFIG_WAIT_NS

    def _save_step(self) -> RawBatch:
        """One poll of the save: wait out a mode switch without the bus, or take the next step.
        The chip makes no samples meanwhile: the batch says so (resync, counted by the clock)."""
        now = self.clock.now_ns()
        self.timing.broke()
        idle = RawBatch(0, {}, self.timing.read(now, now))
        if now < self._save_due_ns:
            return idle
        if self._save_phase == 1:
            raw = self.dev.read(P0.ACC_OFFSET_X_LSB, R.OFFSETS_LEN)
            self.dev.write_u8(P0.OPR_MODE, self.mode)
            self._save_phase, self._save_due_ns = 2, self.clock.now_ns() + R.CONFIG_TO_MODE_WAIT_NS
            offs = Offsets.from_bytes(raw)
            threading.Thread(
                target=self._save_file, args=(offs,), name="bno055 offsets", daemon=True
            ).start()
            return idle
        self._save_phase = 0
        self.timing.broke()
        self.grid.new_phase()  # the chip's output grid restarted with its mode
        self._last_new_ns = now
        return self.read()

    def _save_file(self, offs: Offsets) -> None:
        saved_at = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        text = offs.to_toml(self.cfg.name, self.uid, UNIT_SEL, saved_at)
        try:
            write_atomic(self.offsets_path, text)
        except OSError as e:
            msg = (
                f"cannot save calibration offsets to {self.offsets_path}: {e.strerror or e}; "
                "set offsets_file to a writable path"
            )
            log.warning("%s: %s", self.cfg.name, msg)
            with self._lock:
                self.offsets_error = msg
            return
        log.info("%s: chip fully calibrated; offsets saved to %s", self.cfg.name, self.offsets_path)
        with self._lock:
            self.saved, self.offsets_saved_at, self.offsets_error = offs, saved_at, None

    # --- read -------------------------------------------------------------------------------
    def read(self) -> RawBatch:
        if self._save_phase:
            return self._save_step()
        t0 = self.clock.now_ns()
        if self.poller is not None and self.uart is not None:
            batch = self._read_uart(t0)
            self.next_poll_ns = self.poller.next_read(self.clock.now_ns(), self._held is not None)
            if not self._save_phase:
                self.uart.prepare_read()  # the next read's pause between chunks starts now
            return batch
        due = self.grid.next_due()
        if due is not None and t0 < due:
            # the read would latch before the next sample can exist: a repeat for sure. Leave
            # the bus alone; a later poll comes closer to the sample
            self.skipped_polls += 1
            return RawBatch(0, {}, FifoRead(t0, t0))
        data = self._burst(R.DATA_BURST_LEN)
        t1 = self.clock.now_ns()
        body = data[:_DATA_BYTES]
        new, self._last_body = body != self._last_body, body
        return self._take(data, t1, t0, t1, new)

    def _burst(self, length: int) -> bytes:
        data = self.dev.read(P0.ACC_DATA_X_LSB, length)
        if len(data) != length:
            self.counters.bad_transfers += 1
            raise BusError(0, f"burst from 0x08: {len(data)} of {length} bytes")
        return data

    def _read_uart(self, t0: int) -> RawBatch:
        """A probe or a full read, as the poller says (uartpoll.py). A read is new to the grid
        when its first PROBE_LEN bytes differ from the previous read's, probe or not. While the
        phase is sought, probes come too fast for full reads in between, and most samples are
        seen by a probe alone: what it read of one (the motion sensors) goes out, the rest
        marked invalid, rather than the sample being lost."""
        assert self.uart is not None and self.poller is not None
        probe = self.poller.probe_now(self._held is not None)
        data = self._burst(PROBE_LEN if probe else R.DATA_BURST_LEN)
        t1 = self.clock.now_ns()
        tb, ta = self.uart.latch
        self.poller.note(t0, tb, ta, probe)
        prefix = data[:PROBE_LEN]
        new, self._last_prefix = prefix != self._last_prefix, prefix
        return self._take(data, t1, tb, ta, new)

    def _no_news(self, empty: bool, t1: int) -> None:
        if empty and self._prev is not None:
            # zeros where there were data: a chip back in CONFIG mode after a reset of its
            # own reads so at once; asking OPR_MODE now finds it well within 100 ms
            self._check_mode()
        if t1 - self._last_new_ns > STALE_NS:
            self._stale(t1)

    def _take(self, data: bytes, t1: int, tb: int, ta: int, new: bool) -> RawBatch:
        """A burst latched within [tb, ta]: a full one, or a probe's first PROBE_LEN bytes;
        `new`: its sample is not the previous read's.

        A new sample whose index the grid cannot pin (the read straddled a sample's window) is
        held back, not delivered with a guessed count: the next read pins it (over a UART the
        poller places that read to; over I2C the next polls come within a period) and tells
        which of its possible indices it had, by repeating it or not. A probe's sample held
        and then read whole goes out whole."""
        stat = -1  # not read (a probe)
        if len(data) > _DATA_BYTES:
            stat = self.calib_stat = data[_DATA_BYTES]
            self.calib = decode_calib(stat)
        body = data[:_DATA_BYTES]
        empty = not any(body[:44])  # no sample yet after a mode switch, or a chip back in CONFIG
        g = self.grid
        g.observe(tb, ta, new=new and not empty)
        held, m = self._held, g.newest()
        if held is not None and _alike(body, held.body):  # the held sample again
            self.repeated_reads += 1
            if m is not None and held.epoch == g.epoch:
                self._held = None
                if len(body) > len(held.body):
                    held = Held(body, stat, held.tb, held.ta, held.epoch, held.seen)
                return self._deliver(held, (m, m))
            self._no_news(False, t1)
            return RawBatch(0, {}, FifoRead(tb, ta, fifo_full=True))
        if empty or (self._prev is not None and _alike(body, self._prev)):
            if empty:
                self.empty_reads += 1
            else:
                self.repeated_reads += 1
            self._no_news(empty, t1)
            return RawBatch(0, {}, FifoRead(tb, ta))
        self._last_new_ns = t1
        sample = Held(body, stat, tb, ta, g.epoch, g.seen)
        if m is None and g.lo is not None and held is None:
            self._held = sample  # the next read tells which sample it was
            return RawBatch(0, {}, FifoRead(tb, ta, fifo_full=True))
        self._held = None
        if held is None:
            return self._deliver(sample, g.seen)
        # the held sample is older than this one, so its index is below this one's. Not below
        # this one's lowest: when this read straddled a window too, the held one may be that
        # lowest (a read after it, the next lower): exact only if the ranges do not overlap
        first = self._deliver(held, (held.seen[0], min(held.seen[1], g.seen[1] - 1)))
        first.then = self._deliver(sample, g.seen)
        return first

    def _deliver(self, s: Held, seen: tuple[int, int]) -> RawBatch:
        """A new sample out, its grid index one of `seen` (in its epoch)."""
        timing = self.count.next(s.tb, s.ta, self.timing, s.epoch, seen)
        self._prev = s.body
        self.partial_samples += len(s.body) < _DATA_BYTES
        batch = self._decode(s.body, timing)
        if (
            self.cfg.save_offsets
            and self.fusion
            and not self._save_tried
            and s.stat >= 0
            and s.stat & self.calib_mask == self.calib_mask
        ):
            self._begin_save()
        return batch

    def _stale(self, now: int) -> None:
        """No new sample for STALE_NS: find out why, and have the runner re-initialise."""
        self._check_mode()
        raise RegisterMismatch(
            0,
            f"no new data for {(now - self._last_new_ns) / 1e6:.0f} ms although the chip is in "
            f"{self.mode.name} mode: its fusion stalled; reinitialise",
        )

    def _check_mode(self) -> None:
        """The chip still in the configured mode, or it reset itself: raise for the runner."""
        mode = self.dev.read_u8(P0.OPR_MODE)
        if R.OPR_MODE_FIELD.get(mode) != self.mode:
            self.counters.bad_registers += 1
            raise RegisterMismatch(
                0,
                f"OPR_MODE reads 0x{mode:02x}, configured 0x{int(self.mode):02x}: the chip "
                "reset itself (power glitch?); reinitialise",
            )

    def _decode(self, body: bytes, timing: FifoRead) -> RawBatch:
        """A sample's bytes from 0x08: all of ACC ... TEMP, or a probe's ACC, MAG and GYR
        alone (the other channels then marked invalid: one stream, one set of channels)."""
        partial = len(body) < _DATA_BYTES
        if partial:
            body = body.ljust(_DATA_BYTES, b"\0")
        w = np.frombuffer(body, dtype="<i2", count=22).astype(np.int32).reshape(1, 22)
        temp = np.frombuffer(body, dtype=np.int8, count=1, offset=44).astype(np.float64)
        s = self.scale
        unread = np.array([True]) if partial else None
        ch: dict[Channel, RawChannel] = {
            Channel.ACCEL: RawChannel(w[:, 0:3], s[Channel.ACCEL], ACCEL_FULL_SCALE),
            Channel.GYRO: RawChannel(w[:, 6:9], s[Channel.GYRO], self._gyro_full_scale()),
            Channel.TEMPERATURE: RawChannel(temp, s[Channel.TEMPERATURE], invalid=unread),
        }
        if Channel.MAG in s:
            ch[Channel.MAG] = RawChannel(w[:, 3:6], s[Channel.MAG])
        if self.fusion:
            q = w[:, 12:16]
            bad = unread
            if not partial:
                norm = math.sqrt(float((q * q).sum())) * s[Channel.ORIENTATION]
                if not QUAT_NORM_RANGE[0] <= norm <= QUAT_NORM_RANGE[1]:
                    self.invalid_quaternions += 1
                    bad = np.array([True])
            ch[Channel.ORIENTATION] = RawChannel(q, s[Channel.ORIENTATION], invalid=bad)
            ch[Channel.LINEAR_ACCEL] = RawChannel(
                w[:, 16:19], s[Channel.LINEAR_ACCEL], invalid=unread
            )
            ch[Channel.GRAVITY] = RawChannel(w[:, 19:22], s[Channel.GRAVITY], invalid=unread)
        return RawBatch(1, ch, timing)

    def _gyro_full_scale(self) -> float:
        if self.fusion:  # the range's end in 1/900 rad/s
            return float(math.floor(math.radians(self._gyro_range_dps) * R.GYR_LSB_PER_RPS))
        return float(R.GYR_RAW_FULL_SCALE_COUNTS - 1)

    # --- stop, status -----------------------------------------------------------------------
    def stop(self) -> None:
        with contextlib.suppress(BusError):
            self.dev.write_u8(P0.OPR_MODE, R.OprMode.CONFIG)  # sensors idle, fusion halted

    def chip_status(self) -> dict[str, Any]:
        with self._lock:
            saved, saved_at, error = self.saved, self.offsets_saved_at, self.offsets_error
        c, m = self.calib, self.calib_mask
        out: dict[str, Any] = {
            "mode": self.cfg.mode,
            "calibration": c,
            "fully_calibrated": None if c is None else self.calib_stat & m == m,
            # published from a probe while the phase was sought: motion sensors only, the
            # rest invalid (they are the device's invalid samples at start-up)
            "partial_samples": self.partial_samples,
            "repeated_reads": self.repeated_reads,
            "empty_reads": self.empty_reads,
            "suspected_missed": self.count.suspected,
            "skipped_polls": self.skipped_polls,
            "invalid_quaternions": self.invalid_quaternions,
            "offsets_file": str(self.offsets_path),
            "offsets_restored": self.offsets_restored,
            "offsets": asdict(self.restored) if self.restored is not None else None,
            "offsets_saved_at": saved_at,
            "offsets_saved": asdict(saved) if saved is not None else None,
            "offsets_error": error,
            "firmware": self.firmware,
            "bootloader": self.bootloader,
            "uid": self.uid.hex(),
            "sys_status": self.sys_status,
            "sys_err": self.sys_err,
        }
        out["phase_losses"] = self.grid.phase_losses
        if self.uart is not None and self.poller is not None:
            out["uart"] = self.uart.stats.as_dict() | {
                "probes": self.poller.probes,  # short reads that find the sample grid's phase
            }
        return out
