"""Register-level BNO055 simulator: pages 0 and 1, power-on reset, operating modes with their
switching times, the data registers at 100 Hz (magnetometer at 20 Hz), a fusion output that
tracks the true orientation, calibration status that rises as the body moves through
orientations, a calibration profile (offsets) that round-trips, the axis remap, and the UART
protocol front end with its error answers.

What is modelled beyond the facts sheet (docs/chips/bno055.md), stated so it can be checked
against silicon:
- fusion: the chip's quaternion is the true one turned by a small error (4, 2, 1, 0.25 degrees
  at system calibration 0-3, about a fixed axis); gravity is the error quaternion's view of g,
  linear acceleration the compensated accel minus that gravity; NDOF's world is magnetic ENU
  (magnetic north on +y), IMU mode's heading starts at 0 when it is entered; Euler registers
  read 0 (imud does not use them);
- calibration status (only in fusion modes): gyro rises one step per 0.5 s of (constant-rate)
  motion, a still body included; accel and mag rise with the spread of the directions gravity
  and the field have taken in the body frame (sum over axes of max - min of the unit vector:
  1.0, 2.5, 4.0 for steps 1-3), which a still body never gets; system = the lowest of those
  the mode uses. A sensor reaching 3 stores its learned offsets (its true turn-on bias, the hard
  iron); outputs in fusion modes are compensated by whatever the offset registers hold. A
  profile written in CONFIG mode since the last reset counts as calibrated (3) for each sensor
  whose offsets were written (accel and mag need a non-zero radius) when a fusion mode starts;
- non-fusion (AMG) gyro counts scale with the GYR_CONFIG_0 range over 2^15 (firmware 3.11, as
  Linux reads it); temperature is deg C only; writes while the chip is switching modes are
  ignored (over UART: answered WRITE_FAIL); during the 650 ms reset reads return zeros and UART
  bytes are lost;
- UART: request bytes arrive at the link's rate; a request is executed once its last byte is
  in, answers leave at the link's rate; an unknown command byte is answered WRITE_FAIL; with
  `nak_rate` a request is answered BUS_OVER_RUN_ERROR (0x07) instead; `[device.sim.serial]`
  faults damage the answers (bytes corrupted, dropped, garbage before an answer), counted.
"""

from __future__ import annotations

import math
import struct
import threading
from collections import deque
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from imud.channels import Channel
from imud.chips.bno055 import registers as R
from imud.chips.bno055.noise import (
    ACCEL_FUSION_LPF_HZ,
    ACCEL_NOISE_UG_RTHZ,
    GYRO_FUSION_LPF_HZ,
    GYRO_NOISE_DPS_RTHZ,
    MAG_HOLD,
    MAG_NOISE_UT,
)
from imud.chips.bno055.registers import Page0 as P0
from imud.chips.bno055.registers import Page1 as P1
from imud.clock import Clock
from imud.rotations import quat_conj, quat_from_axis_angle, quat_from_matrix, quat_mul_floats
from imud.sim.api import SimDie, StreamDie, Truth
from imud.sim.chip import TRUTH_KEEP, SampledChip
from imud.sim.filters import NoiseStream, enbw_fir
from imud.sim.physics import ChipFigures, MagneticField
from imud.sim.settings import SimSettings
from imud.units import STANDARD_GRAVITY as G

F64 = npt.NDArray[np.float64]
# The BNO055's own sheet gives no noise densities; these are its accelerometer's and gyroscope's
# class (imud/chips/bno055/noise.py, shared with the ROS 2 covariances), bias stability ~5 deg/h
FIGURES = ChipFigures(
    accel_noise_ug_rthz=ACCEL_NOISE_UG_RTHZ,
    gyro_noise_dps_rthz=GYRO_NOISE_DPS_RTHZ,
    accel_bias_mg=30.0,
    gyro_bias_dps=0.5,
    accel_bias_instability_ug=100.0,
    gyro_bias_instability_dph=5.0,
    scale_error=0.01,
    misalignment_deg=0.3,
    accel_temp_drift_mg_per_c=0.3,
    gyro_temp_drift_dps_per_c=0.01,
)

