"""Local gravity: the WGS84 normal gravity formula against the values its definition fixes."""

from __future__ import annotations

import itertools
import math

import pytest

from imud.calib.gravity import normal_gravity

# WGS84 (NIMA TR8350.2 Table 3.3): normal gravity on the ellipsoid at the equator and the poles
EQUATOR = 9.7803253359
POLE = 9.8321849378
# the free-air gradient 2 gamma / a (1 + f + m - 2 f sin^2 phi) at 45 deg, m/s^2 per metre
FREE_AIR_45 = 3.086e-6


def test_equator_and_poles_are_the_defining_values() -> None:
    assert normal_gravity(0.0) == pytest.approx(EQUATOR, abs=1e-10)
    assert normal_gravity(90.0) == pytest.approx(POLE, abs=1e-9)
    assert normal_gravity(-90.0) == pytest.approx(POLE, abs=1e-9)


def test_gravity_grows_monotonically_toward_the_poles_and_is_symmetric() -> None:
    values = [normal_gravity(lat) for lat in range(0, 91, 5)]
    assert all(b > a for a, b in itertools.pairwise(values))
    for lat in (12.5, 45.0, 71.0):
        assert normal_gravity(lat) == normal_gravity(-lat)
    # the conventional 9.80665 m/s^2 lies at mid latitudes, not at the equator or the poles
    assert normal_gravity(40.0) < 9.80665 < normal_gravity(50.0)


def test_height_lowers_gravity_by_the_free_air_gradient() -> None:
    drop = (normal_gravity(45.0, 0.0) - normal_gravity(45.0, 1000.0)) / 1000.0
    assert drop == pytest.approx(FREE_AIR_45, rel=2e-3)
    # second order: the gradient weakens with height (the + 3 h^2 / a^2 term)
    high = (normal_gravity(45.0, 10000.0) - normal_gravity(45.0, 11000.0)) / 1000.0
    assert high < drop
    assert normal_gravity(45.0, -400.0) > normal_gravity(45.0)


@pytest.mark.parametrize(
    ("lat", "height", "words"),
    [
        (90.5, 0.0, "latitude"),
        (-91.0, 0.0, "latitude"),
        (math.nan, 0.0, "latitude"),
        (45.0, -1500.0, "height"),
        (45.0, 25000.0, "height"),
        (45.0, math.inf, "height"),
    ],
)
def test_out_of_range_inputs_are_refused(lat: float, height: float, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        normal_gravity(lat, height)
