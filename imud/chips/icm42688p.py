"""TDK InvenSense ICM-42688-P over SPI or I2C: register map, config model, FIFO packet driver.

Facts (registers, packet layouts, scale factors, reset sequence) as summarised in
docs/chips/icm42688p-facts.md. The FIFO runs in stop-on-full mode, so a full FIFO keeps whole,
valid packets: imud reads them, and counts the samples the chip dropped meanwhile.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from pydantic import Field, ValidationInfo, field_validator

from imud.buses.models import I2cBus, SimBus
from imud.buses.registers import RegisterDevice
from imud.chips.base import DeviceBase, DeviceIdentityError, DriverCounters, RawBatch
from imud.chips.checks import RegisterChecker
from imud.clock import Clock
from imud.errors import BusError

STANDARD_GRAVITY = 9.80665

# Bank 0
DEVICE_CONFIG = 0x11
FIFO_CONFIG = 0x16
TEMP_DATA1 = 0x1D
INT_STATUS = 0x2D
FIFO_COUNTH = 0x2E
FIFO_DATA = 0x30
SIGNAL_PATH_RESET = 0x4B
INTF_CONFIG0 = 0x4C
PWR_MGMT0 = 0x4E
GYRO_CONFIG0 = 0x4F
ACCEL_CONFIG0 = 0x50
GYRO_ACCEL_CONFIG0 = 0x52
TMST_CONFIG = 0x54
FIFO_CONFIG1 = 0x5F
INT_CONFIG1 = 0x64
WHO_AM_I = 0x75
REG_BANK_SEL = 0x76
# Bank 1 / bank 2: anti-alias filters
GYRO_CONFIG_STATIC2 = 0x0B
GYRO_CONFIG_STATIC3 = 0x0C
GYRO_CONFIG_STATIC4 = 0x0D
GYRO_CONFIG_STATIC5 = 0x0E
ACCEL_CONFIG_STATIC2 = 0x03
ACCEL_CONFIG_STATIC3 = 0x04
ACCEL_CONFIG_STATIC4 = 0x05

WHO_AM_I_VALUE = 0x47
SOFT_RESET = 0x01
INT_RESET_DONE = 0x10
INT_FIFO_FULL = 0x02
FIFO_FLUSH = 0x02
FIFO_MODE_STOP_ON_FULL = 0x80
FIFO_ACCEL_EN = 0x01
FIFO_GYRO_EN = 0x02
FIFO_TEMP_EN = 0x04
FIFO_HIRES_EN = 0x10
INTF_COUNT_BE_DATA_BE = 0x30  # FIFO count big-endian in bytes, sensor data big-endian
PWR_LOW_NOISE = 0x0F  # gyro LN (3 << 2) | accel LN (3)
TMST_EN = 0x01
HDR_EMPTY = 0x80
HDR_ACCEL = 0x40
HDR_GYRO = 0x20
HDR_20 = 0x10
HDR_ODR_CHANGED = 0x03

FIFO_SIZE = 2048
PACKET = 16
PACKET_HIRES = 20
RESET_WAIT_NS = 2_000_000  # datasheet 1 ms, with margin
STARTUP_WAIT_NS = 50_000_000  # gyro start-up before data is valid
POWER_ON_WAIT_NS = 300_000  # datasheet: >= 200 us after a PWR_MGMT0 change before any write
MAX_SPI_HZ = 24_000_000

GYRO_RANGES_DPS: tuple[float, ...] = (
    2000.0,
    1000.0,
    500.0,
    250.0,
    125.0,
    62.5,
    31.25,
    15.625,
)  # FS_SEL 0..7
ACCEL_RANGES_G = (16, 8, 4, 2)  # FS_SEL 0..3
ODR_CODES: dict[float, int] = {
    32000.0: 1, 16000.0: 2, 8000.0: 3, 4000.0: 4, 2000.0: 5, 1000.0: 6,
    500.0: 15, 200.0: 7, 100.0: 8, 50.0: 9, 25.0: 10, 12.5: 11,
}  # fmt: skip
# GYRO_ACCEL_CONFIG0 UI filter bandwidth codes, low-noise mode
UI_FILTERS: dict[str, int] = {
    "odr/2": 0, "odr/4": 1, "odr/5": 2, "odr/8": 3, "odr/10": 4, "odr/16": 5, "odr/20": 6,
    "odr/40": 7, "low_latency": 14, "low_latency_8x": 15,
}  # fmt: skip

# Anti-alias filter: 3 dB bandwidth (Hz) -> (DELT, DELTSQR, BITSHIFT), datasheet section 5.3
AAF_TABLE: dict[int, tuple[int, int, int]] = {
    42: (1, 1, 15), 84: (2, 4, 13), 126: (3, 9, 12), 170: (4, 16, 11), 213: (5, 25, 10),
    258: (6, 36, 10), 303: (7, 49, 9), 348: (8, 64, 9), 394: (9, 81, 9), 441: (10, 100, 8),
    488: (11, 122, 8), 536: (12, 144, 8), 585: (13, 170, 8), 634: (14, 196, 7), 684: (15, 224, 7),
    734: (16, 256, 7), 785: (17, 288, 7), 837: (18, 324, 7), 890: (19, 360, 6), 943: (20, 400, 6),
    997: (21, 440, 6), 1051: (22, 488, 6), 1107: (23, 528, 6), 1163: (24, 576, 6),
    1220: (25, 624, 6), 1277: (26, 680, 6), 1336: (27, 736, 5), 1395: (28, 784, 5),
    1454: (29, 848, 5), 1515: (30, 896, 5), 1577: (31, 960, 5), 1639: (32, 1024, 5),
    1702: (33, 1088, 5), 1766: (34, 1152, 5), 1830: (35, 1232, 5), 1896: (36, 1296, 5),
    1962: (37, 1376, 4), 2029: (38, 1440, 4), 2097: (39, 1536, 4), 2166: (40, 1600, 4),
    2235: (41, 1696, 4), 2306: (42, 1760, 4), 2377: (43, 1856, 4), 2449: (44, 1952, 4),
    2522: (45, 2016, 4), 2596: (46, 2112, 4), 2671: (47, 2208, 4), 2746: (48, 2304, 4),
    2823: (49, 2400, 4), 2900: (50, 2496, 4), 2978: (51, 2592, 4), 3057: (52, 2720, 4),
    3137: (53, 2816, 3), 3217: (54, 2944, 3), 3299: (55, 3008, 3), 3381: (56, 3136, 3),
    3464: (57, 3264, 3), 3548: (58, 3392, 3), 3633: (59, 3456, 3), 3718: (60, 3584, 3),
    3805: (61, 3712, 3), 3892: (62, 3840, 3), 3979: (63, 3968, 3),
}  # fmt: skip
AAF_DEFAULT_GYRO_HZ = 585  # the reset rows
AAF_DEFAULT_ACCEL_HZ = 1163
GYRO_AAF_DIS = 0x02
ACCEL_AAF_DIS = 0x01
INTF_CONFIG1 = 0x4D
INTF_CONFIG1_NO_AUTORANGE = 0x51  # reset 0x91; the top bits' auto-ranging freezes the gyro

UiFilter = Literal[
    "odr/2", "odr/4", "odr/5", "odr/8", "odr/10", "odr/16", "odr/20", "odr/40",
    "low_latency", "low_latency_8x",
]  # fmt: skip

I2C_BITS_PER_BYTE = 9  # 8 data + ACK
SPI_BITS_PER_BYTE = 8
BUS_OVERHEAD = 1.25  # addressing, status/count reads, gaps between transfers


def bus_bits_per_second(odr_hz: float, hires: bool, i2c: bool) -> float:
    """Bus bandwidth the FIFO stream needs at this rate, with transfer overhead."""
    per_byte = I2C_BITS_PER_BYTE if i2c else SPI_BITS_PER_BYTE
    return odr_hz * (PACKET_HIRES if hires else PACKET) * per_byte * BUS_OVERHEAD


def _one_of(v: float, allowed: tuple[float, ...], what: str) -> float:
    if float(v) not in allowed:
        listed = ", ".join(f"{a:g}" for a in sorted(allowed))
        raise ValueError(f"the ICM-42688-P has no {what} {v:g}; allowed: {listed}")
    return float(v)


def _aaf(v: int | str, default: int) -> int | str:
    if v == "off" or v in AAF_TABLE:
        return v
    near = min(AAF_TABLE, key=lambda b: abs(b - float(v)))
    raise ValueError(
        f"no anti-alias filter row for {v!r} Hz: pick one of the datasheet's 63 bandwidths "
        f'(42 ... 3979 Hz; nearest {near}), or "off"; the chip\'s default is {default}'
    )


class Icm42688pConfig(DeviceBase):
    """An ICM-42688-P. Gyro and accel run in low-noise mode at the same `odr_hz`."""

    chip: Literal["icm42688p"]
    gyro_range_dps: float = Field(2000, description="15.625, 31.25, 62.5, 125 ... 2000")
    accel_range_g: Literal[2, 4, 8, 16] = 16
    hires: bool = Field(False, description="20-bit FIFO packets; needs 2000 deg/s and 16 g")
    ui_filter: UiFilter = Field("odr/4", description="gyro and accel UI filter bandwidth")
    gyro_aaf_hz: int | Literal["off"] = Field(AAF_DEFAULT_GYRO_HZ, description="anti-alias 3 dB")
    accel_aaf_hz: int | Literal["off"] = Field(AAF_DEFAULT_ACCEL_HZ, description="anti-alias")
    odr_hz: float = Field(
        1000,
        validate_default=True,  # the bus checks below must run for the default rate too
        description="12.5, 25, 50, 100, 200, 500, 1000 ... 32000",
    )

    @field_validator("gyro_range_dps")
    @classmethod
    def _gyro_range(cls, v: float) -> float:
        return _one_of(v, GYRO_RANGES_DPS, "gyro range (deg/s)")

    @field_validator("gyro_aaf_hz")
    @classmethod
    def _gyro_aaf(cls, v: int | str) -> int | str:
        return _aaf(v, AAF_DEFAULT_GYRO_HZ)

    @field_validator("accel_aaf_hz")
    @classmethod
    def _accel_aaf(cls, v: int | str) -> int | str:
        return _aaf(v, AAF_DEFAULT_ACCEL_HZ)

    @field_validator("odr_hz")
    @classmethod
    def _bus_can_carry(cls, v: float, info: ValidationInfo) -> float:
        v = _one_of(v, tuple(ODR_CODES), "output data rate (Hz)")
        bus = info.data.get("bus")
        hires = bool(info.data.get("hires"))
        i2c = isinstance(bus, I2cBus) or (isinstance(bus, SimBus) and bus.transport == "i2c")
        speed = bus.clock_hz if isinstance(bus, SimBus) else getattr(bus, "speed_hz", None)
        if speed is not None and not i2c and speed > MAX_SPI_HZ:
            raise ValueError(
                f"the ICM-42688-P's SPI runs at most at 24 MHz; bus.speed_hz is {speed / 1e6:g} MHz"
            )
        need = bus_bits_per_second(v, hires, i2c)
        if speed is not None and need > speed:
            kind = "I2C" if i2c else "SPI"
            size = PACKET_HIRES if hires else PACKET
            best = max(
                (r for r in ODR_CODES if bus_bits_per_second(r, hires, i2c) <= speed), default=0
            )
            raise ValueError(
                f"{v:g} Hz needs about {need / 1e6:.2f} Mbit/s on {kind} ({size}-byte FIFO "
                f"packets, {'9' if i2c else '8'} bits a byte, 25 % transfer overhead) but the bus "
                f"runs at {speed / 1e6:g} MHz (bus.speed_hz): use "
                f"{'SPI or ' if i2c else 'a faster clock or '}at most {best:g} Hz"
            )
        return v

    @field_validator("hires")
    @classmethod
    def _hires_ranges(cls, v: bool, info: ValidationInfo) -> bool:
        g, a = info.data.get("gyro_range_dps"), info.data.get("accel_range_g")
        if v and (g != 2000 or a != 16):
            raise ValueError(
                "20-bit FIFO packets only work at gyro_range_dps = 2000 and accel_range_g = 16 "
                f"(configured: {g} and {a}); set hires = false or use those ranges"
            )
        return v


def gyro_scale_rads(range_dps: float, hires: bool) -> float:
    return math.radians(range_dps) / (2**19 if hires else 2**15)


def accel_scale_ms2(range_g: float, hires: bool) -> float:
    return range_g * STANDARD_GRAVITY / (2**19 if hires else 2**15)


@dataclass(slots=True)
class Packets:
    """Decoded FIFO packets (counts), in FIFO order, up to the first 'FIFO empty' header."""

    accel: npt.NDArray[np.int32]
    gyro: npt.NDArray[np.int32]
    temperature_c: npt.NDArray[np.float64]
    timestamp: npt.NDArray[np.int64]  # 16-bit FIFO timestamp field
    valid: npt.NDArray[np.bool_]  # both sensors present and not the -32768 / -524288 marker

    @property
    def n(self) -> int:
        return int(self.accel.shape[0])


# One FIFO packet as a NumPy record: decoding a batch is one zero-copy view, not a loop
PACKET3 = np.dtype([("hdr", "u1"), ("accel", ">i2", 3), ("gyro", ">i2", 3), ("temp", "i1"),
                    ("ts", ">u2")])  # fmt: skip
PACKET4 = np.dtype([("hdr", "u1"), ("accel", ">i2", 3), ("gyro", ">i2", 3), ("temp", ">i2"),
                    ("ts", ">u2"), ("ext", "u1", 3)])  # fmt: skip
assert PACKET3.itemsize == PACKET and PACKET4.itemsize == PACKET_HIRES


def decode_packets(data: bytes, hires: bool) -> Packets:
    """FIFO bytes (big-endian packets 3 or 4) to counts, up to the first 'FIFO empty' header."""
    dt = PACKET4 if hires else PACKET3
    rec = np.frombuffer(data, dtype=dt, count=len(data) // dt.itemsize)
    empty = np.flatnonzero(rec["hdr"] & HDR_EMPTY)
    if empty.size:
        rec = rec[: empty[0]]
    hdr = rec["hdr"]
    accel = rec["accel"].astype(np.int32)
    gyro = rec["gyro"].astype(np.int32)
    if hires:
        ext = rec["ext"].astype(np.int32)
        accel = (accel << 4) | (ext >> 4)
        gyro = (gyro << 4) | (ext & 0x0F)
        marker = -(2**19)
        temp = rec["temp"] / 132.48 + 25.0
        need = HDR_ACCEL | HDR_GYRO | HDR_20
    else:
        marker = -32768
        temp = rec["temp"] / 2.07 + 25.0
        need = HDR_ACCEL | HDR_GYRO
    valid = ((hdr & need) == need) & (accel != marker).any(axis=1) & (gyro != marker).any(axis=1)
    return Packets(accel, gyro, temp, rec["ts"].astype(np.int64), valid)


class Icm42688pDriver:
    """Stop-on-full FIFO driver. Blocking; owned by its bus's worker thread."""

    def __init__(self, cfg: Icm42688pConfig, dev: RegisterDevice, clock: Clock) -> None:
        self.cfg = cfg
        self.dev = dev
        self.clock = clock
        self.counters = DriverCounters()
        self.packet = PACKET_HIRES if cfg.hires else PACKET
        self.fifo_capacity = FIFO_SIZE // self.packet
        self.nominal_period_ns = 1e9 / cfg.odr_hz
        # A quarter of the FIFO between polls: 1 ms at 32 kHz, where the FIFO lasts 4 ms.
        # Halving it measured no better: twice the polls cost twice the interpreter time.
        self.poll_interval_ns = int(min(50e6, self.nominal_period_ns * self.fifo_capacity / 4))
        self.accel_scale = accel_scale_ms2(cfg.accel_range_g, cfg.hires)
        self.gyro_scale = gyro_scale_rads(cfg.gyro_range_dps, cfg.hires)
        self.invalid_packets = 0
        self._plan = self._register_plan()
        self._checker = RegisterChecker(dev, self._plan, clock, self.counters)
        self._resync = False
        self._restart_ns: tuple[int, int] | None = None

    def _register_plan(self) -> list[tuple[int, int]]:
        """Bank-0 registers and their values: written at start, then re-checked one by one."""
        c = self.cfg
        odr = ODR_CODES[float(c.odr_hz)]
        ui = UI_FILTERS[c.ui_filter]
        fifo1 = FIFO_ACCEL_EN | FIFO_GYRO_EN | FIFO_TEMP_EN | (FIFO_HIRES_EN if c.hires else 0)
        return [
            (INTF_CONFIG0, INTF_COUNT_BE_DATA_BE),
            (INTF_CONFIG1, INTF_CONFIG1_NO_AUTORANGE),
            (FIFO_CONFIG, FIFO_MODE_STOP_ON_FULL),
            (FIFO_CONFIG1, fifo1),
            (TMST_CONFIG, TMST_EN),
            (GYRO_CONFIG0, GYRO_RANGES_DPS.index(float(c.gyro_range_dps)) << 5 | odr),
            (ACCEL_CONFIG0, ACCEL_RANGES_G.index(c.accel_range_g) << 5 | odr),
            (GYRO_ACCEL_CONFIG0, ui << 4 | ui),
            (PWR_MGMT0, PWR_LOW_NOISE),
        ]

    def _aaf_writes(self) -> list[tuple[int, int, int]]:
        """(bank, register, value) for both anti-alias filters (bank 1 gyro, bank 2 accel)."""
        out: list[tuple[int, int, int]] = []
        g, a = self.cfg.gyro_aaf_hz, self.cfg.accel_aaf_hz
        if g == "off":
            out.append((1, GYRO_CONFIG_STATIC2, GYRO_AAF_DIS))
        else:
            d, sq, sh = AAF_TABLE[int(g)]
            out += [(1, GYRO_CONFIG_STATIC2, 0), (1, GYRO_CONFIG_STATIC3, d),
                    (1, GYRO_CONFIG_STATIC4, sq & 0xFF),
                    (1, GYRO_CONFIG_STATIC5, sh << 4 | sq >> 8)]  # fmt: skip
        if a == "off":
            out.append((2, ACCEL_CONFIG_STATIC2, ACCEL_AAF_DIS))
        else:
            d, sq, sh = AAF_TABLE[int(a)]
            out += [(2, ACCEL_CONFIG_STATIC2, d << 1), (2, ACCEL_CONFIG_STATIC3, sq & 0xFF),
                    (2, ACCEL_CONFIG_STATIC4, sh << 4 | sq >> 8)]  # fmt: skip
        return out

    def start(self) -> Iterator[int]:
        self.dev.write_u8(REG_BANK_SEL, 0)  # a stale bank would make WHO_AM_I read wrong
        who = self.dev.read_u8(WHO_AM_I)
        if who != WHO_AM_I_VALUE:
            raise DeviceIdentityError(
                f"WHO_AM_I (0x{WHO_AM_I:02x}) reads 0x{who:02x}, expected 0x{WHO_AM_I_VALUE:02x} "
                f"for an ICM-42688-P: check the chip, the wiring and the chip select/address"
            )
        self.dev.write_u8(DEVICE_CONFIG, SOFT_RESET)
        yield RESET_WAIT_NS
        if not self.dev.read_u8(INT_STATUS) & INT_RESET_DONE:
            raise DeviceIdentityError("ICM-42688-P did not report RESET_DONE after soft reset")
        self.counters.resets += 1
        banked = [(0, reg, val) for reg, val in self._plan[:-1]] + self._aaf_writes()
        banked.append((0, *self._plan[-1]))  # power on last, once everything is set
        for bank, reg, val in banked:
            self.dev.write_u8(REG_BANK_SEL, bank)
            self.dev.write_u8(reg, val)
        yield POWER_ON_WAIT_NS  # no register write within 200 us of turning sensors on
        for bank, reg, val in banked:
            self.dev.write_u8(REG_BANK_SEL, bank)
            got = self.dev.read_u8(reg)
            if got != val:
                got = self.dev.read_u8(reg)  # once more: a garbled read is not a wrong write
            if got != val:
                raise DeviceIdentityError(
                    f"bank {bank} register 0x{reg:02x} reads 0x{got:02x} after writing 0x{val:02x}"
                )
        self.dev.write_u8(REG_BANK_SEL, 0)
        yield STARTUP_WAIT_NS  # gyro start-up; packets before it carry the invalid marker
        self._flush()
        self._resync = False
        self._checker.restart()

    def _flush(self) -> None:
        t0 = self.clock.now_ns()
        self.dev.write_u8(SIGNAL_PATH_RESET, FIFO_FLUSH)
        self._restart_ns = (t0, self.clock.now_ns())
        self._resync = True
        self.dev.read(INT_STATUS, 3)  # the first count after a flush reads 0: discard it
        self.counters.fifo_resets += 1

    def _batch(
        self, p: Packets | None, t_before: int, t_after: int, full: bool = False
    ) -> RawBatch:
        resync, self._resync = self._resync, False
        restart, self._restart_ns = (self._restart_ns if resync else None), None
        if p is None:
            z = np.zeros((0, 3), dtype=np.int32)
            return RawBatch(z, z, np.zeros(0), self.accel_scale, self.gyro_scale,
                            t_before, t_after, resync=resync, restart_ns=restart)  # fmt: skip
        return RawBatch(
            p.accel, p.gyro, p.temperature_c, self.accel_scale, self.gyro_scale,
            t_before, t_after, resync=resync, restart_ns=restart,
            valid=None if bool(p.valid.all()) else p.valid, fifo_full=full,
            chip_ticks=p.timestamp, ticks_modulo=1 << 16,
        )  # fmt: skip

    def read(self) -> RawBatch:
        t_before = self.clock.now_ns()
        head = self.dev.read(INT_STATUS, 3)
        t_after = self.clock.now_ns()
        if head == b"\xff\xff\xff":  # the chip never sends this: a floating MISO line
            raise BusError(0, "status and FIFO count read all ones: no answer on MISO")
        status, count = head[0], int.from_bytes(head[1:3], "big")
        full = bool(status & INT_FIFO_FULL) or count >= FIFO_SIZE - self.packet + 1
        n = min(count, FIFO_SIZE) // self.packet
        self._checker.check_next()
        if n == 0:
            return self._batch(None, t_before, t_after)
        r0 = self.clock.now_ns()
        data = self.dev.read(FIFO_DATA, n * self.packet)
        r1 = self.clock.now_ns()
        p = decode_packets(data, self.cfg.hires)
        self.invalid_packets += int((~p.valid).sum())
        if p.n < n:
            # fewer packets than counted: a garbled burst (SPI reads 0xFF when MISO floats) or a
            # FIFO out of step. Keep what decoded, flush, and resync on the next read.
            self.counters.bad_transfers += 1
            batch = self._batch(p, t_before, t_after)
            self._flush()
            return batch
        batch = self._batch(p, t_before, t_after, full=full)
        if full:
            # stop-on-full: what we read is whole and valid, but the chip dropped the samples
            # that came while it was full; space frees as we read, so the stream resumes then
            self.counters.fifo_overflows += 1
            self._resync, self._restart_ns = True, (r0, r1)
        return batch

    def stop(self) -> None:
        with contextlib.suppress(BusError):
            self.dev.write_u8(PWR_MGMT0, 0)
