"""Register-level ADIS16465 simulator behind its own SPI framing: 16-bit frames with the answer
pipelined into the next frame, byte-wise writes, the 176-bit burst with its checksum, DATA_CNTR,
sticky DIAG_STAT flags, RANG_MDL for the simulated model, PROD_ID, GLOB_CMD commands with their
busy times, DEC_RATE decimation of the internal 2 kHz samples, and 32-bit delta-angle and
delta-velocity outputs integrated from the sensed motion (docs/chips/adis16465.md).

Like silicon, the delta outputs are trapezoid sums over the internal samples divided by the
NOMINAL 2000 Hz, while the samples really come at 2000 Hz off by the oscillator error (+-3 %,
drawn from the seed unless `clock_error` is set): a reader must rescale them by the real rate.
The truth channel carries one sample per output sample, with the true delta angle and delta
velocity over its interval (at the real rate).

Modelled behaviour beyond the facts sheet, stated so it can be checked against silicon: a burst
clears DIAG_STAT as a register read of it does; a burst clocked above 1 MHz corrupts one data
byte (so its checksum fails), a register frame above 2 MHz flips bits of its answer; more 16-bit
register reads than 12 x (DEC_RATE + 1) since the last output update set the datapath overrun
flag (bursts do not count); a frame of an odd byte count sets the SPI communication error flag
and loses the pending answer; a register write takes effect when its high byte is written; while
a command runs the chip answers zeros and ignores frames; with DEC_RATE = 0 the _LOW words of
gyro and accel read 0; the 16-bit outputs saturate at +-32767; TIME_STAMP reads 0. The
Bartlett window (FILT_CTRL) filters gyro and accel before the DEC_RATE average, and the delta
outputs are integrated from its output (before or after: not verified); the sensors' own band
limit colours the noise only (its delay is not published); a FILT_CTRL write applies to the
outputs not yet made ahead.
"""

from __future__ import annotations

import bisect
import math
import struct
from collections.abc import Generator, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.channels import Channel
from imud.chips.adis16465 import registers as R
from imud.chips.adis16465.noise import (
    ACCEL_NOISE_BAND_HZ,
    ACCEL_NOISE_UG_RTHZ,
    GYRO_NOISE_BAND_HZ,
    GYRO_NOISE_DPS_RTHZ,
    band_taps,
    bartlett,
)
from imud.chips.adis16465.registers import Register as Reg
from imud.clock import Clock
from imud.sim.api import SpiFrameDie, Truth
from imud.sim.chip import TRUTH_KEEP, SampledChip
from imud.sim.filters import NoiseStream
from imud.sim.physics import ChipFigures
from imud.sim.settings import SimSettings
from imud.units import STANDARD_GRAVITY as G

NOMINAL_HZ = 2000.0  # what the chip's integrator assumes its internal rate is
CLOCK_ERROR_SPAN = 0.03  # initial clock accuracy +-3 %
# delta-angle range (+-deg) of each model, and the delta-velocity range (+-m/s), over 2^31 counts
DELTA_ANGLE_RANGE_DEG = {1: 360.0, 2: 720.0, 3: 2160.0}
DELTA_VELOCITY_RANGE = 100.0
GYRO_COUNTS_AT_RANGE = 20_000  # 16-bit output at the measurement range
ACCEL_COUNTS_AT_8G = 32_000
I32 = 2**31 - 1
F64 = npt.NDArray[np.float64]
# GLOB_CMD bit -> how long the chip is busy (ns); data production stops meanwhile
COMMAND_BUSY_NS = {
    int(R.GlobCmd.SOFTWARE_RESET): R.SW_RESET_TIME_NS,
    int(R.GlobCmd.FACTORY_CALIBRATION_RESTORE): 142_000_000,
    int(R.GlobCmd.FLASH_MEMORY_UPDATE): 72_000_000,
    int(R.GlobCmd.FLASH_MEMORY_TEST): 32_000_000,
    int(R.GlobCmd.SENSOR_SELF_TEST): 14_000_000,
}
_RESETS = int(R.GlobCmd.SOFTWARE_RESET | R.GlobCmd.FACTORY_CALIBRATION_RESTORE)
_DEFAULTS = {
    Reg.MSC_CTRL: R.MSC_CTRL_DEFAULT, Reg.UP_SCALE: 0x07D0, Reg.DEC_RATE: 0,
    Reg.NULL_CNFG: 0x070A, Reg.FILT_CTRL: 0, Reg.PROD_ID: R.PROD_ID_VALUE,
    Reg.SERIAL_NUM: 0x1234,
}  # fmt: skip
_WRITABLE = {Reg.FILT_CTRL, Reg.MSC_CTRL, Reg.UP_SCALE, Reg.DEC_RATE, Reg.NULL_CNFG,
             Reg.GLOB_CMD}  # fmt: skip
