"""The lever arm of a hand-held turn, and what it leaves in the inertial low-pass (``FilterConfig.lever_arm``).

A housing turned about a centre it is not at (a wrist, an elbow) moves on a circle: with the centre at rest and
the IMU at ``r`` in H (constant), its velocity in the world is ``v = R (w x r)`` and the specific force it reads
is gravity plus ``(dw/dt x r) + w x (w x r) = M r``, ``M = [dw/dt]x + [w]x^2``.  The first-order inertial low-pass
leaves of it ``(v - LP v) / tau`` exactly (the low-pass of a derivative), so with ``r`` known the tilt measurement
subtracts that, run beside the low-pass of the specific force (no differentiation).

``r`` is a recursive least-squares fit of ``f - R^T z g`` (the specific force less gravity put into H by the
filter's attitude) on ``M``, both averaged alike over blocks of :data:`BLOCK_S` (the block's mean ``dw/dt`` is its
rate's change over its length, so no sample is differentiated), forgotten over :data:`MEMORY_S`, with a ridge
prior ``r = 0`` of weight :data:`PRIOR`: a translation (``M`` about 0) leaves ``r`` at 0.  The centre's own
acceleration is the fit's noise.

The tilt's noise follows the motion the low-pass leaks (``residual_var``, from ``f`` less the low-pass).  With the
arm's leftover taken out of the measurement, ``M r`` no longer leaks, so :func:`acceleration` takes it out of that
residual too: what remains is the centre's own acceleration and the fit's error ``M (r - r_fit)``, whose leftover
is what the measurement still carries of the arm.  Its ``dw/dt`` is the rate's change low-passed over
:data:`BLOCK_S`: the change between two samples alone turns the gyro's white noise into ``sqrt(2) sigma / dt`` of
angular acceleration (about 1 rad/s^2 at 200 Hz, 0.15 m/s^2 through a 15 cm arm, three times the accelerometer's
noise), which would widen the tilt's noise at rest; over :data:`BLOCK_S` it is ``dt / BLOCK_S`` of that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["LeverState", "acceleration", "add_sample", "leftover", "restart", "restart_block"]

BLOCK_S = 0.05
"""Length of the blocks both sides of the fit are averaged over, s (short against a hand's turn)."""
MEMORY_S = 30.0
"""The fit's forgetting time, s: a grip that changes is followed within it."""
PRIOR = 100.0
"""The ridge prior's weight on ``r = 0``, s^-3: the centre's acceleration's density (about (0.1 g)^2 over 1 s)
over a prior sigma of 0.1 m of lever arm (0.01 g s^2): 30 s of a 2 rad/s turn (``M^2`` about 16 s^-4) outweighs it
five times, a slow translation's stray turns not at all."""


@dataclass(slots=True)
class LeverState:
    """The lever arm's fit and the low-pass of its velocity (part of ``GyroState``).

    Attributes
    ----------
    arm : tuple of 3 floats
        ``r``, the IMU's offset from the turn's centre in H, accelerometer units times s^2 (m for m/s^2).
    info : tuple of 6 floats
        ``integral M^T M dt`` (forgotten over :data:`MEMORY_S`), its upper triangle row by row, s^-3.
    moment : tuple of 3 floats
        ``integral M^T (f - R^T z g) dt``, accelerometer units s^-1.
    block_s : float
        Time accumulated in the current block, s.
    block_y : tuple of 3 floats
        ``integral (f - R^T z g) dt`` over the block, accelerometer units times s.
    block_q : tuple of 6 floats
        ``integral w w^T dt`` over the block (upper triangle), rad^2/s.
    block_w0 : tuple of 3 floats, or None
        The rate at the block's start, rad/s (None: no block started).
    low_pass : tuple of 3 floats, or None
        The velocity ``w x r`` low-passed in the inertial frame (as the specific force is), seen in H,
        accelerometer units times s; None until the low-pass (re)starts.
    rate : tuple of 3 floats, or None
        The previous accelerometer sample's rate, rad/s (H), for :func:`acceleration`'s ``dw/dt``; None after a
        restart or a sample without the accelerometer.
    rate_change : tuple of 3 floats
        ``dw/dt`` low-passed over :data:`BLOCK_S`, rad/s^2 (H); zero after a restart or a sample without the
        accelerometer.
    """

    arm: tuple = (0.0, 0.0, 0.0)
    info: tuple = (0.0,) * 6
    moment: tuple = (0.0, 0.0, 0.0)
    block_s: float = 0.0
    block_y: tuple = (0.0, 0.0, 0.0)
    block_q: tuple = (0.0,) * 6
    block_w0: tuple | None = None
    low_pass: tuple | None = None
    rate: tuple | None = None
    rate_change: tuple = (0.0, 0.0, 0.0)


def restart_block(st: LeverState) -> None:
    """Drop the open block (a sample without the accelerometer: the rate's change over the skipped time would be
    taken over the block's shorter one); the fit is kept."""
    st.block_s, st.block_y, st.block_q, st.block_w0 = 0.0, (0.0, 0.0, 0.0), (0.0,) * 6, None
    st.rate, st.rate_change = None, (0.0, 0.0, 0.0)


def restart(st: LeverState) -> None:
    """The low-pass restarts (a gap, the filter's start): its velocity's low-pass and the open block go with it;
    the fit is kept (the grip is the same housing's)."""
    restart_block(st)
    st.low_pass = None


def add_sample(st: LeverState, dt: float, w: tuple, y: tuple) -> None:
    """One sample into the block: rate ``w`` (rad/s, H) and ``y = f - R^T z g`` (accelerometer units, H) held
    over ``dt`` s; a full block updates the fit and :attr:`LeverState.arm`."""
    wx, wy, wz = w
    if st.block_w0 is None:
        st.block_w0 = w
        return
    yx, yy, yz = st.block_y
    st.block_y = (yx + y[0] * dt, yy + y[1] * dt, yz + y[2] * dt)
    q = st.block_q
    st.block_q = (q[0] + wx * wx * dt, q[1] + wx * wy * dt, q[2] + wx * wz * dt, q[3] + wy * wy * dt,
                  q[4] + wy * wz * dt, q[5] + wz * wz * dt)
    st.block_s += dt
    if st.block_s >= BLOCK_S:
        _close_block(st, w)


def _close_block(st: LeverState, w: tuple) -> None:
    """The block's means into the fit (forgetting the old), the arm solved, the next block started at ``w``."""
    t = st.block_s
    (w0x, w0y, w0z), inv = st.block_w0, 1.0 / t
    ax, ay, az = (w[0] - w0x) * inv, (w[1] - w0y) * inv, (w[2] - w0z) * inv  # the block's mean dw/dt
    q0, q1, q2, q3, q4, q5 = (v * inv for v in st.block_q)  # mean w w^T
    trace = q0 + q3 + q5
    # M = [dw/dt]x + w w^T - |w|^2 I, averaged over the block
    m00, m01, m02 = q0 - trace, q1 - az, q2 + ay
    m10, m11, m12 = q1 + az, q3 - trace, q4 - ax
    m20, m21, m22 = q2 - ay, q4 + ax, q5 - trace
    yx, yy, yz = (v * inv for v in st.block_y)
    keep = math.exp(-t / MEMORY_S)
    i = st.info
    st.info = (keep * i[0] + t * (m00 * m00 + m10 * m10 + m20 * m20),
               keep * i[1] + t * (m00 * m01 + m10 * m11 + m20 * m21),
               keep * i[2] + t * (m00 * m02 + m10 * m12 + m20 * m22),
               keep * i[3] + t * (m01 * m01 + m11 * m11 + m21 * m21),
               keep * i[4] + t * (m01 * m02 + m11 * m12 + m21 * m22),
               keep * i[5] + t * (m02 * m02 + m12 * m12 + m22 * m22))
    b = st.moment
    st.moment = (keep * b[0] + t * (m00 * yx + m10 * yy + m20 * yz), keep * b[1] + t * (m01 * yx + m11 * yy + m21 * yz),
                 keep * b[2] + t * (m02 * yx + m12 * yy + m22 * yz))
    st.arm = _solve(st.info, st.moment)
    st.block_s, st.block_y, st.block_q, st.block_w0 = 0.0, (0.0, 0.0, 0.0), (0.0,) * 6, w


def _solve(i: tuple, b: tuple) -> tuple:
    """``(info + PRIOR I)^-1 moment`` (symmetric 3 x 3, by cofactors)."""
    a00, a01, a02, a11, a12, a22 = i[0] + PRIOR, i[1], i[2], i[3] + PRIOR, i[4], i[5] + PRIOR
    c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
    c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    return ((c00 * b[0] + c01 * b[1] + c02 * b[2]) / det, (c01 * b[0] + c11 * b[1] + c12 * b[2]) / det,
            (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det)


def leftover(st: LeverState, alpha: float, tau: float, w: tuple) -> tuple:
    """What the first-order inertial low-pass (step gain ``alpha``, time constant ``tau`` s) leaves of the lever
    arm's acceleration, ``(v - LP v) / tau`` with ``v = w x r`` (H, accelerometer units); steps the low-pass of ``v``
    (already turned into this sample's H by the propagation)."""
    (wx, wy, wz), (rx, ry, rz) = w, st.arm
    vx, vy, vz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
    if st.low_pass is None:
        st.low_pass = (vx, vy, vz)
        return 0.0, 0.0, 0.0
    lx, ly, lz = st.low_pass
    lx, ly, lz = lx + alpha * (vx - lx), ly + alpha * (vy - ly), lz + alpha * (vz - lz)
    st.low_pass = (lx, ly, lz)
    return (vx - lx) / tau, (vy - ly) / tau, (vz - lz) / tau


def acceleration(st: LeverState, dt: float, w: tuple) -> tuple:
    """The lever arm's acceleration ``M r = dw/dt x r + w x (w x r)`` (H, accelerometer units) with the fitted arm.

    ``dw/dt`` is the rate's change since the previous sample over ``dt`` s, low-passed over :data:`BLOCK_S`
    (``LeverState.rate_change``; no change is taken on the first sample after a restart); ``w`` (rad/s, H) is kept
    for the next sample.
    """
    (wx, wy, wz), (rx, ry, rz) = w, st.arm
    vx, vy, vz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx  # w x r
    ax, ay, az = wy * vz - wz * vy, wz * vx - wx * vz, wx * vy - wy * vx  # w x (w x r)
    if st.rate is not None:
        beta, inv = -math.expm1(-dt / BLOCK_S), 1.0 / dt
        cx, cy, cz = st.rate_change
        st.rate_change = (cx + beta * ((wx - st.rate[0]) * inv - cx), cy + beta * ((wy - st.rate[1]) * inv - cy),
                          cz + beta * ((wz - st.rate[2]) * inv - cz))
    dx, dy, dz = st.rate_change
    st.rate = w
    return ax + dy * rz - dz * ry, ay + dz * rx - dx * rz, az + dx * ry - dy * rx
