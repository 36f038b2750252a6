"""The gyro filter's inertial low-passes with the motion each one leaves measured from the data (issue 22).

Model.  In the gyro-propagated inertial frame the specific force is ``f = g z + a`` (``a`` the motion
acceleration; the gyro's drift turns ``z`` slowly).  A low-pass ``H`` (DC gain 1) gives ``g z + H a``: its
direction is wrong by the horizontal part of ``H a`` over g, the *leak*.  ``a`` is not observed, but
``r = f - H f = (1 - H) a`` is, and ``H a = G r`` with ``G = H / (1 - H)``:

- first order, ``H1 = 1 / (1 + tau s)``: ``G1 = 1 / (tau s)``, the leak is ``(v - LP v) / tau``;
- Butterworth, ``H2 = 2 sigma^2 / (s^2 + 2 sigma s + 2 sigma^2)``, ``sigma = 1 / tau``:
  ``G2 = G1 / (1 + s tau / 2)``, ``2 / (w tau)^2`` at high frequency: the fourth-power roll-off in power.

``G`` has a pole at zero frequency: a constant leak is a tilt, indistinguishable from it, so no estimator
sees it.  The estimate used here is the low-pass applied once more to what it leaves,
``q = H r = H (1 - H) f``: no gravity (zero DC gain), and ``|H (1 - H)| -> |H|`` above the cut-off for both
orders (the leak itself), ``|1 - H|`` times it below (first order ``w tau / sqrt(1 + (w tau)^2)``, Butterworth
1 at ``w tau = 1``).  It replaces the single-frequency estimate ``|r| tau_v / (2 pi tau)`` (right only for
motion at the period ``tau_v``: session 10 measured it 1.2-4x off on BROAD).  The gyro's drift over the
low-pass's memory passes ``H (1 - H)`` too, and is counted as the error it is.

Both low-passes see the same motion, so their leaks are correlated: the blend ``w l1 + (1 - w) l2`` leaks
``w H1 a + (1 - w) H2 a``, whose variance ``w^2 V11 + (1 - w)^2 V22 + 2 w (1 - w) V12`` (``V`` the moving
averages of ``q1 . q1``, ``q2 . q2``, ``q1 . q2`` over ``motion_time_s``, plus each one's norm error) is least at
``w = (V22 - V12) / (V11 + V22 - 2 V12)`` (clipped to [0, 1]).  Per-sample arithmetic on Python floats.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["BandLeak", "butterworth_coefficients", "blend_weight"]


def butterworth_coefficients(dt: float, tau_s: float) -> tuple:
    """``(f00, f01, f10, f11)`` of ``y'' + 2 s y' + 2 s^2 y = 2 s^2 x`` (``s = 1 / tau_s``: a Butterworth whose DC
    group delay is ``tau_s``), discretised exactly with the input held over ``dt``:
    ``(y, y') <- Phi (y, y') + (I - Phi) (x, 0)``."""
    sig = 1.0 / tau_s
    decay, c, sn = math.exp(-sig * dt), math.cos(sig * dt), math.sin(sig * dt)
    return decay * (c + sn), decay * sn / sig, -2.0 * sig * decay * sn, decay * (c - sn)


def _butterworth(k: tuple, y: tuple, v: tuple, x: tuple) -> tuple:
    """One step of :func:`butterworth_coefficients`' filter on 3-vectors: the new ``(y, y')``."""
    f00, f01, f10, f11 = k
    g0 = 1.0 - f00
    d0, d1, d2 = x[0] - y[0], x[1] - y[1], x[2] - y[2]
    return ((y[0] + g0 * d0 + f01 * v[0], y[1] + g0 * d1 + f01 * v[1], y[2] + g0 * d2 + f01 * v[2]),
            (f11 * v[0] - f10 * d0, f11 * v[1] - f10 * d1, f11 * v[2] - f10 * d2))


def _turn(e: tuple, v: tuple) -> tuple:
    """``e^T v``: a vector fixed in the inertial frame, seen from the housing turned by ``e`` (row-major)."""
    return (e[0] * v[0] + e[3] * v[1] + e[6] * v[2], e[1] * v[0] + e[4] * v[1] + e[7] * v[2],
            e[2] * v[0] + e[5] * v[1] + e[8] * v[2])


def blend_weight(v11: float, v22: float, v12: float) -> float:
    """The first low-pass's weight in the least-variance blend of two correlated estimates (variances ``v11``,
    ``v22``, covariance ``v12``), clipped to [0, 1]; 1 when the two are indistinguishable."""
    den = v11 + v22 - 2.0 * v12
    if not den > 0.0:
        return 1.0
    return min(1.0, max(0.0, (v22 - v12) / den))


_ZERO = (0.0, 0.0, 0.0)


@dataclass(slots=True)
class BandLeak:
    """The inertial low-passes (first order, Butterworth, or both) and the leak each one leaves, in H.

    Attributes
    ----------
    first, second : bool
        Which low-passes run.
    lp1, q1 : tuple of 3 floats
        The first-order low-pass of the specific force and its leak estimate ``H1 (f - lp1)``, accelerometer units.
    lp2, lp2_rate, q2, q2_rate : tuple of 3 floats
        The Butterworth's output and rate (units per second), its leak estimate and that one's rate.
    age1 : float
        The first-order content's mean age, s.
    age_lp2 : tuple of 2 floats
        The Butterworth run on the time since the start (output, rate): its content's mean age ``age2`` (s) is
        that time less the output.
    v11, v22, v12 : float
        Moving averages over ``motion_time_s`` of ``n1^2 + |q1|^2 / g^2``, ``n2^2 + |q2|^2 / g^2`` and
        ``n1 n2 + q1 . q2 / g^2`` (``n = |lp| / g - 1``, the norm error), (fraction of g)^2.
    weight : float
        The first-order low-pass's weight in the latest direction.
    """

    first: bool
    second: bool
    lp1: tuple = _ZERO
    q1: tuple = _ZERO
    lp2: tuple = _ZERO
    lp2_rate: tuple = _ZERO
    q2: tuple = _ZERO
    q2_rate: tuple = _ZERO
    age1: float = 0.0
    age_lp2: tuple = (0.0, 0.0)
    age2: float = 0.0
    v11: float = 0.0
    v22: float = 0.0
    v12: float = 0.0
    weight: float = 1.0

    def restart(self, a: tuple, since_s: float) -> None:
        """New content: both low-passes at the reading ``a``, no leak, age 0 (``since_s``: time since the start)."""
        self.lp1 = self.lp2 = tuple(a[:3])
        self.q1 = self.lp2_rate = self.q2 = self.q2_rate = _ZERO
        self.age1, self.age2, self.age_lp2 = 0.0, 0.0, (since_s, 0.0)
        self.v11 = self.v22 = self.v12 = 0.0

    def turn(self, e: tuple) -> None:
        """The housing turned by ``e`` (row-major): every vector state is fixed in the inertial frame."""
        if self.first:
            self.lp1, self.q1 = _turn(e, self.lp1), _turn(e, self.q1)
        if self.second:
            self.lp2, self.lp2_rate = _turn(e, self.lp2), _turn(e, self.lp2_rate)
            self.q2, self.q2_rate = _turn(e, self.q2), _turn(e, self.q2_rate)

    def correct_bias(self, d: tuple) -> None:
        """The part of each low-pass's turn error a bias correction ``d`` (rad/s, H) explains: ``age (l x d)``."""
        d0, d1, d2 = d
        for name, age in (("lp1", self.age1 if self.first else None),
                          ("lp2", self.age2 if self.second else None)):
            if age is None:
                continue
            vx, vy, vz = getattr(self, name)
            setattr(self, name, (vx - age * (vy * d2 - vz * d1), vy - age * (vz * d0 - vx * d2),
                                 vz - age * (vx * d1 - vy * d0)))

    def step(self, dt: float, alpha: float, k2: tuple, beta: float, f: tuple, g: float, since_s: float) -> tuple:
        """One sample of ``dt`` s: ``alpha`` the first-order step's gain, ``k2`` the Butterworth's coefficients, ``beta`` the
        variance averages' gain, ``f`` the specific force (H), ``g`` gravity, ``since_s`` the time since the start.

        Returns
        -------
        tuple
            ``(direction, age_s, variance)``: the least-variance blend of the low-passes that run (3 floats,
            accelerometer units), its content's mean age (s) and its leak variance, (fraction of g)^2.
        """
        if self.first:
            l, q = self.lp1, self.q1
            l = (l[0] + alpha * (f[0] - l[0]), l[1] + alpha * (f[1] - l[1]), l[2] + alpha * (f[2] - l[2]))
            q = (q[0] + alpha * (f[0] - l[0] - q[0]), q[1] + alpha * (f[1] - l[1] - q[1]),
                 q[2] + alpha * (f[2] - l[2] - q[2]))
            self.lp1, self.q1 = l, q
            self.age1 = (1.0 - alpha) * (self.age1 + dt)
            n1 = math.sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]) / g - 1.0
            self.v11 += beta * (n1 * n1 + (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]) / (g * g) - self.v11)
        if self.second:
            self.lp2, self.lp2_rate = _butterworth(k2, self.lp2, self.lp2_rate, f)
            l = self.lp2
            self.q2, self.q2_rate = _butterworth(k2, self.q2, self.q2_rate, (f[0] - l[0], f[1] - l[1], f[2] - l[2]))
            (ty, tv), (f00, f01, f10, f11) = self.age_lp2, k2
            d = since_s - ty
            self.age_lp2 = (ty + (1.0 - f00) * d + f01 * tv, f11 * tv - f10 * d)
            self.age2 = since_s - self.age_lp2[0]
            q = self.q2
            n2 = math.sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]) / g - 1.0
            self.v22 += beta * (n2 * n2 + (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]) / (g * g) - self.v22)
        if not self.second:
            self.weight = 1.0
            return self.lp1, self.age1, self.v11
        age2 = self.age2
        if not self.first:
            self.weight = 0.0
            return self.lp2, age2, self.v22
        q1, q2 = self.q1, self.q2
        self.v12 += beta * (n1 * n2 + (q1[0] * q2[0] + q1[1] * q2[1] + q1[2] * q2[2]) / (g * g) - self.v12)
        w = self.weight = blend_weight(self.v11, self.v22, self.v12)
        u = 1.0 - w
        l1, l2 = self.lp1, self.lp2
        return ((w * l1[0] + u * l2[0], w * l1[1] + u * l2[1], w * l1[2] + u * l2[2]), w * self.age1 + u * age2,
                w * w * self.v11 + u * u * self.v22 + 2.0 * w * u * self.v12)