RATE_HZ = 100.0
MAG_EVERY = MAG_HOLD  # the magnetometer updates at 20 Hz in the fusion modes
AHEAD = 25  # samples whose physics is computed at once, ahead (a quarter of a second)
RESET_BUSY_NS = 650_000_000
TO_MODE_NS = 7_000_000  # CONFIGMODE -> operation mode
TO_CONFIG_NS = 19_000_000  # operation mode -> CONFIGMODE
RX_TIMEOUT_NS = 30_000_000
MAX_LENGTH = 128
GYRO_STEP_S = 0.5
SPREAD_STEPS = (1.0, 2.5, 4.0)
ERROR_DEG = (4.0, 2.0, 1.0, 0.25)
ACC_RADIUS = 1000
MAG_RADIUS_MAX = 960
ACC_FULL_SCALE_G = 4.0

_FUSION = frozenset(int(m) for m in R.FUSION_MODES)
_USES_MAG = frozenset(
    int(m) for m in (R.OprMode.NDOF, R.OprMode.NDOF_FMC_OFF, R.OprMode.COMPASS, R.OprMode.M4G)
)
_CONFIG = int(R.OprMode.CONFIG)
_IMU = int(R.OprMode.IMU)
_RST_SYS = int(R.SysTrigger.RST_SYS)
_CLK_SEL = int(R.SysTrigger.CLK_SEL)
_ACC_MG, _GYR_RPS = int(R.UnitSel.ACC_MG), int(R.UnitSel.GYR_RPS)
_START, _READ, _WRITE = int(R.Uart.START), int(R.Uart.READ), int(R.Uart.WRITE)
_READ_OK, _STATUS = int(R.Uart.READ_RESPONSE), int(R.Uart.STATUS_RESPONSE)
S = R.UartStatus

_PAGE0_DEFAULTS = {
    P0.CHIP_ID: 0xA0, P0.ACC_ID: 0xFB, P0.MAG_ID: 0x32, P0.GYR_ID: 0x0F,
    P0.SW_REV_ID_LSB: 0x11, P0.SW_REV_ID_MSB: 0x03, P0.BL_REV_ID: 0x15,  # firmware 3.11
    0x36: 0x0F,  # ST_RESULT: every self-test passed
    P0.UNIT_SEL: 0x80, P0.AXIS_MAP_CONFIG: 0x24, P0.AXIS_MAP_SIGN: 0x00,
}  # fmt: skip
_PAGE1_DEFAULTS = {0x08: 0x0D, 0x09: 0x0B, P1.GYR_CONFIG_0: 0x38, 0x0B: 0x00}
_READ_ONLY0 = frozenset(range(0x00, 0x07)) | frozenset(range(0x08, 0x3B))
_ANY_MODE0 = frozenset({P0.PAGE_ID, P0.OPR_MODE, P0.SYS_TRIGGER})
_PROFILE = (0x55, 0x6A)
# the MSB whose write applies a profile field, and which sensor it belongs to
_APPLIES = {0x5A: "accel", 0x60: "mag", 0x66: "gyro", 0x68: "accel_radius", 0x6A: "mag_radius"}


def _valid0(reg: int) -> bool:
    return reg <= _PROFILE[1] and reg != 0x3C


def _valid1(reg: int) -> bool:
    return (0x07 <= reg <= 0x1F and reg != 0x0E) or 0x50 <= reg <= 0x5F


def _i16(values: F64) -> bytes:
    clipped = np.clip(np.rint(values), -32768, 32767)
    return clipped.astype("<i2").tobytes()


def _i16s(values: list[float]) -> bytes:
    """As `_i16`, for a few Python floats (round half to even, as np.rint)."""
    return struct.pack(f"<{len(values)}h", *(min(max(round(v), -32768), 32767) for v in values))


class _Physics:
    """What the chip sensed at a run of grid instants: the truth and the sensors' readings."""

    def __init__(self, t_ns: npt.NDArray[np.int64], *arrays: F64) -> None:
        self.t_ns = t_ns
        self.k0 = 0  # the grid index of the first
        self._arrays = arrays  # accel, gyro, orientation, temperature, accel and gyro
        # readings, field in the body, field reading

    def part(self, i: int, j: int) -> _Physics:
        return _Physics(self.t_ns[i:j], *(a[i:j] for a in self._arrays))

    def arrays(self) -> tuple[F64, ...]:
        return self._arrays


