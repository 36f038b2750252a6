"""Closed-form Kalman steps for a 6-state error filter, on Python floats.

The covariance is packed as its upper triangle, 21 floats row by row
(``p00 p01 p02 p03 p04 p05 p11 p12 ... p55``), in a tuple.  For a 6x6 matrix a numpy call costs
about a microsecond whatever it computes, and filterpy's generic ``KalmanFilter.update_sequential``
adds reshapes, an inverse and copies per call; the arithmetic of one scalar-measurement update is
about 60 multiply-adds, which CPython does in about a microsecond on local variables.  So the
per-sample path is written out here, one textbook step per function; ``tests/compass/filter/test_filter.py``
checks each against filterpy.
"""

from __future__ import annotations

from operator import itemgetter

import numpy as np

__all__ = ["pack", "unpack", "predict_gyro", "update_axis", "update_heading", "update_tilt"]

_UPPER = [(i, j) for i in range(6) for j in range(i, 6)]
_INDEX = {ij: k for k, ij in enumerate(_UPPER)} | {(j, i): k for k, (i, j) in enumerate(_UPPER)}
_COLUMN = [itemgetter(*(_INDEX[i, j] for j in range(6))) for i in range(6)]  # column i of P from the packed form


def pack(matrix) -> tuple:
    """The packed upper triangle (21 floats) of a symmetric 6x6 matrix (its mean with its transpose)."""
    m = np.asarray(matrix, dtype=float)
    m = (m + m.T) / 2.0
    return tuple(float(m[i, j]) for i, j in _UPPER)


def unpack(p: tuple) -> np.ndarray:
    """The symmetric 6x6 matrix of a packed upper triangle."""
    m = np.empty((6, 6))
    for k, (i, j) in enumerate(_UPPER):
        m[i, j] = m[j, i] = p[k]
    return m



class PackedCovariance:
    """Mixin of the filters' state records: ``covariance`` packed (upper triangle, row by row), read
    back as the symmetric array by :attr:`covariance_matrix`."""

    __slots__ = ()

    @property
    def covariance_matrix(self) -> np.ndarray:
        """The covariance as a symmetric 6x6 array."""
        return unpack(self.covariance)

def predict_gyro(p: tuple, r: tuple, dt: float, q_att: float, q_bias: float) -> tuple:
    """``F P F^T + Q`` with ``F = [[I, A], [0, I]]``, ``A = -R dt``, ``Q = diag(q_att I, q_bias I)``.

    Parameters
    ----------
    p : tuple of 21 floats
        Packed covariance of ``(eps, db)``.
    r : tuple of 9 floats
        ``R`` row-major (the gyro filter's nominal attitude: a bias error ``db`` turns the attitude by
        ``-R db dt``).
    dt : float
        Time step, s.
    q_att, q_bias : float
        Process noise variance of each attitude and each bias component.

    Returns
    -------
    tuple of 21 floats

    Notes
    -----
    With ``M = P_ab + A P_bb``: ``P_aa <- P_aa + A P_ba + M A^T``, ``P_ab <- M``, ``P_bb`` unchanged.
    """
    (p00, p01, p02, p03, p04, p05, p11, p12, p13, p14, p15, p22, p23, p24, p25,
     p33, p34, p35, p44, p45, p55) = p
    r0, r1, r2, r3, r4, r5, r6, r7, r8 = r
    n = -dt
    a0, a1, a2, a3, a4, a5, a6, a7, a8 = r0 * n, r1 * n, r2 * n, r3 * n, r4 * n, r5 * n, r6 * n, r7 * n, r8 * n
    # M = P_ab + A P_bb
    m00 = p03 + a0 * p33 + a1 * p34 + a2 * p35
    m01 = p04 + a0 * p34 + a1 * p44 + a2 * p45
    m02 = p05 + a0 * p35 + a1 * p45 + a2 * p55
    m10 = p13 + a3 * p33 + a4 * p34 + a5 * p35
    m11 = p14 + a3 * p34 + a4 * p44 + a5 * p45
    m12 = p15 + a3 * p35 + a4 * p45 + a5 * p55
    m20 = p23 + a6 * p33 + a7 * p34 + a8 * p35
    m21 = p24 + a6 * p34 + a7 * p44 + a8 * p45
    m22 = p25 + a6 * p35 + a7 * p45 + a8 * p55
    # (A P_ba)_ij = A_i . (P_ab row j); (M A^T)_ij = M_i . A_j
    return (
        p00 + a0 * p03 + a1 * p04 + a2 * p05 + m00 * a0 + m01 * a1 + m02 * a2 + q_att,
        p01 + a0 * p13 + a1 * p14 + a2 * p15 + m00 * a3 + m01 * a4 + m02 * a5,
        p02 + a0 * p23 + a1 * p24 + a2 * p25 + m00 * a6 + m01 * a7 + m02 * a8,
        m00, m01, m02,
        p11 + a3 * p13 + a4 * p14 + a5 * p15 + m10 * a3 + m11 * a4 + m12 * a5 + q_att,
        p12 + a3 * p23 + a4 * p24 + a5 * p25 + m10 * a6 + m11 * a7 + m12 * a8,
        m10, m11, m12,
        p22 + a6 * p23 + a7 * p24 + a8 * p25 + m20 * a6 + m21 * a7 + m22 * a8 + q_att,
        m20, m21, m22,
        p33 + q_bias, p34, p35, p44 + q_bias, p45, p55 + q_bias)


