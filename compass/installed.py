"""The runtime half of an installed calibration: the bench sensor inside its product (SPEC section 2).

An installed calibration file (``"model": "installed"``) holds the bench calibration whole under
``"base"`` and the product's iron under ``"installation"``: in the housing frame H the bench model
measures ``B_seen = S B_H + h`` (``soft_iron`` S, ``hard_iron_ut`` h).  Channel ``c`` of the bench
(direction ``a``, response ``f``) reads ``v = f(a . B_seen) = f(k a' . B_H + a . h)`` with

.. math:: a' = S^T a / k, \\qquad k = |S^T a|,

so the installed sensor is again a set of single-axis channels: direction ``a'``, response
``f(k x' + a . h)`` (for a linear channel: offset ``V0 + K a . h``, gain ``K k``).  Everything that
reads a calibration then works unchanged.  The bench's uncertainty (direction covariance, offset
and gain sigmas) is carried through this map, and the installation's own (covariance of ``h`` and
of the six soft-iron entries) is added: ``da' = (I - a' a'^T) dS a / k``, ``dk = a' . dS a``,
``dV0 = K a . dh`` (cross-correlations between bench and installation are neglected: they come
from independent recordings).  A bench channel's joint covariance of its direction, offset and gain
(``SensorModel.joint_covariance``) goes through the same map, its correlations kept, with the
installation's terms added to its diagonal blocks: its marginals stay the installed sigmas.  A bench channel's
response curve's coefficients (an 8 x 8 joint covariance) are not carried: the installed curve is the bench's
shifted and scaled (``f(k x' + a . h)``), not a cubic in ``x'``, so its 5 x 5 block goes through the map.

With an ``alignment`` (``R_product<-housing``) the installed model is written in the product's
frame: directions ``A a'``; the module's accelerometer must be turned the same way
(:class:`compass.calibration.ImuCorrection`).  The file is read by :mod:`compass.calibration`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .model import SensorModel
from .response import LinearResponse, Response

__all__ = ["SOFT_IRON_ENTRIES", "installed_model", "soft_iron_basis"]

SOFT_IRON_ENTRIES = ("xx", "yy", "zz", "xy", "xz", "yz")
"""The six entries of the symmetric soft-iron deviation ``S - I``, in parameter order."""


def soft_iron_basis() -> np.ndarray:
    """``E`` (6, 3, 3): ``S - I = sum_k d_k E_k`` for the entries :data:`SOFT_IRON_ENTRIES`."""
    basis = np.zeros((6, 3, 3))
    for k, (i, j) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
        basis[k, i, j] = basis[k, j, i] = 1.0
    return basis


@dataclass(frozen=True)
class ShiftedResponse(Response):
    """A bench response read through the installation: ``v = base(scale x + shift)``.

    Only for nonlinear bench channels (a linear one becomes a :class:`LinearResponse`).  It has no
    record of its own in a file: the installed file keeps the bench calibration and the installation.
    """

    base: Response | None = None
    scale: float = 1.0
    shift: float = 0.0
    model = "installed"

    def output(self, x):
        return self.base.output(self.scale * np.asarray(x, dtype=float) + self.shift)

    def field_component(self, v):
        x, ok = self.base.field_component(v)
        return (x - self.shift) / self.scale, ok

    def to_json(self) -> dict:
        raise ValueError("a nonlinear bench channel inside an installation has no response record of its own: "
                         "write the installed file (base + installation) instead")


def installed_model(base: SensorModel, hard_iron, soft_iron, covariance=None, alignment=None) -> SensorModel:
    """The bench model ``base`` inside its product (module docstring).

    Parameters
    ----------
    base : SensorModel
        The bench calibration's model (housing frame H).
    hard_iron : array_like, shape (3,)
        ``h`` in H, the base model's field units.
    soft_iron : array_like, shape (3, 3)
        ``S`` in H (symmetric).
    covariance : array_like, shape (9, 9), optional
        Covariance of ``(h_x, h_y, h_z, d_xx, d_yy, d_zz, d_xy, d_xz, d_yz)`` (field units^2, 1).
    alignment : array_like, shape (3, 3), optional
        ``R_product<-housing``: the model is then in the product's frame.

    Returns
    -------
    SensorModel
        Channel form, same channel names, noise and temperature effect.
    """
    h = np.asarray(hard_iron, dtype=float)
    s = np.asarray(soft_iron, dtype=float)
    a = base.unit_directions
    w = a @ s  # rows: S^T a (S symmetric or not: a . S B = (S^T a) . B)
    k = np.linalg.norm(w, axis=1)
    directions = w / k[:, None]
    shift = a @ h
    responses = []
    for c, r in enumerate(base.responses):
        lo, hi = r.x_range
        span = ((lo - shift[c]) / k[c], (hi - shift[c]) / k[c])
        if isinstance(r, LinearResponse):
            responses.append(LinearResponse(r.offset + r.gain * shift[c], r.gain * k[c], span))
        else:
            responses.append(ShiftedResponse(float(r.output(shift[c])), r.gain * k[c], span, base=r, scale=k[c],
                                             shift=shift[c]))
    project = np.eye(3)[None] - directions[:, :, None] * directions[:, None, :]  # (c, 3, 3)
    direction_cov = None
    if base.direction_covariance is not None:
        jac = project @ s.T[None] / k[:, None, None]
        direction_cov = jac @ base.direction_covariance @ jac.transpose(0, 2, 1)
    response_sigma = None if base.response_sigma is None else base.response_sigma * np.array([1.0, 1.0])
    if response_sigma is not None:
        response_sigma = np.column_stack([response_sigma[:, 0], response_sigma[:, 1] * k])
    if covariance is not None:
        cov = np.asarray(covariance, dtype=float)
        cov_h, cov_d = cov[:3, :3], cov[3:, 3:]
        e_a = np.einsum("kij,cj->cik", soft_iron_basis(), a)  # (c, 3, 6): dS a = E(a) dd
        spread = e_a @ cov_d @ e_a.transpose(0, 2, 1)  # covariance of dS a, (c, 3, 3)
        added = project @ spread @ project / k[:, None, None] ** 2
        direction_cov = added if direction_cov is None else direction_cov + added
        gains = base.gains
        offset_var = gains**2 * np.einsum("ci,ij,cj->c", a, cov_h, a)
        gain_var = gains**2 * np.einsum("ci,cij,cj->c", directions, spread, directions)
        old = np.zeros((len(a), 2)) if response_sigma is None else response_sigma
        response_sigma = np.sqrt(old**2 + np.column_stack([offset_var, gain_var]))
    joint = _installed_joint(base, project @ s.T[None] / k[:, None, None], k,
                             None if covariance is None else (added, offset_var, gain_var))
    gyro_matrix, accel = base.gyro_matrix, base.accel_correction
    if alignment is not None:
        rot = np.asarray(alignment, dtype=float)
        directions = directions @ rot.T
        if gyro_matrix is not None:  # the gyro read in the product's frame too
            gyro_matrix = rot @ gyro_matrix @ rot.T
        if accel is not None:  # the accelerometer read in the product's frame too: R A (a - b) = R A R^T (R a - R b)
            accel = (rot @ accel[0] @ rot.T, rot @ accel[1], accel[2])
        if direction_cov is not None:
            direction_cov = rot[None] @ direction_cov @ rot.T[None]
        if joint is not None:
            turn = np.eye(5)
            turn[:3, :3] = rot
            joint = tuple(None if j is None else turn @ j @ turn.T for j in joint)
    # a tumble base's own uncertainty is in its frame and for its iron alone: not carried (the installation's
    # covariance is); its magnetometer latency is the module's timing, its gyro matrix the module's gyro and its
    # accelerometer correction the module's accelerometer, kept;
    # a channel base's priors for null sigmas stay in its (transformed) numbers, their words were said when the
    # base was read
    return replace(base, directions=directions, responses=tuple(responses), direction_covariance=direction_cov,
                   response_sigma=response_sigma, form="installed", iron_uncertainty=None, gyro_matrix=gyro_matrix,
                   accel_correction=accel, sigma_priors=None, joint_covariance=joint)


def _installed_joint(base: SensorModel, direction_jac: np.ndarray, k: np.ndarray, added) -> tuple | None:
    """Each bench channel's joint covariance through the installation's map (module docstring): the direction
    by ``direction_jac`` (c, 3, 3), the offset as it is, the gain times ``k``; ``added`` (the installation's
    direction covariance (c, 3, 3), offset and gain variances (c,)) on the diagonal blocks, or None.  None when
    the base has none."""
    if base.joint_covariance is None:
        return None
    out = []
    for c, joint in enumerate(base.joint_covariance):
        if joint is None:
            out.append(None)
            continue
        m = np.zeros((5, 5))
        m[:3, :3], m[3, 3], m[4, 4] = direction_jac[c], 1.0, k[c]
        moved = m @ joint[:5, :5] @ m.T  # a curve's coefficients left behind (module docstring)
        if added is not None:
            moved[:3, :3] += added[0][c]
            moved[3, 3] += added[1][c]
            moved[4, 4] += added[2][c]
        out.append(moved)
    return tuple(out)
