"""Per-flip harmonic analysis of four-flip curves and seed 000's closed-form rules.

For a linear channel the output over one turn of flip k is a first harmonic in the turntable
angle, ``v = m_k + c_k cos(phi) + s_k sin(phi)``, whose minimum lies at
``phi_k0 = atan2(s_k, c_k) + 180 deg``.  Seed 000 turns the four minima into angles; we also
combine the four complex amplitudes as vectors, which has no singularity for channels near Y
or Z and gives the starting point of the joint maximum-likelihood fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from compass.frames import unit_from_seed_angles

__all__ = ["FlipHarmonics", "fit_harmonics", "orient", "sample_minima", "seed_direction", "seed_dip",
           "vector_harmonic"]


@dataclass(frozen=True)
class FlipHarmonics:
    """First-harmonic fit of every channel in every flip.

    Attributes
    ----------
    mean, cos, sin : ndarray, shape (4, c)
        ``m_k``, ``c_k``, ``s_k`` in output units.
    residual_rms : ndarray, shape (c,)
    mean_sigma : ndarray, shape (4, c)
        Standard error of each ``m_k`` from the residual rms, output units.
    """

    mean: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    residual_rms: np.ndarray
    mean_sigma: np.ndarray

    @property
    def amplitude(self) -> np.ndarray:
        return np.hypot(self.cos, self.sin)

    @property
    def minimum_deg(self) -> np.ndarray:
        """Turntable angle of each curve's minimum, degrees in [0, 360), shape (4, c)."""
        return np.mod(np.degrees(np.arctan2(self.sin, self.cos)) + 180.0, 360.0)


def fit_harmonics(platform_deg: np.ndarray, flip_index: np.ndarray, outputs: np.ndarray) -> FlipHarmonics:
    """Least-squares first-harmonic fit per flip and channel (all samples)."""
    n_channels = outputs.shape[1]
    mean, cos, sin = (np.empty((4, n_channels)) for _ in range(3))
    rss = np.zeros(n_channels)
    mean_variance_factor = np.empty(4)
    for k in range(4):
        mask = flip_index == k
        phi = np.radians(platform_deg[mask])
        design = np.column_stack([np.ones_like(phi), np.cos(phi), np.sin(phi)])
        coef, *_ = np.linalg.lstsq(design, outputs[mask], rcond=None)
        mean[k], cos[k], sin[k] = coef
        rss += np.sum((outputs[mask] - design @ coef) ** 2, axis=0)
        mean_variance_factor[k] = np.linalg.pinv(design.T @ design)[0, 0]
    rms = np.sqrt(rss / max(len(outputs) - 12, 1))
    return FlipHarmonics(mean, cos, sin, rms, np.sqrt(mean_variance_factor)[:, None] * rms[None, :])


def sample_minima(platform_deg: np.ndarray, flip_index: np.ndarray, outputs: np.ndarray) -> np.ndarray:
    """Seed 000's minima: the turntable reading of the lowest sample, shape (4, c), degrees."""
    minima = np.empty((4, outputs.shape[1]))
    for k in range(4):
        mask = np.flatnonzero(flip_index == k)
        minima[k] = np.mod(platform_deg[mask[np.argmin(outputs[mask], axis=0)]], 360.0)
    return minima


def _half_difference(a_deg, b_deg):
    """(a - b) / 2 with the difference wrapped to [-180, 180): the seed's theta and gamma."""
    return (np.mod(a_deg - b_deg + 180.0, 360.0) - 180.0) / 2.0


def seed_direction(minima_deg: np.ndarray) -> dict[str, np.ndarray]:
    """Seed 000's angles from the four minima (claims 3 and 4), degrees, per channel.

    ``theta = (phi_30 - phi_10)/2``, ``gamma = (phi_20 - phi_40)/2``,
    ``elevation = atan(tan(gamma) cos(theta))``, ``psi = atan(tan(theta) cos(gamma))``.
    The direction assumes, as the seed does, a positive X component (theta, gamma in [-90, 90]):
    the four minima are the same for ``a`` and ``-a``, so they cannot tell; :func:`orient` takes
    each channel's sign from the data.
    """
    theta = _half_difference(minima_deg[2], minima_deg[0])
    gamma = _half_difference(minima_deg[1], minima_deg[3])
    th, ga = np.radians(theta), np.radians(gamma)
    elevation = np.degrees(np.arctan(np.tan(ga) * np.cos(th)))
    psi = np.degrees(np.arctan(np.tan(th) * np.cos(ga)))
    return {
        "theta_deg": theta,
        "gamma_deg": gamma,
        "elevation_deg": elevation,
        "psi_deg": psi,
        "direction": unit_from_seed_angles(theta, elevation),
    }


def seed_dip(elevation_deg, crossing_minus_minimum_deg) -> np.ndarray:
    """Seed 000's dip from the first midpoint crossing after the flip-0 minimum (claim 5).

    ``dip = atan(-cos(elevation) cos(phi_11 - phi_10) / sin(elevation))``; singular for a
    horizontal channel (elevation 0), where every crossing is 90 deg from the minimum.
    """
    el, d = np.radians(elevation_deg), np.radians(crossing_minus_minimum_deg)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.degrees(np.arctan(-np.cos(el) * np.cos(d) / np.sin(el)))