def update_axis(p: tuple, x: list, i: int, z: float, var: float, hold_bias: bool = False) -> tuple:
    """Scalar measurement ``z = x_true[i] + n`` with ``var n = var`` (a direct measurement of component ``i``).

    ``x`` (the error state accumulated so far this sample; the innovation is ``z - x[i]``) is
    updated in place; the updated packed covariance is returned.  ``hold_bias`` (``i`` < 3): the bias
    states (3-5) are *considered*, as in :func:`update_tilt`.
    """
    c = _COLUMN[i](p)
    return _downdate(p, x, c, c[i] + var, z - x[i], hold_bias)


def update_heading(p: tuple, x: list, z: float, var: float, up_h: tuple | None = None,
                   tilt: tuple = (0.0, 0.0), hold_bias: bool = False) -> tuple:
    """The gyro filter's heading measurement ``z = tilt . x_true[:2] + x_true[2] + n`` (``var n = var``),
    decoupled from the tilt.

    A Schmidt (consider) update in the world frame: the estimated states are the heading error
    ``eps_z`` and, with ``up_h``, the gyro-bias error along the world vertical, ``u . db`` with
    ``u = R^T z`` (``up_h``, the world's up in H, unit); the tilt ``(eps_x, eps_y)`` and the bias's two
    horizontal components are *considered*: their gains are zero, so the field never moves them,
    while their uncertainty and correlations still count.  Without ``up_h`` the whole bias is
    estimated (only the tilt considered).  ``tilt``: what a tilt error adds to the measured heading
    (the field's azimuth moves by ``tan(dip)`` times the tilt about its horizontal direction); with
    it the update records how the heading it teaches shares the tilt's error, so that a later tilt
    correction carries the heading along.

    The gain ``K`` (``K_2 = c_2 / s``; ``K_b = u (u . c_b) / s`` with ``c = P h``, ``s = h . c + var``)
    is not the full Kalman gain, so the covariance is the Joseph form's for that gain,
    ``(I - K h) P (I - K h)^T + K var K^T = P - K c^T - c K^T + s K K^T``: symmetric and positive
    definite whatever ``K``; the considered block is unchanged.

    ``hold_bias``: no bias component is estimated (all three considered).

    ``x`` (the error state accumulated so far this sample; the innovation is ``z - h . x``) is
    updated in place; the updated packed covariance is returned.
    """
    t0, t1 = tilt
    c = tuple(a + t0 * b + t1 * d for a, b, d in zip(_COLUMN[2](p), _COLUMN[0](p), _COLUMN[1](p)))
    s = c[2] + t0 * c[0] + t1 * c[1] + var
    inv = 1.0 / s
    nu = z - x[2] - t0 * x[0] - t1 * x[1]
    if hold_bias:
        k = (0.0, 0.0, c[2] * inv, 0.0, 0.0, 0.0)
    elif up_h is None:
        k = (0.0, 0.0, c[2] * inv, c[3] * inv, c[4] * inv, c[5] * inv)
    else:
        u0, u1, u2 = up_h
        kb = (c[3] * u0 + c[4] * u1 + c[5] * u2) * inv
        k = (0.0, 0.0, c[2] * inv, kb * u0, kb * u1, kb * u2)
    for i in range(2, 6):
        x[i] += k[i] * nu
    return tuple(p[n] - k[i] * c[j] - c[i] * k[j] + s * k[i] * k[j] for n, (i, j) in enumerate(_UPPER))


