"""ADIS16465 driver: one checksummed burst per new sample, the delta outputs read after it,
DATA_CNTR for duplicates and gaps (docs/chips/adis16465.md).

The chip has no FIFO: its output registers hold the newest sample, and DATA_CNTR counts the
samples. imud polls through each sample period (see `_set_poll_interval`) and reads the 176-bit
burst at 1 MHz at most: a DATA_CNTR equal to the last one is a sample already read (an empty
batch, whose read brackets still feed the clock fit), a step of more than one is samples lost,
counted exactly from the counter. A burst whose checksum fails is dropped and counted.

The burst has no delta outputs, so after a new sample the six 32-bit delta registers are read
word by word (pipelined: each 16-bit frame clocks out the answer to the one before), then
DATA_CNTR once more: if a new sample landed meanwhile, the words may belong to two samples, so
that sample's deltas are published as invalid, never mixed. The chip integrates them with its
nominal 2000 Hz; its oscillator is off by up to 3 %, so they are scaled by the nominal over the
real rate, which the driver measures from DATA_CNTR against host time over a long baseline.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from imud.buses.spi import SpiDevLike
from imud.channels import Channel
from imud.chips.adis16465 import decode as d
from imud.chips.adis16465 import registers as R
from imud.chips.adis16465.config import (
    Adis16465Config,
    bus_speed_hz,
    bus_time_ns,
    frame_speeds,
)
from imud.chips.adis16465.wordplan import WordPlan
from imud.chips.api import ChipCounter, DriverCounters, FifoRead, RawBatch, RawChannel
from imud.chips.regplan import RegisterChecker, RegisterSetting
from imud.clock import Clock
from imud.errors import BusError, DeviceIdentityError, RegisterMismatch

Reg = R.Register
RESET_WAIT_NS = 200_000_000  # the datasheet's 198 ms, rounded up as Linux does
RESET_POLL_NS = 20_000_000  # then PROD_ID is polled this often until the chip answers
RESET_POLLS = 5
BASELINE_SAMPLES = 400  # the rate estimate is used once its fit spans this many samples
RATE_MEMORY_S = 60.0  # it forgets older samples over about this long (the clock drifts)
REFIT_AFTER_NS = 10_000_000_000  # a pause this long could hide a DATA_CNTR wrap at 2 kHz
OSCILLATOR_SPAN = 0.03  # initial clock accuracy +-3 %
POLL_MARGIN = 0.98  # polls at most this share of the real period apart
POLL_LATENESS_NS = 250_000  # how late a poll may come and still find its sample in time
LATENESS_SHARE = 0.25  # or this share of a period, if more (slower rates can afford it)
MIN_GAP_SHARE = 0.25  # polls no closer than this share of a period on average, whatever
RATE_GATE = 0.05  # an estimate further than this from nominal is not the +-3 % oscillator
# phase-locked polls (`_lock`): aimed this share of a period around the next sample's expected
# latch, mostly after it (the early ones bound the latch from below, for the lock and for the
# pipeline's clock fit); a poll that finds no new sample tries again this much later
LOCK_WINDOW_SHARE = 0.1
LOCK_WINDOW_MIN_NS = 20_000
LOCK_EARLY_SHARE = 0.25  # of the polls aimed inside the window, this share before the latch
UNBRACKETED_MAX = 50  # then the rate is measured from the polls' ends: better than not at all
LOCK_CREEP_SHARE = 0.2  # of a window: how far the aim moves earlier a sample no poll came before
_GOLDEN = 0.6180339887
_BURST_TX = [R.BURST_CMD >> 8, R.BURST_CMD & 0xFF] + [0] * (R.BURST_FRAME_BYTES - 2)
_TRAILER = int(Reg.PROD_ID)  # a harmless read whose frame clocks out the last answer
_LOWS = [int(r) for r in d.LOW_REGISTERS]
_DELTAS = [int(r) for r in d.DELTA_REGISTERS]
_CNTR = int(Reg.DATA_CNTR)
_POLL = [_CNTR]
_DIAG_BITS = [(int(b), str(b.name).lower()) for b in R.DiagStat]
_MODULO = R.DATA_CNTR_MODULO


def register_plan(c: Adis16465Config) -> list[RegisterSetting]:
    def field(name: str, reg: int, f: Any, value: int) -> RegisterSetting:
        bits = f.bits(value)
        return RegisterSetting(reg, bits, f.mask & ~bits, width=16, name=name)

    return [
        field("DEC_RATE", Reg.DEC_RATE, R.DEC_RATE_FIELD, c.dec_rate),
        field("FILT_CTRL", Reg.FILT_CTRL, R.FILT_CTRL_SIZE, c.filt_ctrl),
        # internal clock: scaled sync would put TIME_STAMP where the burst has DATA_CNTR
        field("MSC_CTRL", Reg.MSC_CTRL, R.MSC_CTRL_SYNC_MODE, R.SYNC_MODE_INTERNAL),
    ]


def model_name(model: int) -> str:
    return f"ADIS16465-{model} (+-{R.GYRO_RANGES_DPS[model]} deg/s)"


class RateEstimator:
    """The chip's real output rate: a least-squares line through (DATA_CNTR unwrapped, host time
    the sample was first seen), forgetting over about a minute. The host time of each sample is
    late by up to a poll period; the fit averages that out where two end points would not."""

    def __init__(self, nominal_hz: float) -> None:
        self.nominal_hz = nominal_hz
        self.memory = max(1000.0, RATE_MEMORY_S * nominal_hz)
        self.rate_hz: float | None = None
        self.restart()

    def restart(self) -> None:
        """A new counter origin (a reset chip, a long pause): a new fit; the old rate stays."""
        self._origin: tuple[int, int] | None = None
        self._last_ns = 0
        self._k = 0
        self._mx = self._my = self._vx = self._cxy = 0.0

    def add(self, total: int, t_ns: int) -> float | None:
        if self._origin is None or t_ns - self._last_ns > REFIT_AFTER_NS:
            self.restart()
            self._origin = (total, t_ns)
        self._last_ns = t_ns
        x = float(total - self._origin[0])
        y = (t_ns - self._origin[1]) / 1e9
        self._k += 1
        alpha = max(1.0 / self._k, 1.0 / self.memory)
        dx, dy = x - self._mx, y - self._my
        self._mx += alpha * dx
        self._my += alpha * dy
        self._vx = (1 - 1 / self.memory) * self._vx + (1 - alpha) * dx * dx
        self._cxy = (1 - 1 / self.memory) * self._cxy + (1 - alpha) * dx * dy
        if x >= BASELINE_SAMPLES and self._cxy > 0:
            rate = self._vx / self._cxy
            if abs(rate / self.nominal_hz - 1.0) < RATE_GATE:
                self.rate_hz = rate
        return self.rate_hz


class Adis16465Driver:
    """Burst polling with DATA_CNTR. Blocking; owned by its bus's worker."""

    fifo_capacity = 1  # no FIFO: a poll later than a period loses samples (counted)

    def __init__(self, cfg: Adis16465Config, spi: SpiDevLike, clock: Clock) -> None:
        self.cfg, self.spi, self.clock = cfg, spi, clock
        self.counters = DriverCounters(chip={"checksum_errors": 0})
        speed = bus_speed_hz(cfg.bus) or R.MAX_BURST_SCLK_HZ
        self.reg_hz, self.burst_hz = frame_speeds(speed)
        self.nominal_period_ns = 1e9 / cfg.odr_hz
        # the Bartlett window (2^B - 1 internal samples) and the DEC_RATE average ((D - 1) / 2):
        # linear-phase FIRs, delays from their lengths (docs/timestamps.md)
        delay = 2**cfg.filt_ctrl - 1 + cfg.dec_rate / 2
        self.group_delay_ns = round(delay * 1e9 / R.INTERNAL_RATE_HZ)
        self.poll_interval_ns = 0
        self.rate = RateEstimator(cfg.odr_hz)
        # the gyro and accel low words carry bits when the chip decimates or filters
        self.wide = bool(cfg.dec_rate or cfg.filt_ctrl)
        self.lows = cfg.low_words()
        self._after = (_LOWS if self.lows else []) + (_DELTAS if cfg.deltas else [])
        frames = d.sample_frames(self.lows, cfg.deltas)
        # how long after a poll starts the last word of a new sample is read: the reads after
        # the burst must end before the next sample lands (the burst itself is one snapshot)
        self._read_ns = bus_time_ns(speed, frames) if frames else 0.0
        # Without reads after the burst, a poll reads DATA_CNTR (two register reads, 32 us of
        # bus at 2 MHz) and bursts only for a new sample: a burst polled is 176 us at 1 MHz,
        # which at 2000 Hz would keep the bus busy. The datasheet's read allowance per
        # data-ready period then bounds the polls: with delays uniform over [gap - period,
        # gap), clipped at 0, a period holds 2 / gap_share^2 polls on average (if a poll took
        # no time), which sets the gap's floor. With reads after the burst (deltas, low words)
        # those take the allowance, and the poll is the burst (which counts for no register
        # read; not verified).
        self.poll_counter = not self._after
        self._min_gap_share = MIN_GAP_SHARE
        if self.poll_counter:
            polls = (R.READS_PER_DR * (cfg.dec_rate + 1) - 2) / 2
            self._min_gap_share = min(POLL_MARGIN, max(MIN_GAP_SHARE, (2 / polls) ** 0.5))
        self._set_poll_interval()
        wide = 1 / 65536 if self.wide else 1.0
        self.gyro_scale = d.gyro_scale_rads(cfg.model) * wide
        self.accel_scale = d.accel_scale_ms2() * wide
        # saturated: the top 16-bit code, whatever the low word (half a code of margin, so a
        # midpoint-filled -32767 counts too)
        self.full_scale = d.FULL_SCALE_16 / wide - (0.5 / wide if self.wide else 0.0)
        self.dang_scale = d.delta_angle_scale_rad(cfg.model)
        self.dvel_scale = d.delta_velocity_scale_ms()
        self.plan = WordPlan(self, register_plan(cfg))
        self._checker = RegisterChecker([self.plan], clock, self.counters)
        self._ready_ns = 0  # the clock instant the next frame may start (the stall)
        self.duplicates = 0
        self.counter_gaps = 0
        self.samples_skipped = 0  # counted from DATA_CNTR steps
        self.overtaken = 0  # reads after the burst that a new sample overtook
        self.diag_seen = 0  # union of every DIAG_STAT bit seen since the daemon started
        self.diag_counts: dict[str, int] = {}
        self._restart_stream()

    def _restart_stream(self, count: int | None = None) -> None:
        """A new stream from the chip's sample `count` (already in its registers: not
        published)."""
        self._last_count = count
        self._pending_diag = 0  # bits not yet marked on a published sample
        self._total = 0  # DATA_CNTR unwrapped
        self.rate.restart()
        self.next_poll_ns: int | None = None  # the interval's polls until the lock has a sample
        self._latch_ns: float | None = None  # host time the newest sample is estimated latched
        self._not_yet_ns: int | None = None  # a poll started here found no new sample
        self._unbracketed = 0  # new samples in a row no poll came before
        self._sweep = 0.0

    # --- frames -----------------------------------------------------------------------------
    def _frame(self, tx: list[int], speed_hz: int) -> list[int]:
        """One chip-select frame, no sooner than the stall after the last one ends (spun, not
        slept: 16 us is far below the scheduler's granularity)."""
        start = self.clock.spin_until_ns(self._ready_ns)
        try:
            rx = self.spi.xfer2(tx, speed_hz)
        except OSError as e:
            raise BusError(e.errno, f"SPI frame 0x{tx[0]:02x}{tx[1]:02x}: {e}") from e
        self._ready_ns = max(self.clock.now_ns() + R.STALL_NS, start + R.READ_RATE_NS)
        return rx

    def read_words(self, registers: Sequence[int]) -> list[int]:
        """16-bit registers, pipelined: each frame's answer is the previous frame's register."""
        out: list[int] = []
        hz = self.reg_hz
        self._frame([registers[0] & 0x7F, 0], hz)
        for r in (*registers[1:], _TRAILER):
            rx = self._frame([r & 0x7F, 0], hz)
            out.append(rx[0] << 8 | rx[1])
        return out

    def write_word(self, register: int, value: int) -> None:
        """A 16-bit write is two frames, one per byte, low byte first."""
        self._frame([R.WRITE | register, value & 0xFF], self.reg_hz)
        self._frame([R.WRITE | (register + 1), value >> 8 & 0xFF], self.reg_hz)

    # --- start ------------------------------------------------------------------------------
    def _product_id(self) -> int:
        (pid,) = self.read_words([Reg.PROD_ID])
        return pid

    def _identify(self, pid: int) -> None:
        if pid == R.PROD_ID_VALUE:
            return
        family = R.FAMILY_PROD_IDS.get(pid)
        if family is not None:
            raise DeviceIdentityError(
                f"PROD_ID (0x72) reads 0x{pid:04x} ({pid}): an {family}, not an ADIS16465; its "
                "scale factors differ, so imud will not read it as one: configure the chip that "
                "is fitted"
            )
        raise DeviceIdentityError(
            f"PROD_ID (0x72) reads 0x{pid:04x}, expected 0x{R.PROD_ID_VALUE:04x} (16465) for an "
            "ADIS16465: check the wiring, SPI mode 3 and the chip select"
        )

    def start(self) -> Iterator[int]:
        pid = self._product_id()
        if pid != R.PROD_ID_VALUE:
            pid = self._product_id()  # once more: the first frame after power-up may be lost
        for _ in range(RESET_WAIT_NS // RESET_POLL_NS + RESET_POLLS):
            if pid:
                break
            # silent: a chip resetting (after a power glitch of its own) answers zeros
            yield RESET_POLL_NS
            pid = self._product_id()
        self._identify(pid)
        self.write_word(Reg.GLOB_CMD, R.GlobCmd.SOFTWARE_RESET)
        yield RESET_WAIT_NS
        for _ in range(RESET_POLLS):  # the SPI port is silent until the reset is done
            pid = self._product_id()
            if pid == R.PROD_ID_VALUE:
                break
            yield RESET_POLL_NS
        else:
            raise DeviceIdentityError(
                f"the ADIS16465 does not answer after its software reset: PROD_ID reads "
                f"0x{pid:04x} {(RESET_WAIT_NS + RESET_POLLS * RESET_POLL_NS) // 1_000_000} ms on"
            )
        self.counters.soft_resets += 1
        (rang,) = self.read_words([Reg.RANG_MDL])
        model = d.model_from_rang_mdl(rang)
        if model is None:
            raise DeviceIdentityError(
                f"RANG_MDL (0x5e) reads 0x{rang:04x}, which names no ADIS16465 model (bits "
                "[1:0] read 11, [3:2] 00, 01 or 11): check the wiring"
            )
        if model != self.cfg.model:
            raise DeviceIdentityError(
                f"RANG_MDL (0x5e) reads 0x{rang:04x}: the chip is an {model_name(model)}, but the "
                f"config says model = {self.cfg.model}, an {model_name(self.cfg.model)}: set "
                f"model = {model} (the model sets the gyro scale)"
            )
        self.plan.write_all()
        yield R.MSC_CTRL_WAIT_NS
        self.plan.verify_all()
        # the output registers still hold a sample of the old DEC_RATE until the first new one:
        # wait for two new output periods (the clock may be 3 % slow), and start after that
        yield int(2 * self.nominal_period_ns / (1 - OSCILLATOR_SPAN))
        (count,) = self.read_words([_CNTR])
        self._restart_stream(count)
        self._checker.restart()

    # --- read -------------------------------------------------------------------------------
    def _burst_failed(self, rx: list[int], got: int, sent: int) -> BusError:
        self.counters.bad_transfers += 1
        self.counters.chip["checksum_errors"] += 1
        if all(b == 0xFF for b in rx[2:]):
            return BusError(0, "burst read all ones: no answer on MISO")
        return BusError(
            0,
            f"burst checksum word 0x{sent:04x}, but its 18 data bytes sum to 0x{got:04x}: "
            f"frame dropped (SCLK {self.burst_hz / 1e6:g} MHz; noise on the lines?)",
        )

    def _silent(self) -> BusError:
        """A burst of all zeros: the chip does not answer. If PROD_ID reads 0 too, it is
        resetting (its SPI port is silent for 198 ms after a reset): it reset itself, and is
        re-initialised once it answers; its registers and DATA_CNTR start over."""
        (pid,) = self.read_words([Reg.PROD_ID])
        if pid == 0:
            self.counters.bad_registers += 1
            return RegisterMismatch(
                0,
                "burst and PROD_ID (0x72) read all zeros: the ADIS16465 is not answering "
                "(it reset itself, or lost power or its wiring); reinitialise",
            )
        return BusError(0, "burst read all zeros: the ADIS16465 is not answering (resetting?)")

    def _note_diag(self, diag: int) -> None:
        """DIAG_STAT bits clear when read: keep their union and a count per bit."""
        self.diag_seen |= diag
        self._pending_diag |= diag
        for bit, name in _DIAG_BITS:
            if diag & bit:
                self.diag_counts[name] = self.diag_counts.get(name, 0) + 1

    def read(self) -> RawBatch:
        self._checker.check_next()
        last = self._last_count
        polled = None
        if self.poll_counter:  # a new sample? DATA_CNTR by register read (32 us at 2 MHz)
            t_before = self.clock.now_ns()
            (polled,) = self.read_words(_POLL)
            t_after = self.clock.now_ns()
            if polled == last:
                self.duplicates += 1
                self._early(t_before, t_after)
                return RawBatch(0, {}, FifoRead(t_before, t_after))
        b_before = self.clock.now_ns()
        rx = self._frame(list(_BURST_TX), self.burst_hz)
        b_after = self.clock.now_ns()
        response = bytes(rx[2:])
        diag, gx, gy, gz, ax, ay, az, temp, count, sent = d.BURST.unpack(response)
        got = d.checksum(response)
        if got != sent:
            raise self._burst_failed(rx, got, sent)
        if not any(response):
            raise self._silent()
        if count != polled:  # no counter poll, or a newer sample since: the burst's brackets
            t_before, t_after = b_before, b_after
        if diag:
            self._note_diag(diag)
        if count == last:
            self.duplicates += 1
            self._early(t_before, t_after)
            return RawBatch(0, {}, FifoRead(t_before, t_after))
        words = self.read_words([*self._after, _CNTR]) if self._after else []
        # the sample is ours only now: a read that failed above leaves it to count as lost
        step = 1 if last is None else (count - last) % _MODULO
        self._last_count = count
        resync = step != 1
        if resync:
            self.counter_gaps += 1
            self.samples_skipped += step - 1
        self._total += step
        # the latch lies after the last poll that did not see it (when it was this sample's
        # predecessor it saw) and before this one's end: the middle of that bracket is where the
        # rate is measured. The end alone would carry the polls' pattern into it: how late
        # after the latch a poll comes changes when the polls lock on
        lo = self._not_yet_ns if step == 1 else None
        self._not_yet_ns = None
        if lo is not None:
            self._unbracketed = 0
            rate = self.rate.add(self._total, (lo + t_after) // 2)
        else:  # polls that always come late (a busy machine): the ends, rather than nothing
            self._unbracketed += 1
            late = self._unbracketed > UNBRACKETED_MAX
            rate = self.rate.add(self._total, t_after) if late else self.rate.rate_hz
        if words:
            self._read_ns += 0.05 * (self.clock.now_ns() - t_before - self._read_ns)
        self._set_poll_interval()
        self._lock(step, lo, t_after, rate)
        overtaken = bool(words) and words[-1] != count  # a new sample came during the reads
        if overtaken:
            self.overtaken += 1
        gyro, accel = [gx, gy, gz], [ax, ay, az]
        if self.wide:  # 32-bit values: the low words read, else their midpoint
            lows = words[:6] if self.lows and not overtaken else [d.MIDPOINT_LOW] * 6
            gyro = [(v << 16) | lo for v, lo in zip(gyro, lows[:3], strict=True)]
            accel = [(v << 16) | lo for v, lo in zip(accel, lows[3:], strict=True)]
        channels = {
            Channel.ACCEL: RawChannel(
                np.array([accel], dtype=np.int64), self.accel_scale, self.full_scale
            ),
            Channel.GYRO: RawChannel(
                np.array([gyro], dtype=np.int64), self.gyro_scale, self.full_scale
            ),
            Channel.TEMPERATURE: RawChannel(np.array([temp], dtype=np.int32), d.TEMP_C_PER_LSB),
        }
        if self.cfg.deltas:
            channels.update(self._deltas(words[-13:-1], overtaken, rate))
        alarm = None
        if self._pending_diag:
            alarm, self._pending_diag = np.ones(1, dtype=bool), 0
        timing = FifoRead(
            t_before,
            t_after,
            resync=resync,
            counter=ChipCounter(np.array([count], dtype=np.int64), _MODULO),
        )
        return RawBatch(1, channels, timing, alarm)

    def _deltas(
        self, w: list[int], overtaken: bool, rate: float | None
    ) -> dict[Channel, RawChannel]:
        """The 32-bit delta outputs, scaled by nominal over real rate: the chip integrates with
        its nominal 2000 Hz. Overtaken by a new sample: invalid (NaN), never mixed."""
        invalid = np.ones(1, dtype=bool) if overtaken else None
        v = [d.join32(w[i], w[i + 1]) for i in range(0, 12, 2)]
        fix = self.cfg.odr_hz / rate if rate else 1.0
        return {
            Channel.DELTA_ANGLE: RawChannel(
                np.array([v[:3]], dtype=np.int64), self.dang_scale * fix, invalid=invalid
            ),
            Channel.DELTA_VELOCITY: RawChannel(
                np.array([v[3:]], dtype=np.int64), self.dvel_scale * fix, invalid=invalid
            ),
        }

    def _early(self, t_before: int, t_after: int) -> None:
        """A poll found no new sample: the next one was not latched when it began. Try again
        a window later (once locked; before, the interval's polls go on)."""
        self._not_yet_ns = t_before
        if self._latch_ns is not None:
            self.next_poll_ns = t_after + self._window_ns()

    def _lock(self, step: int, lo: int | None, t_after: int, rate: float | None) -> None:
        """Place the new sample's latch and aim the next poll just after the next one's.

        Without a FIFO each sample must be read before the next replaces it; polling many times
        a period (the fallback interval) costs a bus transaction and the interpreter's time each
        (measured: 70 % of a core at 2 kHz in the simulated daemon). Once the chip's period is
        measured (`RateEstimator`), the estimate steps by it from sample to sample, so a poll
        that comes late does not move it. The latch lies after the last poll that did not see
        it: an estimate before that is pulled up to it; a sample no poll came before moves the
        estimate a little earlier, since a late aim would otherwise never learn it is late. The
        next poll is aimed within a window around the next latch (a golden-ratio sweep, mostly
        after it): one before the latch finds nothing, bounds it and tries again a window
        later."""
        if rate is None:  # the period is not measured yet (the chip is off by up to 3 %)
            return
        period = 1e9 / rate
        window = self._window_ns()
        if self._latch_ns is None:
            est = t_after if lo is None else (lo + t_after) / 2
        else:
            est = self._latch_ns + step * period
            if lo is None:  # an aim that is late never sees it: move it earlier until a poll
                est -= LOCK_CREEP_SHARE * window  # comes before the latch and bounds it
            elif est <= lo:
                est = lo + 1
        est = min(est, t_after)
        self._latch_ns = est
        self._sweep = (self._sweep + _GOLDEN) % 1.0
        self.next_poll_ns = int(est + period + (self._sweep - LOCK_EARLY_SHARE) * window)

    def _window_ns(self) -> int:
        return max(LOCK_WINDOW_MIN_NS, int(LOCK_WINDOW_SHARE * self.nominal_period_ns))

    def _set_poll_interval(self) -> None:
        """When to poll. Without a FIFO each sample must be read, with the words after it,
        before the next one replaces it. The runner polls after this interval plus a uniform
        fraction of the nominal period (the phase sweep the clock fit needs); the interval is
        set negative so that no two polls are further apart than the real period less the time
        the reads after a new sample take (none without deltas or low words: the burst is one
        snapshot) and some scheduler lateness. The polls the negative part makes immediate find
        the sample already read: they cost a DATA_CNTR read or a burst each."""
        nominal = self.nominal_period_ns
        rate = self.rate.rate_hz
        real = nominal * (1 - OSCILLATOR_SPAN) if rate is None else 1e9 / rate
        gap = real - self._read_ns - max(POLL_LATENESS_NS, LATENESS_SHARE * real)
        gap = min(max(gap, self._min_gap_share * real), POLL_MARGIN * real)
        self.poll_interval_ns = int(gap - nominal)

    def stop(self) -> None:
        """The ADIS16465 has no sleep mode to put it in."""

    @property
    def odr_estimate_hz(self) -> float | None:
        return self.rate.rate_hz

    def chip_status(self) -> dict[str, Any]:
        est = self.odr_estimate_hz
        return {
            "model": f"ADIS16465-{self.cfg.model}",
            "gyro_accel_bits": 32 if self.lows else 16,
            "duplicate_reads": self.duplicates,
            "counter_gaps": self.counter_gaps,
            "samples_skipped": self.samples_skipped,
            "overtaken_reads": self.overtaken,  # their deltas invalid, low words not used
            "delta_races": self.overtaken if self.cfg.deltas else 0,
            "diag_stat": f"0x{self.diag_seen:04x}",
            "diag_stat_counts": dict(self.diag_counts),
            "odr_estimate_hz": None if est is None else round(est, 4),
            "clock_error_pct": None if est is None else round(100 * (est / self.cfg.odr_hz - 1), 4),
        }