_SPI_ERROR = int(R.DiagStat.SPI_COMMUNICATION_ERROR)
_OVERRUN = int(R.DiagStat.DATAPATH_OVERRUN)
_BURST_HEAD = (R.BURST_CMD >> 8, R.BURST_CMD & 0xFF)
_NINE = struct.Struct(">9H")


BLOCK = 128  # internal samples made per NumPy pass, ahead of time (64 ms)
# outputs of the current block still to latch when the next one is begun: it is made in
# BLOCK_STAGES parts, one at the end of each sample's reads (`_make_ahead`)
AHEAD_LEFT = 8
BLOCK_STAGES = 5


# output registers -> column of an output sample's words: gyro and accel _LOW/_OUT (0x04 ...
# 0x1A), the deltas' (0x24 ... 0x3A), TEMP_OUT
_COL = {
    **{Reg.X_GYRO_LOW + 2 * i: i for i in range(12)},
    **{Reg.X_DELTANG_LOW + 2 * i: 12 + i for i in range(12)},
    Reg.TEMP_OUT: 24,
}


@dataclass(slots=True)
class _Block:
    """Output samples made ahead: the internal sample each latches at, its register words,
    its time and its truth."""

    k: list[int]
    rows: npt.NDArray[np.int64]  # (n, len(_COL))
    t_ns: npt.NDArray[np.int64]
    truth: dict[Channel, F64]

    @classmethod
    def empty(cls) -> _Block:
        return cls([], np.zeros((0, len(_COL)), dtype=np.int64), np.zeros(0, dtype=np.int64), {})


def figures(model: int) -> ChipFigures:
    """Datasheet noise (imud/chips/adis16465/noise.py, shared with the ROS 2 covariances) and
    in-run bias instability of each model (docs/chips/adis16465.md); turn-on bias, scale,
    misalignment and temperature drift are moderate figures for a factory-calibrated,
    temperature-compensated part, not datasheet values."""
    return ChipFigures(
        accel_noise_ug_rthz=ACCEL_NOISE_UG_RTHZ,
        gyro_noise_dps_rthz=GYRO_NOISE_DPS_RTHZ[model],
        accel_bias_mg=0.5,
        gyro_bias_dps=0.02,
        accel_bias_instability_ug=3.6,
        gyro_bias_instability_dph={1: 2.0, 2: 2.5, 3: 6.0}[model],
        scale_error=0.001,
        misalignment_deg=0.05,
        accel_temp_drift_mg_per_c=0.005,
        gyro_temp_drift_dps_per_c=0.0005,
    )


Stages = Generator[None, None, _Block]


def _finish(stages: Stages) -> _Block:
    """What a block's remaining stages make, run all at once."""
    while True:
        try:
            next(stages)
        except StopIteration as done:
            block: _Block = done.value
            return block


