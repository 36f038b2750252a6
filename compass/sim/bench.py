"""Forward model of seed 000's bench: what each channel outputs at a turntable angle and flip.

The same code predicts outputs for the simulator (with the truth) and for the estimators (with
trial parameters), so a change of convention cannot make them disagree silently.

Model, per sample i and channel c (SPEC section 1):

.. math::

    \\phi_i^{true} = \\phi_i + e(\\phi_i), \\qquad \\kappa_i^{true} = \\kappa_i + \\epsilon_{k(i)}

    B_{H,i} = R_x(\\kappa_i^{true})^T \\left( R_z(\\phi_i^{true})^T B_W + b_p \\right)

    x_{ic} = B_{H,i} \\cdot a_c, \\qquad
    v_{ic} = V_{0c}(t_i, T_i) + K_c(T_i) \\, (x_{ic} + c_{2c} x_{ic}^2 + c_{3c} x_{ic}^3 + c_{5c} x_{ic}^5)

with ``e`` the encoder error (Fourier series in the reading), ``E_k`` the small rotation by
which the cube in flip k sits off its nominal pose (faces not square; identity for flip 0, which
defines the housing frame),
``b_p`` a field fixed to the turntable (in its frame), ``V0`` drifting with time and temperature,
``K`` depending on temperature and ``c2``, ``c3``, ``c5`` a polynomial non-linearity.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from scipy.spatial.transform import Rotation

from ..frames import bench_rotation, field_in_bench

__all__ = ["BenchSamples", "BenchPhysics", "true_platform_deg", "housing_field", "bench_outputs", "channel_outputs"]


@dataclass(frozen=True)
class BenchSamples:
    """Where each sample was taken: the recording's independent variables.

    Attributes
    ----------
    platform_deg, flip_deg : ndarray, shape (n,)
        Recorded turntable reading and flip, degrees.
    flip_index : ndarray of int, shape (n,)
        0..3 for nominal flips 0, 90, 180, 270.
    t_s, temp_c : ndarray, shape (n,), or None
    """

    platform_deg: np.ndarray
    flip_deg: np.ndarray
    flip_index: np.ndarray
    t_s: np.ndarray | None = None
    temp_c: np.ndarray | None = None

    @classmethod
    def from_recording(cls, rec) -> "BenchSamples":
        return cls(rec.platform_deg, rec.flip_deg, rec.flip_index, rec.t_s, rec.temp_c)

    @cached_property
    def recorded_rotations(self) -> tuple[np.ndarray, np.ndarray]:
        """Matrices of ``Rz(phi) Rx(kappa)`` and ``Rx(kappa)`` at the recorded angles, (n, 3, 3) each.

        Cached: fits that leave the angles alone reuse them at every evaluation.
        """
        full = bench_rotation(self.platform_deg, self.flip_deg).as_matrix()
        flip = bench_rotation(np.zeros_like(self.platform_deg), self.flip_deg).as_matrix()
        return full, flip


@dataclass(frozen=True)
class BenchPhysics:
    """Physical parameters of a bench session (truth in the simulator, trial values in a fit).

    Attributes
    ----------
    directions : ndarray, shape (c, 3)
        Unit sensing directions in the housing frame H.
    offsets, gains : ndarray, shape (c,)
        Zero-field output V0 (output units) and gain K (output units per field unit).
    dip_deg, azimuth_deg : float
        Field dip (> 0 down) and azimuth delta from the turntable zero.
    field_norm : float
        |B| in field units (uT when known, else 1).
    quadratic, cubic, quintic : ndarray, shape (c,), optional
        Polynomial coefficients c2 (1 / field unit), c3 (1 / field unit^2) and c5
        (1 / field unit^4) of the response (``nonlinear_response``).
    encoder_fourier : ndarray, shape (m, 2), optional
        Encoder error ``e(phi) = sum_k A_k cos(k phi) + B_k sin(k phi)``, degrees, k = 1..m.
    turntable_zero_deg : ndarray, shape (4,), optional
        Each flip's turntable zero against the recorded angles, degrees: the true angle is
        ``platform_deg + turntable_zero_deg[flip]`` (the cube set down turned about the vertical).
    flip_rotvec_deg : ndarray, shape (4, 3), optional
        Rotation vector (degrees, bench axes at turntable angle 0) of each flip's pose error
        ``E_k``: a true pose ``Rz(phi) E_k Rx(kappa)``; its x component is an error of the flip
        angle itself.
    platform_field : ndarray, shape (3,), optional
        Field fixed to the turntable, in the turntable frame, field units.
    drift : ndarray, shape (c, p), optional
        Offset change as a polynomial in ``(t_s - drift_t0) / drift_scale_s`` with powers 1..p.
    drift_t0, drift_scale_s : float
    warmup : ndarray, shape (c,), optional
        Warm-up offset: ``warmup * exp(-(t_s - drift_t0) / warmup_tau_s)``, output units
        (a first-order thermal settling from the start of the session).
    warmup_tau_s : float
    gain_drift : ndarray, shape (c, p), optional
        Relative gain change as a polynomial in ``(t_s - gain_drift_t0) / gain_drift_scale_s`` with
        powers 1..p: the gains are ``K (1 + sum_k g_ck tau^k)`` (``gain_drift``).
    gain_drift_t0, gain_drift_scale_s : float
    temp_offset, temp_gain : ndarray, shape (c,), optional
        d V0 / d T (output units per degC) and relative gain change per degC, about ``temp_ref_c``.
    temp_ref_c : float
    """

    directions: np.ndarray
    offsets: np.ndarray
    gains: np.ndarray
    dip_deg: float
    azimuth_deg: float
    field_norm: float = 1.0
    quadratic: np.ndarray | None = None
    cubic: np.ndarray | None = None
    quintic: np.ndarray | None = None
    encoder_fourier: np.ndarray | None = None
    turntable_zero_deg: np.ndarray | None = None
    flip_rotvec_deg: np.ndarray | None = None
    platform_field: np.ndarray | None = None
    drift: np.ndarray | None = None
    drift_t0: float = 0.0
    drift_scale_s: float = 1.0
    warmup: np.ndarray | None = None
    warmup_tau_s: float = 1.0
    gain_drift: np.ndarray | None = None
    gain_drift_t0: float = 0.0
    gain_drift_scale_s: float = 1.0
    temp_offset: np.ndarray | None = None
    temp_gain: np.ndarray | None = None
    temp_ref_c: float = 20.0

    def with_(self, **changes) -> "BenchPhysics":
        return replace(self, **changes)


def true_platform_deg(physics: BenchPhysics, samples: BenchSamples) -> np.ndarray:
    """Turntable angle after the encoder error and each flip's zero, degrees, shape (n,)."""
    phi = samples.platform_deg
    zero = physics.turntable_zero_deg
    true = phi if zero is None else phi + np.asarray(zero)[samples.flip_index]
    if physics.encoder_fourier is None:
        return true
    k = np.arange(1, len(physics.encoder_fourier) + 1)
    arg = np.radians(phi)[:, None] * k[None, :]
    return true + np.cos(arg) @ physics.encoder_fourier[:, 0] + np.sin(arg) @ physics.encoder_fourier[:, 1]