def update_tilt(p: tuple, x: list, w: tuple, z0: float, v: tuple, z1: float, var: float, hold_bias: bool = False) -> tuple:
    """The gyro filter's two tilt rows, one after the other: scalar measurements ``z = h . x_true + n``
    with ``h = (0, -1, 0, w)`` and ``z0``, then ``h = (1, 0, 0, v)`` and ``z1``, both with ``var n = var``.

    ``x`` (the error state accumulated so far this sample) is updated in place; the updated packed
    covariance is returned.  Written out with the covariance in local variables (unpacked and packed
    once), without the products with 0 and 1; the downdate is written twice on purpose (a helper
    would pack and unpack the 21 floats between the rows, a third of the cost).

    ``hold_bias``: the bias states (3-5) are *considered*, not estimated (Schmidt-Kalman): their
    gains are zero, so neither they nor their variances change, while their uncertainty still widens
    the tilt states' (``P - K_a (H P)`` with ``K_b = 0``).
    """
    (p00, p01, p02, p03, p04, p05, p11, p12, p13, p14, p15, p22, p23, p24, p25,
     p33, p34, p35, p44, p45, p55) = p
    x0, x1, x2, x3, x4, x5 = x
    # h = (0, -1, 0, w)
    h3, h4, h5 = w
    c0 = -p01 + p03 * h3 + p04 * h4 + p05 * h5
    c1 = -p11 + p13 * h3 + p14 * h4 + p15 * h5
    c2 = -p12 + p23 * h3 + p24 * h4 + p25 * h5
    c3 = -p13 + p33 * h3 + p34 * h4 + p35 * h5
    c4 = -p14 + p34 * h3 + p44 * h4 + p45 * h5
    c5 = -p15 + p35 * h3 + p45 * h4 + p55 * h5
    s = -c1 + c3 * h3 + c4 * h4 + c5 * h5 + var
    nu = z0 - (-x1 + x3 * h3 + x4 * h4 + x5 * h5)
    inv = 1.0 / s
    k0, k1, k2, k3, k4, k5 = c0 * inv, c1 * inv, c2 * inv, c3 * inv, c4 * inv, c5 * inv
    if hold_bias:
        k3 = k4 = k5 = 0.0
    x0 += k0 * nu
    x1 += k1 * nu
    x2 += k2 * nu
    x3 += k3 * nu
    x4 += k4 * nu
    x5 += k5 * nu
    p00 -= k0 * c0; p01 -= k0 * c1; p02 -= k0 * c2; p03 -= k0 * c3; p04 -= k0 * c4; p05 -= k0 * c5
    p11 -= k1 * c1; p12 -= k1 * c2; p13 -= k1 * c3; p14 -= k1 * c4; p15 -= k1 * c5
    p22 -= k2 * c2; p23 -= k2 * c3; p24 -= k2 * c4; p25 -= k2 * c5
    p33 -= k3 * c3; p34 -= k3 * c4; p35 -= k3 * c5
    p44 -= k4 * c4; p45 -= k4 * c5
    p55 -= k5 * c5
    # h = (1, 0, 0, v)
    h3, h4, h5 = v
    c0 = p00 + p03 * h3 + p04 * h4 + p05 * h5
    c1 = p01 + p13 * h3 + p14 * h4 + p15 * h5
    c2 = p02 + p23 * h3 + p24 * h4 + p25 * h5
    c3 = p03 + p33 * h3 + p34 * h4 + p35 * h5
    c4 = p04 + p34 * h3 + p44 * h4 + p45 * h5
    c5 = p05 + p35 * h3 + p45 * h4 + p55 * h5
    s = c0 + c3 * h3 + c4 * h4 + c5 * h5 + var
    nu = z1 - (x0 + x3 * h3 + x4 * h4 + x5 * h5)
    inv = 1.0 / s
    k0, k1, k2, k3, k4, k5 = c0 * inv, c1 * inv, c2 * inv, c3 * inv, c4 * inv, c5 * inv
    if hold_bias:
        k3 = k4 = k5 = 0.0
    x0 += k0 * nu
    x1 += k1 * nu
    x2 += k2 * nu
    x3 += k3 * nu
    x4 += k4 * nu
    x5 += k5 * nu
    p00 -= k0 * c0; p01 -= k0 * c1; p02 -= k0 * c2; p03 -= k0 * c3; p04 -= k0 * c4; p05 -= k0 * c5
    p11 -= k1 * c1; p12 -= k1 * c2; p13 -= k1 * c3; p14 -= k1 * c4; p15 -= k1 * c5
    p22 -= k2 * c2; p23 -= k2 * c3; p24 -= k2 * c4; p25 -= k2 * c5
    p33 -= k3 * c3; p34 -= k3 * c4; p35 -= k3 * c5
    p44 -= k4 * c4; p45 -= k4 * c5
    p55 -= k5 * c5
    x[:] = (x0, x1, x2, x3, x4, x5)
    return (p00, p01, p02, p03, p04, p05, p11, p12, p13, p14, p15, p22, p23, p24, p25, p33, p34, p35, p44, p45, p55)


