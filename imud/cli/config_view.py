"""`imud check-config`'s summary: what a config asks for, for a human."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from imud.config import ImudConfig


def config_summary(cfg: ImudConfig, path: str) -> list[str]:
    """What a config asks for, for a human: one line per device, one for the daemon, one for
    Zenoh. Addresses in hex, as datasheets and i2cdetect write them."""
    from imud.buses.models import describe

    n = len(cfg.device)
    d, z = cfg.daemon, cfg.session_settings()
    rt = f"realtime priority {d.realtime_priority}" if d.realtime_priority else "no realtime"
    lines = [
        f"{path}: valid, {n} device{'s' if n != 1 else ''}",
        f"daemon: {'one process per bus' if d.bus_processes else 'bus threads'}, {rt}",
        f"zenoh: {z.mode}, listen {', '.join(z.listen) or 'nowhere'}, "
        f"connect {', '.join(z.connect) or 'none'}, prefix {z.prefix!r}, "
        f"shared memory {'on' if z.shared_memory else 'off'}"
        + (
            ", options " + ", ".join(f"{k}={v!r}" for k, v in z.options.items())
            if z.options
            else ""
        ),
    ]
    lines.append(_ros2_line(cfg))
    rows = []
    for dev in cfg.device:
        ranges = []
        fields = dev.model_dump()  # the range fields have the same names for every chip
        gyro, accel = fields.get("gyro_range_dps"), fields.get("accel_range_g")
        if gyro is not None:
            ranges.append(f"gyro ±{gyro:g} °/s")
        if accel is not None:
            ranges.append(f"accel ±{accel:g} g")
        if dev.sim is not None:
            sim = f"sim ({dev.sim.motion.kind}{', truth on' if dev.sim.truth else ''})"
        else:
            sim = "hardware"
        extra = f", calibration {dev.calibration}" if dev.calibration else ""
        if dev.orientation.enabled:
            extra += ", orientation filter"
        rows.append(
            [
                dev.name,
                dev.chip,
                " + ".join(describe(b) for b in dev.die_buses()),
                f"{dev.odr_hz:g} Hz",
                ", ".join(ranges),
                sim + extra,
            ]
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    for r in rows:
        lines.append("  " + "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip())
    return lines


def _ros2_line(cfg: ImudConfig) -> str:
    r = cfg.ros2
    if not r.enabled:
        return "ros2: off"
    from imud.rosnames import join

    domain = str(r.domain_id) if r.domain_id is not None else "$ROS_DOMAIN_ID or 0"
    on = [d for d in cfg.device if d.ros2.enabled]
    where = ", ".join(join(r.namespace, d.ros2.namespace or d.name) + "/imu/..." for d in on)
    return (
        f"ros2: {' + '.join(r.profiles)} ({r.distro}), domain {domain}, node {r.node!r}, "
        f"at most {r.rate_hz:g} Hz, router {', '.join(r.connect)}; topics {where or 'none'}"
    )
