"""Analytic derivatives of the four-flip model's outputs (:func:`compass.sim.bench.bench_outputs`).

The model (:mod:`compass.sim.bench`) per sample and channel ``c``:

.. math:: v_c = V_c(t) + K_c(t) f_c(x_c), \\qquad x_c = a_c \\cdot B_H, \\qquad
          B_H = R_x(\\kappa')^T \\big( R_z(\\varphi')^T B_W + b_p \\big),

``f_c(x) = x + c_2 x^2 + c_3 x^3 + c_5 x^5``, ``V_c(t)`` the offset with its drifts, ``K_c(t)`` the gain
with its drift and temperature, ``phi'`` the true turntable angle (encoder error), ``kappa'`` the true
flip (flip error), ``b_p`` a field fixed to the turntable.  Derivatives of the field in H:

- of the turntable angle: ``dB_H / dphi' = R_x(kappa')^T (-z x R_z(phi')^T B_W)`` (``d R_z(-phi) / dphi = -[z]x R_z(-phi)``);
- of the flip angle: ``dB_H / dkappa' = -x x B_H``;
- of a bench-frame vector ``B_W`` (dip, azimuth): ``R_x(kappa')^T R_z(phi')^T dB_W``.

Each effect maps its block onto these (:meth:`calibrate.fourflip.effects.Effect.jacobian`); the base
parameters are done here.  Every derivative is checked against finite differences in
``tests/calibrate/fourflip/test_jacobians.py``.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

from compass.frames import field_in_bench
from compass.iron_uncertainty import CURVE_FIELDS, CURVE_POWERS
from compass.sim.bench import BenchPhysics, BenchSamples, housing_field, true_platform_deg

from ..effects import time_powers

__all__ = ["Partials"]


class Partials:
    """What every derivative of the outputs at one ``physics`` needs, computed once.

    Parameters
    ----------
    physics : BenchPhysics
        Every effect applied.
    samples : BenchSamples
        Where the outputs are predicted.
    b_h : ndarray, shape (n, 3), optional
        The field in H at ``samples`` (computed when None).

    Attributes
    ----------
    b_h : ndarray, shape (n, 3)
    x : ndarray, shape (n, c)
        Field component along each direction, field units.
    bent, slope : ndarray, shape (n, c)
        The response ``f(x)`` and its derivative ``f'(x)``.
    gain_t : ndarray, shape (n, c)
        The gain at each sample (drift and temperature included).
    """

    def __init__(self, physics: BenchPhysics, samples: BenchSamples, b_h: np.ndarray | None = None):
        self.physics, self.samples = physics, samples
        self.b_h = housing_field(physics, samples) if b_h is None else b_h
        x = self.b_h @ physics.directions.T
        bent, slope = x.copy(), np.ones_like(x)
        for k, name in zip(CURVE_POWERS, CURVE_FIELDS):
            coef = getattr(physics, name)
            if coef is not None:
                bent += coef * x**k
                slope += k * coef * x ** (k - 1)
        self.x, self.bent, self.slope = x, bent, slope
        self.gain_drift_factor = np.ones_like(x)  # 1 + sum_k g_k tau^k
        if physics.gain_drift is not None and samples.t_s is not None:
            tau = (samples.t_s - physics.gain_drift_t0) / physics.gain_drift_scale_s
            self.gain_drift_factor = 1.0 + time_powers(tau, physics.gain_drift.shape[1]) @ physics.gain_drift.T
        self.temperature_factor = np.ones_like(x)  # 1 + gamma (T - T_ref)
        if samples.temp_c is not None and physics.temp_gain is not None:
            self.temperature_factor = 1.0 + (samples.temp_c - physics.temp_ref_c)[:, None] * physics.temp_gain[None, :]
        self.gain_t = physics.gains * self.gain_drift_factor * self.temperature_factor

    @property
    def per_x(self) -> np.ndarray:
        """d output / d x, shape (n, c)."""
        return self.gain_t * self.slope

    def per_channel(self, values: np.ndarray) -> np.ndarray:
        """A block of per-channel parameters (channel-major) from each one's derivative in its own channel.

        ``values`` (n, c, q): the derivative of channel c's output by its q-th parameter; returns
        (n, c, c q), zero off the channel.
        """
        n, c, q = values.shape
        out = np.zeros((n, c, c * q))
        for ch in range(c):
            out[:, ch, ch * q:(ch + 1) * q] = values[:, ch, :]
        return out

    def through_field(self, d_b_h: np.ndarray) -> np.ndarray:
        """d outputs from a change of the field in H ``d_b_h`` (n, 3, m): shape (n, c, m)."""
        return self.per_x[:, :, None] * np.einsum("njm,cj->ncm", d_b_h, self.physics.directions)

    @cached_property
    def _rotations(self) -> tuple[Rotation, Rotation]:
        """``R_z(phi')`` and the flip ``R_x(kappa')`` (pose error included) of each sample."""
        p = self.physics
        phi = Rotation.from_euler("z", true_platform_deg(p, self.samples)[:, None], degrees=True)
        flip = Rotation.from_euler("x", self.samples.flip_deg[:, None], degrees=True)
        if p.flip_rotvec_deg is not None:
            flip = Rotation.from_rotvec(p.flip_rotvec_deg, degrees=True)[self.samples.flip_index] * flip
        return phi, flip

    def turntable_to_housing(self, v_t: np.ndarray) -> np.ndarray:
        """Vectors in the turntable frame (3,) or (n, 3) taken into H, shape (n, 3)."""
        return self._rotations[1].apply(v_t, inverse=True)  # one vector applies to every rotation

    def bench_to_housing(self, v_w: np.ndarray) -> np.ndarray:
        """A constant bench-frame vector (3,) taken into H at each sample, shape (n, 3)."""
        return self.turntable_to_housing(self._rotations[0].apply(v_w, inverse=True))

    @property
    def per_turn(self) -> np.ndarray:
        """d output / d phi' (rad), shape (n, c)."""
        p = self.physics
        earth_t = self._rotations[0].apply(field_in_bench(p.dip_deg, p.azimuth_deg, p.field_norm), inverse=True)
        d_b_h = self.turntable_to_housing(-np.cross([0.0, 0.0, 1.0], earth_t))
        return self.through_field(d_b_h[:, :, None])[:, :, 0]

    @property
    def per_flip(self) -> np.ndarray:
        """d output / d kappa' (rad), shape (n, c)."""
        return self.through_field(-np.cross([1.0, 0.0, 0.0], self.b_h)[:, :, None])[:, :, 0]