def _downdate(p: tuple, x: list, c: tuple, s: float, nu: float, hold_bias: bool = False) -> tuple:
    """``K = c / s`` (``c = P h``; with ``hold_bias`` its bias part zero, a Schmidt update); ``x += K nu``;
    returns ``P - K c^T`` (its upper triangle: with ``K_b = 0`` the Joseph form's for that gain)."""
    (p00, p01, p02, p03, p04, p05, p11, p12, p13, p14, p15, p22, p23, p24, p25,
     p33, p34, p35, p44, p45, p55) = p
    c0, c1, c2, c3, c4, c5 = c
    inv = 1.0 / s
    k0, k1, k2, k3, k4, k5 = c0 * inv, c1 * inv, c2 * inv, c3 * inv, c4 * inv, c5 * inv
    if hold_bias:
        k3 = k4 = k5 = 0.0
    x[0] += k0 * nu
    x[1] += k1 * nu
    x[2] += k2 * nu
    x[3] += k3 * nu
    x[4] += k4 * nu
    x[5] += k5 * nu
    return (p00 - k0 * c0, p01 - k0 * c1, p02 - k0 * c2, p03 - k0 * c3, p04 - k0 * c4, p05 - k0 * c5,
            p11 - k1 * c1, p12 - k1 * c2, p13 - k1 * c3, p14 - k1 * c4, p15 - k1 * c5,
            p22 - k2 * c2, p23 - k2 * c3, p24 - k2 * c4, p25 - k2 * c5,
            p33 - k3 * c3, p34 - k3 * c4, p35 - k3 * c5,
            p44 - k4 * c4, p45 - k4 * c5,
            p55 - k5 * c5)
