"""Local gravity from latitude and height: the WGS84 normal gravity formula.

Why it matters: an accelerometer calibrated against the magnitude of gravity puts any error in
that magnitude straight into its scale factors. Normal gravity runs from 9.7803 m/s^2 at the
equator to 9.8322 m/s^2 at the poles, and falls by about 3.1e-6 m/s^2 per metre of height, so the
conventional 9.80665 m/s^2 is up to 0.27 % off. The formula below (the ellipsoid's own field, no
local anomalies) is good to a few parts in 1e5 on land, far below that.

Source of every constant: NIMA TR8350.2, "Department of Defense World Geodetic System 1984",
3rd edition (2000): Table 3.1 (defining parameters), Table 3.3 (derived geometric and physical
constants), equation 4-1 (Somigliana's closed formula on the ellipsoid) and equation 4-3 (the
second-order free-air expansion above it).
"""

from __future__ import annotations

import math

# WGS84 defining parameters (TR8350.2 Table 3.1)
SEMI_MAJOR_AXIS_M = 6378137.0
FLATTENING = 1.0 / 298.257223563
# WGS84 derived constants (TR8350.2 Table 3.3)
GAMMA_EQUATOR = 9.7803253359  # normal gravity at the equator, m/s^2
GAMMA_POLE = 9.8321849378  # normal gravity at the poles, m/s^2
SOMIGLIANA_K = 0.00193185265241  # k = (b * gamma_p) / (a * gamma_e) - 1
ECCENTRICITY_SQ = 6.69437999014e-3  # first eccentricity squared, e^2
GRAVITY_RATIO_M = 0.00344978650684  # m = omega^2 a^2 b / GM

LATITUDE_LIMIT_DEG = 90.0
HEIGHT_RANGE_M = (-1000.0, 20000.0)  # Dead Sea shore to stratospheric balloons


def normal_gravity(latitude_deg: float, height_m: float = 0.0) -> float:
    """Normal gravity (m/s^2) at geodetic latitude `latitude_deg` and ellipsoidal height `height_m`.

    On the ellipsoid (TR8350.2 eq. 4-1):
    gamma = gamma_e (1 + k sin^2 phi) / sqrt(1 - e^2 sin^2 phi).
    Above it (eq. 4-3): gamma_h = gamma [1 - 2/a (1 + f + m - 2 f sin^2 phi) h + 3 h^2 / a^2],
    i.e. about -3.086e-6 m/s^2 per metre. Height is above the ellipsoid; height above sea level
    (what a map gives) differs from it by the geoid undulation, at most ~100 m, i.e. at most
    3e-4 m/s^2 (31 ppm) and usually a few ppm: fine for calibration.
    """
    lat = float(latitude_deg)
    h = float(height_m)
    if not math.isfinite(lat) or abs(lat) > LATITUDE_LIMIT_DEG:
        raise ValueError(
            f"latitude {latitude_deg!r} deg is outside -90..90: give the geodetic latitude in "
            "decimal degrees (north positive)"
        )
    lo, hi = HEIGHT_RANGE_M
    if not math.isfinite(h) or not lo <= h <= hi:
        raise ValueError(
            f"height {height_m!r} m is outside {lo:g}..{hi:g} m: give the height above sea level "
            "in metres (not feet, not kilometres)"
        )
    s2 = math.sin(math.radians(lat)) ** 2
    gamma = GAMMA_EQUATOR * (1.0 + SOMIGLIANA_K * s2) / math.sqrt(1.0 - ECCENTRICITY_SQ * s2)
    a = SEMI_MAJOR_AXIS_M
    free_air = (
        1.0
        - 2.0 / a * (1.0 + FLATTENING + GRAVITY_RATIO_M - 2.0 * FLATTENING * s2) * h
        + 3.0 * h * h / (a * a)
    )
    return gamma * free_air