class _OutputSetup(NamedTuple):
    key: tuple[object, ...]
    remap: F64
    acc_off: F64
    gyr_off: F64
    mag_off: F64
    err: tuple[float, ...]  # the fusion's orientation error at its calibration level
    world: tuple[float, ...]  # its world reference
    remap_q: tuple[float, ...]  # the axis remap's rotation, after the truth


def _yaw(q: F64) -> float:
    w, x, y, z = (float(v) for v in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _units(v: F64) -> F64:
    n = np.linalg.norm(v, axis=1, keepdims=True)
    out: F64 = v / np.where(n > 0, n, 1.0)
    return out


class Bno055Sim(SampledChip):
    def __init__(self, settings: SimSettings, clock: Clock, serial_baud: int | None = None) -> None:
        super().__init__(settings, clock, FIGURES)
        self._truth: list[dict[str, Any]] = []  # made here, whole (`_produce`)
        seeds = np.random.SeedSequence([settings.seed, 0x055]).spawn(3)
        magnetic = settings.magnetic
        if "noise_ut" not in magnetic.model_fields_set:  # the chip's figure unless overridden
            magnetic = magnetic.model_copy(update={"noise_ut": MAG_NOISE_UT})
        self.field = MagneticField(magnetic, np.random.default_rng(seeds[0]))
        rng = np.random.default_rng(seeds[1])
        axis = rng.normal(size=3)
        self.error_axis = axis / np.linalg.norm(axis)
        self.uid = bytes(int(b) for b in rng.integers(0, 256, 16))
        self.lock = threading.RLock()  # the pty pump and the bus worker (truth) both come here
        self.uart = UartFrontEnd(self, serial_baud, settings, seeds[2]) if serial_baud else None
        self.resets = 0
        self._setup: _OutputSetup | None = None
        self._ahead: _Physics | None = None  # samples computed ahead (`_physics_of`)
        # fusion mode locks the filters at accel 62.5 Hz and gyro 32 Hz (noise.py); at 100 Hz
        # out only the gyro's narrows the noise, the accel's band is above the Nyquist and
        # aliases: white, drawn at that band's variance; no delay is published (0)
        self._noise = (NoiseStream(enbw_fir(ACCEL_FUSION_LPF_HZ, RATE_HZ)),
                       NoiseStream(enbw_fir(GYRO_FUSION_LPF_HZ, RATE_HZ)))  # fmt: skip
        self._aliased = tuple(
            math.sqrt(max(1.0, bw / (RATE_HZ / 2)))
            for bw in (ACCEL_FUSION_LPF_HZ, GYRO_FUSION_LPF_HZ)
        )
        self._power_on_reset()

    @property
    def dies(self) -> Sequence[SimDie | StreamDie]:  # type: ignore[override]
        return (self.uart,) if self.uart is not None else (self,)

    # --- state ------------------------------------------------------------------------------
    def _power_on_reset(self) -> None:
        self._ahead = None
        self.p0 = bytearray(128)
        self.p1 = bytearray(128)
        for reg, val in _PAGE0_DEFAULTS.items():
            self.p0[reg] = val
        for reg, val in _PAGE1_DEFAULTS.items():
            self.p1[reg] = val
        self.p1[P1.UNIQUE_ID : P1.UNIQUE_ID + 16] = self.uid
        self.page = 0
        self.mode = _CONFIG
        self.sampling = False
        self.busy_until_ns = 0
        self.reset_until_ns = 0
        self.levels = {"gyro": 0, "accel": 0, "mag": 0}
        self.learned: set[str] = set()
        self.profile_written: set[str] = set()
        self.steady_s = 0.0
        self.acc_lo, self.acc_hi = np.full(3, np.inf), np.full(3, -np.inf)
        self.mag_lo, self.mag_hi = np.full(3, np.inf), np.full(3, -np.inf)
        self.world_ref = np.array([1.0, 0.0, 0.0, 0.0])  # chip world <- ENU
        self.mag_latched = np.zeros(3)

    @property
    def rate_hz(self) -> float:
        return RATE_HZ * (1 + self.clock_error)

    @property
    def fusion(self) -> bool:
        return self.mode in _FUSION

    def resetting(self, t_ns: int) -> bool:
        return t_ns < self.reset_until_ns

    def calib_stat(self) -> int:
        if not self.fusion:
            return 0
        lv = self.levels
        used = [lv["gyro"], lv["accel"]] + ([lv["mag"]] if self.mode in _USES_MAG else [])
        return (min(used) << 6) | (lv["gyro"] << 4) | (lv["accel"] << 2) | lv["mag"]

    # --- sampling ---------------------------------------------------------------------------
    def _physics(self, t_ns: npt.NDArray[np.int64]) -> _Physics:
        t_s = (t_ns - self.t_origin_ns) / 1e9
        f, w = self.motion.sample(t_s)
        q = self.motion.orientation(t_s)
        temp = self.temp.at(t_s)
        e, rng, n = self.errors, self.errors.noise_rng, t_ns.shape[0]
        fm = e.accel.deterministic(t_s, f, temp)
        fm += self._noise[0].draw(rng, e.accel.noise * self._aliased[0], self.rate_hz, n)
        wm = e.gyro.deterministic(t_s, w, temp)
        wm += self._noise[1].draw(rng, e.gyro.noise * self._aliased[1], self.rate_hz, n)
        b = self.field.in_body(q)
        return _Physics(t_ns, f, w, q, temp, fm, wm, b, self.field.measure(b))

    def _physics_of(self, t_ns: npt.NDArray[np.int64]) -> _Physics:
        """The physics of the samples at `t_ns` (the grid's next ones), from a block computed
        ahead: a read every few ms finds one sample due at a time, and the models' cost is per
        call, not per sample. A block is the grid's next AHEAD samples; a new grid (a mode
        switch) or a reset starts another."""
        n = t_ns.shape[0]
        blk, k = self._ahead, self.next_k
        if blk is not None and blk.k0 <= k and k + n <= blk.k0 + blk.t_ns.shape[0]:
            i = k - blk.k0
            if np.array_equal(blk.t_ns[i : i + n], t_ns):
                return blk.part(i, i + n)
        period = 1e9 / self.rate_hz
        _, grid = next(self._grid(k, k + max(n, AHEAD) - 1, period))
        if not np.array_equal(grid[:n], t_ns):  # not the grid's: compute just these
            self._ahead = None
            return self._physics(t_ns)
        blk = self._physics(grid)
        blk.k0 = k
        self._ahead = blk
        return blk.part(0, n)

    def _produce(self, t_ns: npt.NDArray[np.int64]) -> None:
        f, w, q, temp, fm, wm, b, mm = self._physics_of(t_ns).arrays()
        n = t_ns.shape[0]
        k = self.samples_produced + np.arange(n)
        latch = np.flatnonzero(k % MAG_EVERY == 0)
        if latch.size:
            self.mag_latched = mm[latch[-1]]
        if self.fusion:
            self._calibrate(n, f, b)
        self._outputs(fm[-1], wm[-1], q[-1], float(temp[-1]))
        if self.record_truth:
            self._truth.append(
                {
                    "index": self.samples_produced,
                    "t_ns": t_ns,
                    "accel": f,
                    "gyro": w,
                    "temp": temp,
                    "orientation": q,
                    "mag": b,
                }
            )
            if len(self._truth) > TRUTH_KEEP:
                del self._truth[: TRUTH_KEEP // 2]
        self.samples_produced += n

    def _emit(self, *args: Any) -> None:  # _produce does the whole job here
        raise NotImplementedError

    def _calibrate(self, n: int, f: F64, b: F64) -> None:
        """The calibration model (module docstring): levels only rise while fusion runs."""
        self.steady_s += n / self.rate_hz
        a = _units(f)
        self.acc_lo = np.minimum(self.acc_lo, a.min(axis=0))
        self.acc_hi = np.maximum(self.acc_hi, a.max(axis=0))
        new = {"gyro": min(3, int(self.steady_s / GYRO_STEP_S))}
        new["accel"] = sum(float((self.acc_hi - self.acc_lo).sum()) >= s for s in SPREAD_STEPS)
        if self.mode in _USES_MAG:
            m = _units(b)
            self.mag_lo = np.minimum(self.mag_lo, m.min(axis=0))
            self.mag_hi = np.maximum(self.mag_hi, m.max(axis=0))
            new["mag"] = sum(float((self.mag_hi - self.mag_lo).sum()) >= s for s in SPREAD_STEPS)
        for sensor, level in new.items():
            if level > self.levels[sensor]:
                self.levels[sensor] = level
                if level == 3 and sensor not in self.learned:
                    self._learn(sensor)

    def _learn(self, sensor: str) -> None:
        """The offsets the chip found, into the profile registers (in UNIT_SEL's units)."""
        self.learned.add(sensor)
        unit = self.p0[P0.UNIT_SEL]
        if sensor == "accel":
            lsb = 1.0 / (G * 1e-3) if unit & _ACC_MG else 100.0
            self._put(0x55, self.errors.accel.bias * lsb)
            self._put(0x67, np.array([ACC_RADIUS]))
        elif sensor == "gyro":
            lsb = 900.0 if unit & _GYR_RPS else 16.0 * 180.0 / math.pi
            self._put(0x61, self.errors.gyro.bias * lsb)
        else:
            self._put(0x5B, self.field.hard_iron * 1e6 * 16.0)
            radius = min(MAG_RADIUS_MAX, round(float(np.linalg.norm(self.field.world)) * 16e6))
            self._put(0x69, np.array([radius]))

    def _put(self, reg: int, values: F64) -> None:
        data = _i16(np.asarray(values, dtype=np.float64))
        self.p0[reg : reg + len(data)] = data

    def _profile(self, reg: int, per_si: float) -> F64:
        return np.frombuffer(bytes(self.p0[reg : reg + 6]), dtype="<i2").astype(float) / per_si

    def _remap(self) -> F64:
        """The axis remap as a matrix: published = M @ chip axes."""
        cfg, sign = self.p0[P0.AXIS_MAP_CONFIG], self.p0[P0.AXIS_MAP_SIGN]
        m = np.zeros((3, 3))
        for i in range(3):
            m[i, (cfg >> (2 * i)) & 3] = -1.0 if sign & (4 >> i) else 1.0
        return m

    def _output_setup(self) -> _OutputSetup:
        """What the outputs take from the registers and the fusion state, remade only when one
        of them changed (a sample's outputs then cost scalar arithmetic, not array calls)."""
        p = self.p0
        key = (
            bytes(p[0x55:0x67]),
            p[P0.UNIT_SEL],
            p[P0.AXIS_MAP_CONFIG],
            p[P0.AXIS_MAP_SIGN],
            self.fusion,
            self.calib_stat(),
            self.world_ref.tobytes(),
        )
        setup = self._setup
        if setup is not None and setup.key == key:
            return setup
        unit = p[P0.UNIT_SEL]
        m = self._remap()
        acc_off = gyr_off = mag_off = np.zeros(3)
        if self.fusion:  # offset compensated by what the profile registers hold
            acc_off = self._profile(0x55, 100.0 if not unit & _ACC_MG else 1 / (G * 1e-3))
            gyr_off = self._profile(0x61, 900.0 if unit & _GYR_RPS else 16 * 180 / math.pi)
            mag_off = self._profile(0x5B, 16e6)
        sys_level = self.calib_stat() >> 6
        err = quat_from_axis_angle(self.error_axis, math.radians(ERROR_DEG[sys_level]))
        setup = _OutputSetup(
            key, m, acc_off, gyr_off, mag_off,
            tuple(err.tolist()),
            tuple(self.world_ref.tolist()),
            tuple(quat_conj(quat_from_matrix(m)).tolist()),
        )  # fmt: skip
        self._setup = setup
        return setup

    def _outputs(self, acc: F64, gyr: F64, q_true: F64, temp_c: float) -> None:
        """The newest sample into the data registers, as the mode and UNIT_SEL make it."""
        p = self.p0
        unit = p[P0.UNIT_SEL]
        c = self._output_setup()
        m = c.remap
        acc, gyr, mag = (
            m @ (acc - c.acc_off),
            m @ (gyr - c.gyr_off),
            m @ (self.mag_latched - c.mag_off),
        )
        acc_lsb = G * 1e-3 if unit & _ACC_MG else 0.01
        full = ACC_FULL_SCALE_G * G / acc_lsb
        ax, ay, az = acc.tolist()
        p[0x08:0x0E] = _i16s([min(max(v / acc_lsb, -full), full) for v in (ax, ay, az)])
        p[0x0E:0x14] = _i16s([v * 1e6 * 16.0 for v in mag.tolist()])
        range_dps = 2000.0 / 2 ** (self.p1[P1.GYR_CONFIG_0] & 0x07)
        if self.fusion:
            per = 900.0 if unit & _GYR_RPS else 16.0 * 180.0 / math.pi
            cap = math.radians(range_dps) * per
        else:  # raw counts: the range over 2^15, in either unit (firmware 3.11)
            per, cap = 2**15 / math.radians(range_dps), 32767.0
        p[0x14:0x1A] = _i16s([min(max(v * per, -cap), cap) for v in gyr.tolist()])
        p[0x34] = min(max(round(temp_c), -128), 127) & 0xFF
        p[0x35] = self.calib_stat()
        if not self.fusion:
            p[0x1A:0x34] = bytes(0x34 - 0x1A)
            return
        w, x, y, z = quat_mul_floats(
            quat_mul_floats(c.err, quat_mul_floats(c.world, q_true.tolist())), c.remap_q
        )
        # gravity in the (remapped) body, the world's (0, 0, G) turned by the inverse of q: the
        # operations of `quat_rotate(quat_conj(q), (0, 0, G))` in its order, so the same bits
        gx = w * (2.0 * -(y * G)) + z * (2.0 * (x * G))
        gy = w * (2.0 * (x * G)) + z * (2.0 * (y * G))
        gz = G + (-(x * (2.0 * (x * G))) - y * (2.0 * (y * G)))
        p[0x1A:0x20] = bytes(6)
        p[0x20:0x28] = _i16s([w * 16384.0, x * 16384.0, y * 16384.0, z * 16384.0])
        p[0x28:0x2E] = _i16s([(ax - gx) / acc_lsb, (ay - gy) / acc_lsb, (az - gz) / acc_lsb])
        p[0x2E:0x34] = _i16s([gx / acc_lsb, gy / acc_lsb, gz / acc_lsb])

    # --- modes ------------------------------------------------------------------------------
    def _set_mode(self, mode: int, now: int) -> None:
        if mode == self.mode:
            return
        if mode == _CONFIG:
            self.sampling = False
            self.p0[0x08:0x35] = bytes(0x35 - 0x08)  # outputs read zero in CONFIG mode
            self.busy_until_ns = now + TO_CONFIG_NS
            self.p0[P0.SYS_STATUS] = 0
        else:
            start = now + TO_MODE_NS
            self.busy_until_ns = start
            if mode in _FUSION and self.mode not in _FUSION:
                self._start_fusion(mode, start)
            self.sampling = True
            self._anchor(start)
            self.p0[P0.SYS_STATUS] = 5 if mode in _FUSION else 6
        self.mode = mode
        self.p0[P0.OPR_MODE] = mode

    def _start_fusion(self, mode: int, t_ns: int) -> None:
        """A profile written since reset counts as calibrated; the heading reference is set."""
        w = self.profile_written
        radius = np.frombuffer(bytes(self.p0[0x67:0x6B]), dtype="<i2")
        if "accel" in w and "accel_radius" in w and radius[0]:
            self.levels["accel"] = 3
        if "gyro" in w:
            self.levels["gyro"] = 3
        if "mag" in w and "mag_radius" in w and radius[1]:
            self.levels["mag"] = 3
        if mode == _IMU:  # relative heading: 0 where the fusion starts
            q_now = self.motion.orientation(np.array([(t_ns - self.t_origin_ns) / 1e9]))[0]
            z = np.array([0.0, 0.0, 1.0])
            self.world_ref = quat_from_axis_angle(z, -_yaw(q_now))
        else:  # magnetic ENU: magnetic north on +y
            z = np.array([0.0, 0.0, 1.0])
            self.world_ref = quat_from_axis_angle(z, self.field.declination_rad)

    # --- bus side ---------------------------------------------------------------------------
    def read(self, register: int, length: int) -> bytes:
        with self.lock:
            now = self.clock.now_ns()
            if self.resetting(now):
                return bytes(length)
            self.advance()
            regs = self.p0 if self.page == 0 else self.p1
            out = bytes(regs[register : register + length])
            if self.page == 0 and register <= P0.CHIP_ID < register + len(out):
                i = P0.CHIP_ID - register
                out = out[:i] + bytes([self.identity(out[i])]) + out[i + 1 :]
            return out + bytes(length - len(out))

    def power_on_reset(self) -> None:
        """A brown-out: as RST_SYS (defaults, CONFIG mode, silent while it boots)."""
        with self.lock:
            self.resets += 1
            self._power_on_reset()
            self.reset_until_ns = self.clock.now_ns() + RESET_BUSY_NS

    def write(self, register: int, data: bytes) -> None:
        self.write_status(register, data)

    def write_status(self, register: int, data: bytes) -> int | None:
        """A burst write; the UART status it earns (None: the chip reset, no answer)."""
        with self.lock:
            now = self.clock.now_ns()
            if self.resetting(now) or now < self.busy_until_ns:
                return int(S.WRITE_FAIL)
            self.advance()
            for i, value in enumerate(data):
                reg = register + i
                if self.page == 1:
                    if not _valid1(reg):
                        return int(S.REGMAP_INVALID_ADDRESS)
                    if reg in (0x07,):
                        self.page = value & 1
                    elif 0x08 <= reg <= 0x1F and self.mode == _CONFIG:
                        self.p1[reg] = value
                    else:
                        return int(S.REGMAP_WRITE_DISABLED)
                    continue
                if not _valid0(reg):
                    return int(S.REGMAP_INVALID_ADDRESS)
                if reg in _READ_ONLY0:
                    return int(S.REGMAP_WRITE_DISABLED)
                if reg not in _ANY_MODE0 and self.mode != _CONFIG:
                    return int(S.REGMAP_WRITE_DISABLED)
                if reg == P0.SYS_TRIGGER and value & _RST_SYS:
                    self.resets += 1
                    self._power_on_reset()
                    self.reset_until_ns = now + RESET_BUSY_NS
                    return None
                self._write0(reg, value, now)
            return int(S.WRITE_SUCCESS)

    def _write0(self, reg: int, value: int, now: int) -> None:
        if reg == P0.PAGE_ID:
            self.page = value & 1
            self.p0[reg] = self.p1[reg] = self.page
        elif reg == P0.OPR_MODE:
            self._set_mode(value & 0x0F, now)
        elif reg == P0.SYS_TRIGGER:
            self.p0[reg] = value & _CLK_SEL  # the other bits clear themselves
        elif reg == P0.AXIS_MAP_CONFIG:
            axes = [(value >> s) & 3 for s in (0, 2, 4)]
            if sorted(axes) == [0, 1, 2]:  # an axis used twice: the old setting stays
                self.p0[reg] = value & 0x3F
        else:
            self.p0[reg] = value
            if reg in _APPLIES:
                self.profile_written.add(_APPLIES[reg])

    def valid_read(self, register: int) -> bool:
        return _valid0(register) if self.page == 0 else _valid1(register)

    def drain_truth(self) -> Truth | None:
        with self.lock:
            if not self._truth:
                return None
            parts, self._truth = self._truth, []
        return Truth(
            int(parts[0]["index"]),
            np.concatenate([p["t_ns"] for p in parts]),
            {
                Channel.ACCEL: np.concatenate([p["accel"] for p in parts]),
                Channel.GYRO: np.concatenate([p["gyro"] for p in parts]),
                Channel.TEMPERATURE: np.concatenate([p["temp"] for p in parts]),
                Channel.ORIENTATION: np.concatenate([p["orientation"] for p in parts]),
                Channel.MAG: np.concatenate([p["mag"] for p in parts]),
            },
        )


class UartFrontEnd:
    """The chip's UART: request bytes in at the link's rate, answers out at the link's rate."""

    def __init__(
        self, chip: Bno055Sim, baud: int, s: SimSettings, seed: np.random.SeedSequence
    ) -> None:
        self.chip = chip
        self.clock = chip.clock
        self.char_ns = 10e9 / baud  # 8N1
        self.rng = np.random.default_rng(seed)
        self.overrun_rate = s.nak_rate
        self.faults = s.serial
        self.rx: deque[tuple[int, int]] = deque()  # (instant its last bit is in, byte)
        self.rx_free = 0
        self.frame = bytearray()
        self.last_rx = 0
        self.tx: deque[tuple[int, int]] = deque()  # (instant its last bit is out, byte)
        self.tx_free = 0
        self.answers: dict[str, int] = {}  # status answers by name
        self.requests = 0
        self.corrupted = self.dropped = self.garbage_bursts = 0

    # --- StreamDie --------------------------------------------------------------------------
    def receive(self, data: bytes) -> None:
        with self.chip.lock:
            now = self.clock.now_ns()
            for b in data:
                self.rx_free = int(max(now, self.rx_free) + self.char_ns)
                self.rx.append((self.rx_free, b))

    def transmit(self, now_ns: int) -> bytes:
        with self.chip.lock:
            self._process(now_ns)
            out = bytearray()
            while self.tx and self.tx[0][0] <= now_ns:
                out.append(self.tx.popleft()[1])
            return bytes(out)

    def next_transmit_ns(self) -> int | None:
        with self.chip.lock:
            times = [q[0][0] for q in (self.tx, self.rx) if q]
            if self.frame:
                times.append(self.last_rx + RX_TIMEOUT_NS + 1)
            return min(times) if times else None

    # --- protocol ---------------------------------------------------------------------------
    def _process(self, now: int) -> None:
        while self.rx and self.rx[0][0] <= now:
            t, b = self.rx.popleft()
            if self.chip.resetting(t):
                continue  # rebooting: the byte is lost
            if self.frame and t - self.last_rx > RX_TIMEOUT_NS:
                self._status(S.RECEIVE_CHARACTER_TIMEOUT, self.last_rx + RX_TIMEOUT_NS)
                self.frame.clear()
            self.last_rx = t
            if not self.frame and b != _START:
                self._status(S.WRONG_START_BYTE, now)
                continue
            self.frame.append(b)
            self._request(now)
        if self.frame and now - self.last_rx > RX_TIMEOUT_NS:
            self._status(S.RECEIVE_CHARACTER_TIMEOUT, self.last_rx + RX_TIMEOUT_NS)
            self.frame.clear()

    def _request(self, now: int) -> None:
        f = self.frame
        if len(f) < 4:
            return
        op, reg, length = f[1], f[2], f[3]
        if op == _WRITE and 1 <= length <= MAX_LENGTH and len(f) < 4 + length:
            return  # the data is still coming
        data = bytes(f[4 : 4 + length])
        self.frame = bytearray()
        self.requests += 1
        if op not in (_READ, _WRITE):
            self._status(S.WRITE_FAIL, now)
        elif length == 0:
            self._status(S.MIN_LENGTH_ERROR, now)
        elif length > MAX_LENGTH:
            self._status(S.MAX_LENGTH_ERROR, now)
        elif self.overrun_rate and self.rng.random() < self.overrun_rate:
            self._status(S.BUS_OVER_RUN_ERROR, now)
        elif op == _READ:
            if not self.chip.valid_read(reg):
                self._status(S.REGMAP_INVALID_ADDRESS, now)
            else:
                data = self.chip.read(reg, length)
                # the answer leaves after the snapshot, however late this thread got to it
                self._send(bytes([_READ_OK, length]) + data, self.clock.now_ns())
        else:
            status = self.chip.write_status(reg, data)
            if status is not None:  # None: the chip reset itself, it does not answer
                self._status(status, self.clock.now_ns())

    def _status(self, code: int, at: int) -> None:
        name = S(code).name
        if code != S.WRITE_SUCCESS:
            self.answers[name] = self.answers.get(name, 0) + 1
        self._send(bytes([_STATUS, code]), at)

    def _send(self, message: bytes, at: int) -> None:
        f = self.faults
        out = bytearray()
        if f.garbage_rate and self.rng.random() < f.garbage_rate:
            self.garbage_bursts += 1
            out += bytes(int(b) for b in self.rng.integers(0, 256, f.garbage_bytes))
        for b in message:
            if f.drop_rate and self.rng.random() < f.drop_rate:
                self.dropped += 1
                continue
            if f.corrupt_rate and self.rng.random() < f.corrupt_rate:
                self.corrupted += 1
                b ^= 1 << int(self.rng.integers(0, 8))
            out.append(b)
        t = max(at, self.tx_free)
        for b in out:
            t = int(t + self.char_ns)
            self.tx.append((t, b))
        self.tx_free = max(self.tx_free, t)