def housing_field(physics: BenchPhysics, samples: BenchSamples) -> np.ndarray:
    """The field in the housing frame H at each sample, shape (n, 3), field units."""
    b_w = field_in_bench(physics.dip_deg, physics.azimuth_deg, physics.field_norm)
    if physics.encoder_fourier is None and physics.turntable_zero_deg is None and physics.flip_rotvec_deg is None:
        full, flip = samples.recorded_rotations
        b_h = np.einsum("nji,j->ni", full, b_w)
        if physics.platform_field is not None:
            b_h = b_h + np.einsum("nji,j->ni", flip, physics.platform_field)
        return b_h
    # B_H = Rx(kappa)^T E_k^T (Rz(phi)^T B_W + b_p): single-axis rotations applied in turn
    phi = true_platform_deg(physics, samples)
    in_turntable = Rotation.from_euler("z", phi[:, None], degrees=True).apply(b_w, inverse=True)
    if physics.platform_field is not None:
        in_turntable = in_turntable + physics.platform_field  # turns with the turntable
    flip = Rotation.from_euler("x", samples.flip_deg[:, None], degrees=True)
    if physics.flip_rotvec_deg is not None:
        flip = Rotation.from_rotvec(physics.flip_rotvec_deg, degrees=True)[samples.flip_index] * flip
    return flip.apply(in_turntable, inverse=True)


def bench_outputs(physics: BenchPhysics, samples: BenchSamples) -> np.ndarray:
    """Noise-free channel outputs, shape (n, c)."""
    return channel_outputs(physics, samples, housing_field(physics, samples) @ physics.directions.T)


def channel_outputs(physics: BenchPhysics, samples: BenchSamples, x: np.ndarray) -> np.ndarray:
    """Outputs for field components ``x`` along each channel's direction, shape (n, c).

    Applies the response (cubic), offset and gain drift and temperature; ``x`` in field units.
    """
    if physics.quadratic is not None or physics.cubic is not None or physics.quintic is not None:
        x2 = x * x  # products, not powers: np.power is several times slower on these small arrays
        bent = x
        if physics.quadratic is not None:
            bent = bent + physics.quadratic * x2
        if physics.cubic is not None or physics.quintic is not None:
            x3 = x2 * x
            if physics.cubic is not None:
                bent = bent + physics.cubic * x3
            if physics.quintic is not None:
                bent = bent + physics.quintic * (x3 * x2)
        x = bent
    gains = physics.gains
    offsets = physics.offsets
    if physics.drift is not None and samples.t_s is not None:
        tau = (samples.t_s - physics.drift_t0) / physics.drift_scale_s
        powers = tau[:, None] ** np.arange(1, physics.drift.shape[1] + 1)[None, :]
        offsets = offsets + powers @ physics.drift.T
    if physics.warmup is not None and samples.t_s is not None:
        with np.errstate(over="ignore"):  # a fit's trial time constant near zero or negative: inf, its residual refused
            settling = np.exp(-(samples.t_s - physics.drift_t0) / physics.warmup_tau_s)
        offsets = offsets + settling[:, None] * physics.warmup[None, :]
    if physics.gain_drift is not None and samples.t_s is not None:
        tau = (samples.t_s - physics.gain_drift_t0) / physics.gain_drift_scale_s
        powers = tau[:, None] ** np.arange(1, physics.gain_drift.shape[1] + 1)[None, :]
        gains = gains * (1.0 + powers @ physics.gain_drift.T)
    if samples.temp_c is not None and (physics.temp_offset is not None or physics.temp_gain is not None):
        dt = (samples.temp_c - physics.temp_ref_c)[:, None]
        if physics.temp_offset is not None:
            offsets = offsets + dt * physics.temp_offset[None, :]
        if physics.temp_gain is not None:
            gains = gains * (1.0 + dt * physics.temp_gain[None, :])
    return offsets + gains * x