@dataclass(frozen=True)
class VectorHarmonic:
    """Singularity-free closed-form estimate from all four flips' first harmonics.

    Attributes
    ----------
    directions : ndarray, shape (c, 3)
    offsets : ndarray, shape (c,)
        Zero-field outputs (mean of the four flip means).
    gains : ndarray, shape (c,)
        Output per field unit (|B| = ``field_norm``).
    dip_deg, azimuth_deg : float
    vertical_sigmas : float
        The vertical field the flip-mean differences show, in standard errors (the statistic
        ``tan(dip)`` is read from).  Below a few, the data hardly see the vertical field (dip near
        0, or every channel along X) and the hemisphere no longer fixes the sign common to all
        directions.
    """

    directions: np.ndarray
    offsets: np.ndarray
    gains: np.ndarray
    dip_deg: float
    azimuth_deg: float
    vertical_sigmas: float


def vector_harmonic(h: FlipHarmonics, field_norm: float, dip_sign: float = 1.0) -> VectorHarmonic:
    """Combine the four flips' harmonics into directions, dip and gains.

    With ``C_k = c_k - i s_k`` and ``H = K |B| cos(dip)``, a linear channel gives
    ``C_k = H e^{-i delta} w_k`` with ``w = (x+iy, x-iz, x-iy, x+iz)`` for flips 0, 90, 180, 270,
    and flip means ``m_k = V0 - S (z, y, -z, -y)_k`` with ``S = K |B| sin(dip)``.  So
    ``H x, H y, H z`` are real multiples of ``e^{-i delta}`` (delta from their common phase) and
    ``tan(dip) = S / H`` from the y and z pairs.  The data cannot tell ``(a, B)`` from
    ``(-a, -B)``; ``dip_sign`` picks the hemisphere (+1: field points down).
    """
    c = h.cos - 1j * h.sin  # (4, c)
    hx = (c[0] + c[1] + c[2] + c[3]) / 4
    hy = (c[0] - c[2]) / 2j
    hz = (c[3] - c[1]) / 2j
    stack = np.concatenate([hx, hy, hz])
    delta = -0.5 * np.angle(np.sum(stack**2))
    s_y = (h.mean[3] - h.mean[1]) / 2
    s_z = (h.mean[2] - h.mean[0]) / 2
    for candidate in (delta, delta + np.pi):
        rot = np.exp(1j * candidate)
        hxyz = np.stack([np.real(hx * rot), np.real(hy * rot), np.real(hz * rot)], axis=1)  # (c, 3)
        tan_dip = np.sum(s_y * hxyz[:, 1] + s_z * hxyz[:, 2]) / max(np.sum(hxyz[:, 1:] ** 2), 1e-300)
        if np.sign(tan_dip) == np.sign(dip_sign) or tan_dip == 0.0:
            break
    var_s_y = (h.mean_sigma[1] ** 2 + h.mean_sigma[3] ** 2) / 4
    var_s_z = (h.mean_sigma[0] ** 2 + h.mean_sigma[2] ** 2) / 4
    spread = np.sqrt(np.sum(hxyz[:, 1] ** 2 * var_s_y + hxyz[:, 2] ** 2 * var_s_z))
    vertical = abs(np.sum(s_y * hxyz[:, 1] + s_z * hxyz[:, 2])) / max(spread, 1e-300)
    dip = np.arctan(tan_dip)
    horizontal = np.linalg.norm(hxyz, axis=1)
    directions = hxyz / horizontal[:, None]
    gains = horizontal / (field_norm * np.cos(dip))
    return VectorHarmonic(
        directions=directions,
        offsets=h.mean.mean(axis=0),
        gains=gains,
        dip_deg=float(np.degrees(dip)),
        azimuth_deg=float(np.mod(np.degrees(candidate), 360.0)),
        vertical_sigmas=float(vertical),
    )


def orient(directions: np.ndarray, reference: VectorHarmonic) -> np.ndarray:
    """Each direction turned to the sign the data support: ``a`` or ``-a``, whichever points with
    the vector harmonic's estimate.

    Seed 000's minima are the same for ``a`` and ``-a``.  The vector combination of the four flips'
    harmonics is not: channels share one field azimuth, so each channel's first-harmonic phases fix
    its sign relative to the others (well conditioned for every channel: each is horizontal in
    some flip), and the flip-mean differences, which see the vertical field, fix the common sign
    given the hemisphere (``reference.vertical_sigmas`` says how well).

    Parameters
    ----------
    directions : ndarray, shape (c, 3)
        Unit sensing directions in H, of either sign.
    reference : VectorHarmonic
        From :func:`vector_harmonic` of the same recording and hemisphere.

    Returns
    -------
    ndarray, shape (c, 3)
    """
    sign = np.where(np.sum(directions * reference.directions, axis=1) < 0.0, -1.0, 1.0)
    return directions * sign[:, None]
