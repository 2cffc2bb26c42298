"""The gyro's g-sensitivity: a bias that follows the specific force, G a (3x3, rad/s per m/s^2;
imucal's K_ga, a MEMS data sheet's "linear acceleration effect", typically 0.01-0.1 deg/s/g).

Estimated from the still poses, where the gyro reads only its bias, G a and Earth's rotation:
each pose's gyro mean m_k against its (calibrated) specific force a_k,

    m_k = b + G a_k + noise,      weighted by the mean's own covariance (block averaging),

and kept only when the data ask for it: the fit with G against the fit with b alone, a
chi-squared difference on 9 degrees of freedom (a likelihood-ratio test) beyond `significance`,
the difference divided by the fit's own chi2/dof when that is above 1 (scatter between poses
the means' noise does not cover, a bias wandering between poses, must not read as G), and G
larger than Earth's rotation could make it. A sensor without it keeps b alone, so a right
model's bias keeps its Cramer-Rao bound.

Earth's rotation projects into the still poses: its vertical part, Omega sin(latitude) along
the measured up, looks exactly like a diagonal G (0.003 deg/s/g at 45 deg); its horizontal part
varies with the heading. With the latitude the vertical part is taken out of the means first;
without, a G below three times Earth's whole rate per g (0.013 deg/s/g) is not kept: on
simulated sessions without any G, Earth's rotation and the poses' noise fit one up to 1.5 times
that rate (tests/test_calib_gyro.py), and a MEMS part's is 0.01-0.1 deg/s/g or more. The intercept's
covariance (`bias_cov`) includes G's uncertainty: the bias is correlated with G, the more the
fewer directions the poses face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from imud.calib.stats import chi2_sf

F64 = npt.NDArray[np.float64]
MIN_POSES = 6  # 12 parameters from 3 equations a pose, with room to test them


@dataclass(frozen=True)
class GSensitivity:
    matrix: F64  # (3, 3) rad/s per m/s^2
    bias: F64  # (3,) the intercept, rad/s
    chi2_without: float
    chi2_with: float
    dof_with: int
    p_value: float  # of the improvement, chi2 on 9 dof, if there were no G
    included: bool
    bias_cov: F64  # (3, 3) the bias's covariance: the intercept's with G, else the mean's
    matrix_sigma: F64  # (3, 3) each element's 1-sigma, rad/s per m/s^2 (of the fit with G)


def _weighted_fit(design: F64, y: F64) -> tuple[F64, float]:
    p: F64 = np.asarray(np.linalg.lstsq(design, y, rcond=None)[0], dtype=np.float64)
    r = y - design @ p
    return p, float(r @ r)


EARTH_RATE_RAD_S = 7.292115e-5
EARTH_PER_G = EARTH_RATE_RAD_S / 9.80665  # rad/s per m/s^2: Earth's whole rate per g
EARTH_MARGIN = 3.0  # without the latitude, a G must exceed this many EARTH_PER_G to be kept


def fit_g_sensitivity(
    gyro_means: F64,
    gyro_covs: F64,
    specific_force: F64,
    significance: float = 0.01,
    latitude_deg: float | None = None,
) -> GSensitivity | None:
    """From N still poses: gyro means (N, 3) with their covariances (N, 3, 3) and the specific
    force in each (N, 3). `latitude_deg`: take Earth's vertical rate out of the means first.
    None with fewer than MIN_POSES poses or a singular design."""
    n = gyro_means.shape[0]
    if n < MIN_POSES:
        return None
    if latitude_deg is not None:
        up = specific_force / np.linalg.norm(specific_force, axis=1, keepdims=True)
        vertical = EARTH_RATE_RAD_S * np.sin(np.radians(latitude_deg))
        gyro_means = gyro_means - vertical * up
    try:
        whiten = np.array([np.linalg.cholesky(np.linalg.inv(c)).T for c in gyro_covs])
    except np.linalg.LinAlgError:
        return None
    x_b = np.tile(np.eye(3), (n, 1, 1))  # (n, 3, 3)
    x_g = np.zeros((n, 3, 9))
    for i in range(3):
        x_g[:, i, 3 * i : 3 * i + 3] = specific_force
    y = np.einsum("nij,nj->ni", whiten, gyro_means).ravel()
    d0 = np.einsum("nij,njk->nik", whiten, x_b).reshape(3 * n, 3)
    d1 = np.einsum("nij,njk->nik", whiten, np.concatenate([x_b, x_g], axis=2)).reshape(3 * n, 12)
    if np.linalg.matrix_rank(d1) < 12:
        return None  # the poses' specific forces do not span three directions
    p0, c0 = _weighted_fit(d0, y)
    p1, c1 = _weighted_fit(d1, y)
    dof1 = 3 * n - 12
    scatter = max(1.0, c1 / dof1) if dof1 > 0 else 1.0  # what the means' noise does not cover
    p_value = chi2_sf(max(c0 - c1, 0.0) / scatter, 9)
    g = p1[3:].reshape(3, 3)
    beyond_earth = float(np.abs(g).max()) > EARTH_MARGIN * EARTH_PER_G
    included = p_value < significance and (latitude_deg is not None or beyond_earth)
    cov1 = np.linalg.inv(d1.T @ d1) * scatter
    cov0 = np.linalg.inv(d0.T @ d0) * max(1.0, c0 / (3 * n - 3))
    return GSensitivity(
        matrix=g if included else np.zeros((3, 3)),
        bias=p1[:3] if included else p0,
        chi2_without=c0,
        chi2_with=c1,
        dof_with=dof1,
        p_value=p_value,
        included=included,
        bias_cov=cov1[:3, :3] if included else cov0,
        matrix_sigma=np.sqrt(np.clip(np.diag(cov1)[3:], 0.0, None)).reshape(3, 3),
    )