class Adis16465Sim(SampledChip):
    """One die with its own SPI framing. `model` (1, 2, 3) is what RANG_MDL says and which gyro
    range the outputs have; set it apart from the config's to simulate the wrong part."""

    def __init__(self, settings: SimSettings, clock: Clock, model: int = 3) -> None:
        super().__init__(settings, clock, figures(model))
        if settings.clock_error is None:
            on = 0.0 if settings.errors.ideal else 1.0
            rng = np.random.default_rng([settings.seed, 0xAD15])
            self.clock_error = float(rng.uniform(-CLOCK_ERROR_SPAN, CLOCK_ERROR_SPAN)) * on
        self._glitch = np.random.default_rng([settings.seed, 0x6A7])
        self.model = model
        self.record_truth = settings.truth
        self._truth_out: list[tuple[int, npt.NDArray[np.int64], dict[Channel, F64]]] = []
        self.outputs_produced = 0  # truth index: output samples since the simulator was made
        # the sensors' own band limits (noise.py): they colour the noise only, their delay is
        # not published
        self._noise = (NoiseStream(band_taps(GYRO_NOISE_BAND_HZ[model], NOMINAL_HZ)),
                       NoiseStream(band_taps(ACCEL_NOISE_BAND_HZ, NOMINAL_HZ)))  # fmt: skip
        self.bursts = 0
        self.register_reads = 0
        self._power_on(clock.now_ns())

    @property
    def dies(self) -> Sequence[SpiFrameDie]:  # type: ignore[override]
        return (self,)

    @property
    def rate_hz(self) -> float:
        """The internal sample rate (2000 Hz off by the oscillator error); outputs come every
        DEC_RATE + 1 of them."""
        return NOMINAL_HZ * (1 + self.clock_error)

    @property
    def dec(self) -> int:
        """D: internal samples per output sample."""
        return min(self.words[Reg.DEC_RATE >> 1] & R.DEC_RATE_FIELD.mask, R.DEC_RATE_MAX) + 1

    # --- state ------------------------------------------------------------------------------
    def _power_on(self, now: int) -> None:
        """Power-on or software reset: registers from flash (the defaults), counter at 0."""
        self.words = [0] * 64
        for reg, value in _DEFAULTS.items():
            self.words[reg >> 1] = value
        rang = R.RANG_MDL_RANGE.bits(R.RANG_MDL_CODES[self.model]) | R.RANG_MDL_READS_ONE
        self.words[Reg.RANG_MDL >> 1] = rang
        self.diag = 0
        self.pending: int | None = None  # the answer the next 16-bit frame clocks out
        self.reads_this_period = 0
        self.busy_until_ns = 0
        self._command = 0
        self.count = 0  # DATA_CNTR
        self.current = [0] * len(_COL)  # the newest output sample's register words
        self.sampling = True
        self._anchor(now)

    def _restart_decimation(self, k_next: int = 1) -> None:
        """Decimation starts over at internal sample `k_next`; outputs made ahead are dropped."""
        self.next_k = k_next
        self._n_acc = 0  # internal samples into the current output
        self._sum = np.zeros(12)  # measured gyro, accel; true gyro, accel
        self._trap = np.zeros(12)
        self._prev: F64 | None = None  # the last internal sample
        self._hist: F64 | None = None  # the Bartlett filter's last inputs (taps - 1, 6)
        self._block = _Block.empty()
        self._oi = 0  # the block's next output not yet due
        self._ahead: _Block | None = None  # the block after it, made at the end of reads
        self._making: Stages | None = None  # ... while it is being made, a stage a read
        self._words_read = 0  # output registers read by frame since the last burst

    def _wake(self) -> None:
        """End a command whose busy time is over."""
        if self.busy_until_ns and self.clock.now_ns() >= self.busy_until_ns:
            end, cmd = self.busy_until_ns, self._command
            if cmd & int(R.GlobCmd.SOFTWARE_RESET):
                self._power_on(end)
                return
            if cmd & int(R.GlobCmd.FACTORY_CALIBRATION_RESTORE):
                for reg in (Reg.MSC_CTRL, Reg.DEC_RATE, Reg.FILT_CTRL):
                    self.words[reg >> 1] = _DEFAULTS[reg]
            self.busy_until_ns = 0
            self.sampling = True
            self._anchor(end)

    # --- sampling ---------------------------------------------------------------------------
    def _anchor(self, now: int) -> None:
        """Restart the internal sample grid: the next sample comes one period after `now`."""
        self.grid_origin_ns = float(now)
        self._restart_decimation(1)

    def advance(self) -> None:
        """Latch every output sample due by now. Outputs are made ahead in blocks (one NumPy
        pass for hundreds of internal samples) and only latched when their time comes."""
        if self._resets_ns and self.clock.now_ns() >= self._resets_ns[0]:
            self.self_resets_due()
        if not self.sampling:
            return
        k_now = math.floor((self.clock.now_ns() - self.grid_origin_ns) * self.rate_hz / 1e9)
        while True:
            b = self._block
            ks = b.k
            if self._oi < len(ks):
                if ks[self._oi] > k_now:
                    return
                end = bisect.bisect_right(ks, k_now, self._oi)
                self._latch(self._oi, end)
                if end < len(ks):
                    return
            ahead = self._ahead or (_finish(self._making) if self._making else self._make_block())
            self._block, self._ahead, self._making = ahead, None, None
            self._oi = 0

    def _make_ahead(self) -> None:
        """Make the next block once this one is nearly latched, a stage at the end of each
        sample's reads.

        Making a block takes more than a period at 2 kHz with a cold cache (0.5-0.6 ms
        measured in the bus worker), host time silicon does not take. Inside the DATA_CNTR poll
        that begins a sample's read it would delay the burst after it past the next latch and
        lose the polled sample; between a burst and the delta words after it, it would let the
        next sample overtake them. So it is done where a reader has the most slack: once the
        sample's last word is answered, which is the burst for a reader that reads nothing
        after it, and the DATA_CNTR re-check for one that reads words after the burst
        (`_words_read`). Made whole even there, it still left the reader's next poll late by
        its own length often enough to lose a sample a second: made in BLOCK_STAGES parts over
        as many reads, no read waits for more than a part."""
        if self._ahead is not None or not self.sampling:
            return
        if self._making is None:
            if len(self._block.k) - self._oi > AHEAD_LEFT:
                return
            self._making = self._block_stages()
        try:
            next(self._making)
        except StopIteration as done:
            self._ahead, self._making = done.value, None

    @property
    def filt(self) -> int:
        """B of FILT_CTRL: the Bartlett window's two stages average 2^B internal samples."""
        return min(self.words[Reg.FILT_CTRL >> 1] & R.FILT_CTRL_SIZE.mask, R.FILT_CTRL_MAX)

    def group_delay_samples(self) -> float:
        """The digital filters' delay in internal samples: the Bartlett window's 2^B - 1 and
        the DEC_RATE average's (D - 1) / 2 (both linear phase: their lengths say it)."""
        return (1 << self.filt) - 1 + (self.dec - 1) / 2

    def _measure_stages(
        self, k: F64
    ) -> Generator[None, None, tuple[npt.NDArray[np.int64], F64, F64, F64, F64]]:
        """Internal samples k before the digital filters: their instants (ns), temperature,
        true specific force and rate, and measured gyro and accel (n, 6) with the noise; in
        three stages (the motion, the gyro, the accel)."""
        t_ns = np.floor(self.grid_origin_ns + k * (1e9 / self.rate_hz)).astype(np.int64)
        t_s = (t_ns - self.t_origin_ns) / 1e9
        f, w = self.motion.sample(t_s)
        temp = self.temp.at(t_s)
        yield
        e, rng, n = self.errors, self.errors.noise_rng, k.shape[0]
        wm = e.gyro.deterministic(t_s, w, temp)
        wm += self._noise[0].draw(rng, e.gyro.noise, self.rate_hz, n)
        yield
        fm = e.accel.deterministic(t_s, f, temp)
        fm += self._noise[1].draw(rng, e.accel.noise, self.rate_hz, n)
        return t_ns, temp, f, w, np.concatenate([wm, fm], axis=1)

    def _make_block(self) -> _Block:
        """The next block, made whole (a reader late for it, or none reading)."""
        return _finish(self._block_stages())

    def _block_stages(self) -> Stages:
        """The next internal samples (at least BLOCK, and enough for one output), measured,
        through the Bartlett window, and true, into output samples: their mean, and the
        trapezoid sums of the deltas. The truth is the motion the outputs stand for: the
        window's 2^B - 1 samples back, the mean over the same D samples, stamped at the latch
        less the group delay (so a stamp minus the truth's is the stamp's error). In
        BLOCK_STAGES stages, each ending at a `yield`; the block is the generator's value."""
        D = self.dec
        n = max(BLOCK, D - self._n_acc)
        k = np.arange(self.next_k, self.next_k + n, dtype=np.float64)
        self.next_k += n
        t_ns, temp, f, w, raw = yield from self._measure_stages(k)
        yield
        taps = bartlett(self.filt)
        back = taps.shape[0] - 1  # inputs the window needs before the block
        if back:
            if self._hist is None or self._hist.shape[0] != back:
                past = k[0] - back + np.arange(back, dtype=np.float64)
                self._hist = (yield from self._measure_stages(past))[4]
            full = np.concatenate([self._hist, raw])
            self._hist = full[full.shape[0] - back :]
            raw = np.stack([np.convolve(full[:, c], taps, mode="valid") for c in range(6)], 1)
            lag = back // 2  # the window's delay, 2^B - 1 samples
            t_lag = np.floor(self.grid_origin_ns + (k - lag) * (1e9 / self.rate_hz))
            f, w = self.motion.sample((t_lag - self.t_origin_ns) / 1e9)
        x = np.concatenate([raw, w, f], axis=1)
        prev = x[:1] if self._prev is None else self._prev[None, :]
        trap = 0.5 * (x + np.concatenate([prev, x[:-1]]))
        self._prev = x[-1]
        ends = np.arange(D - self._n_acc - 1, n, D)
        cx, ct = np.cumsum(x, axis=0), np.cumsum(trap, axis=0)
        sums, traps = cx[ends], ct[ends]
        sums[1:] -= cx[ends[:-1]]
        traps[1:] -= ct[ends[:-1]]
        sums[0] += self._sum
        traps[0] += self._trap
        last = int(ends[-1])
        self._sum, self._trap = cx[-1] - cx[last], ct[-1] - ct[last]
        self._n_acc = n - 1 - last
        mean = sums / D
        yield
        truth = {
            Channel.ACCEL: mean[:, 9:12],
            Channel.GYRO: mean[:, 6:9],
            Channel.TEMPERATURE: temp[ends],
            # the true rotation and velocity change over each interval: at the real rate
            Channel.DELTA_ANGLE: traps[:, 6:9] / self.rate_hz,
            Channel.DELTA_VELOCITY: traps[:, 9:12] / self.rate_hz,
        }
        delay_ns = self.group_delay_samples() * 1e9 / self.rate_hz
        return _Block(
            k[ends].astype(np.int64).tolist(),
            self._words(mean, traps, temp[ends], D == 1),
            t_ns[ends] - np.int64(round(delay_ns)),
            truth,
        )

    def _words(self, mean: F64, traps: F64, temp: F64, whole16: bool) -> npt.NDArray[np.int64]:
        """Each output sample's register words, in `_COL` order: gyro and accel 32-bit
        (16-bit words with a zero low word without decimation), the 32-bit deltas (the chip's
        own integration, at its nominal rate), TEMP_OUT."""
        g_lsb = math.radians(R.GYRO_RANGES_DPS[self.model] / GYRO_COUNTS_AT_RANGE)
        a_lsb = 8 * G / ACCEL_COUNTS_AT_8G
        scaled = np.concatenate([mean[:, 0:3] / g_lsb, mean[:, 3:6] / a_lsb], axis=1)
        if whole16:
            wide = np.clip(np.rint(scaled), -32767, 32767).astype(np.int64) << 16
        else:
            lo, hi = -32767 * 65536, 32767 * 65536 + 65535
            wide = np.clip(np.rint(scaled * 65536), lo, hi).astype(np.int64)
        da_lsb = math.radians(DELTA_ANGLE_RANGE_DEG[self.model]) / 2**31
        dv_lsb = DELTA_VELOCITY_RANGE / 2**31
        deltas = np.concatenate([traps[:, 0:3] / da_lsb, traps[:, 3:6] / dv_lsb], axis=1)
        deltas = np.clip(np.rint(deltas / NOMINAL_HZ), -I32, I32).astype(np.int64)
        u = np.concatenate([wide, deltas], axis=1) & 0xFFFF_FFFF
        words = np.empty((u.shape[0], 25), dtype=np.int64)
        words[:, 0:24:2] = u & 0xFFFF  # _LOW
        words[:, 1:24:2] = u >> 16  # _OUT
        words[:, 24] = np.rint(temp / 0.1).astype(np.int64) & 0xFFFF
        return words

    def _latch(self, i0: int, i1: int) -> None:
        """Output samples i0 .. i1 - 1 of the block are due: the newest into the output
        registers; DATA_CNTR counts them all; the truth records each."""
        b = self._block
        self.current = b.rows[i1 - 1].tolist()
        self.count = (self.count + i1 - i0) % R.DATA_CNTR_MODULO
        self.reads_this_period = 0
        self._oi = i1
        if self.record_truth:
            chans = {c: a[i0:i1] for c, a in b.truth.items()}
            self._truth_out.append((self.outputs_produced, b.t_ns[i0:i1], chans))
            if len(self._truth_out) > TRUTH_KEEP:
                del self._truth_out[: TRUTH_KEEP // 2]
        self.outputs_produced += i1 - i0

    def _register(self, reg: int) -> int:
        col = _COL.get(reg)
        if col is not None:
            return self.current[col]
        if reg == Reg.DATA_CNTR:
            return self.count
        if reg == Reg.PROD_ID:
            return self.identity(self.words[reg >> 1], 16)
        return self.words[reg >> 1]

    def drain_truth(self) -> Truth | None:
        if not self._truth_out:
            return None
        parts, self._truth_out = self._truth_out, []
        return Truth(
            parts[0][0],
            np.concatenate([p[1] for p in parts]),
            {c: np.concatenate([p[2][c] for p in parts]) for c in parts[0][2]},
        )

    # --- bus side ---------------------------------------------------------------------------
    def spi_frame(self, tx: bytes, speed_hz: int) -> bytes:
        if self._resets_ns and self.clock.now_ns() >= self._resets_ns[0]:
            self.self_resets_due()
        self._wake()
        n = len(tx)
        if n % 2:  # an SCLK count that is not a multiple of 16
            self.diag |= _SPI_ERROR
            self.pending = None
            return bytes(n)
        if self.busy_until_ns:
            return bytes(n)
        if n == R.BURST_FRAME_BYTES and (tx[0], tx[1]) == _BURST_HEAD:
            return self._burst(speed_hz)
        out = bytearray()
        for i in range(0, n, 2):
            out += self._frame16(tx[i] << 8 | tx[i + 1], speed_hz)
        return bytes(out)

    def _frame16(self, cmd: int, speed_hz: int) -> bytes:
        answer = self.pending or 0
        self.pending = None
        if cmd & 0x8000:
            self._write_byte((cmd >> 8) & 0x7F, cmd & 0xFF)
        else:
            self.register_reads += 1
            self.reads_this_period += 1
            reg = (cmd >> 8) & 0x7E
            if reg in _COL:
                self._words_read += 1
            if reg in _COL or reg == Reg.DATA_CNTR:
                self.advance()
            if self.reads_this_period > R.READS_PER_DR * self.dec:
                self.diag |= _OVERRUN
            if reg == Reg.DIAG_STAT:
                self.pending, self.diag = self.diag, 0
            elif reg != Reg.GLOB_CMD:  # write only: reads 0
                self.pending = self._register(reg)
            if reg == Reg.DATA_CNTR and self._words_read:  # the re-check after the words
                self._make_ahead()
        if speed_hz > R.MAX_SCLK_HZ:
            answer ^= int(self._glitch.integers(1, 0x10000))
        return answer.to_bytes(2, "big")

    def _burst(self, speed_hz: int) -> bytes:
        answer = self.pending or 0
        self.pending = None
        self.advance()
        self.bursts += 1
        c = self.current
        data = bytearray(
            _NINE.pack(self.diag, c[1], c[3], c[5], c[7], c[9], c[11], c[24], self.count)
        )
        self.diag = 0
        check = sum(data) & 0xFFFF
        if speed_hz > R.MAX_BURST_SCLK_HZ:  # clocked too fast: a byte comes out wrong
            data[int(self._glitch.integers(0, len(data)))] ^= int(self._glitch.integers(1, 256))
        out = answer.to_bytes(2, "big") + bytes(data) + check.to_bytes(2, "big")
        words_after = self._words_read > 0  # (between the last two bursts: the reader's habit)
        self._words_read = 0
        if not words_after:
            self._make_ahead()
        return out

    def _write_byte(self, addr: int, value: int) -> None:
        reg = addr & 0x7E
        if reg not in _WRITABLE:
            return
        self.advance()
        i = reg >> 1
        if addr & 1:
            self.words[i] = (self.words[i] & 0x00FF) | value << 8
            self._word_written(reg, self.words[i])
        else:
            self.words[i] = (self.words[i] & 0xFF00) | value

    def _word_written(self, reg: int, value: int) -> None:
        """A 16-bit write completes with its high byte."""
        if reg == Reg.GLOB_CMD:
            self.words[reg >> 1] = 0
            busy = max((t for bit, t in COMMAND_BUSY_NS.items() if value & bit), default=0)
            if busy:
                self._command = value & 0xFF
                self.busy_until_ns = self.clock.now_ns() + busy
                self.sampling = False
                self.pending = None
        elif reg == Reg.DEC_RATE:  # decimation starts over with the next internal sample
            now = self.clock.now_ns()
            self._restart_decimation(
                math.floor((now - self.grid_origin_ns) * self.rate_hz / 1e9) + 1
            )

    def power_on_reset(self) -> None:
        """A brown-out: as GLOB_CMD's software reset (silent for its 198 ms, then the flash
        defaults and DATA_CNTR from 0)."""
        self._word_written(Reg.GLOB_CMD, int(R.GlobCmd.SOFTWARE_RESET))

    # SampledChip's byte-register side does not exist on this chip
    def read(self, register: int, length: int) -> bytes:
        raise NotImplementedError("the ADIS16465 speaks 16-bit SPI frames (spi_frame)")

    def _write_one(self, reg: int, value: int) -> None:
        raise NotImplementedError("the ADIS16465 speaks 16-bit SPI frames (spi_frame)")
