r"""The accelerometer's own calibration from the still rows of a tumble (issue 22, items 2 and 5).

Model, in the accelerometer's (housing) frame and the recording's accelerometer unit:

.. math:: f = A\,(a - b), \qquad |f_k| = g_0 \quad (\text{still rows } k),

``a`` the reading, ``b`` the offset (3 numbers), ``A = I + E`` symmetric (6 numbers: the axes' scales and the
cross-axis sensitivity; no rotation, so the housing frame stays the accelerometer's, as the sensor model's
docstring says), ``g_0`` what 1 g reads: the median ``|a|`` over the still rows.  ``A``'s overall size and
``g_0`` trade exactly (``|c A (a - b)| = c g_0``); fixing ``g_0`` is the gauge, so the corrected reading is in
the recording's unit with 1 g reading ``g_0``.  Still rows (:func:`rest_rows`): the reading holds still over
:data:`REST_WINDOW_S` within its white noise, the only test that does not assume ``|a|`` is already right (an
uncalibrated board reads 0.77-1.30 g at rest, far beyond :func:`~calibrate.tumble.alignment.static_mask`'s 2 %).

What the still rows determine (the Jacobian of ``|f_k|`` at ``A = I``, ``b = 0``, ``u_k`` the row's gravity
direction): ``d|f_k| = g_0 u_k^T E u_k - u_k^T db``, a regression on ``(u_x^2, u_y^2, u_z^2, 2 u_x u_y, 2 u_x u_z,
2 u_y u_z)`` and ``-u_k``.  On the full sphere the nine regressors are independent: all of ``A`` and ``b``.  On a
cap about the axis ``n`` (a robot tilting at most ~60 deg) ``u_k = n cos t + (...) sin t`` with ``t`` small: the
offset along ``n`` (regressor ``-cos t ~ -1 + t^2 / 2``) and the scale along ``n`` (``g_0 cos^2 t ~ g_0 (1 -
t^2)``) differ only in ``t^2``: one combination (the reading of 1 g along ``n``) is well determined, the other only
as well as the spread of the cap's ``1 - cos t`` lets it (its sigma grows as ``1 / var(cos t)`` on a narrowing
cap).  The offsets and scales across ``n`` are seen through ``sin t`` and stay
determined.  Holding one of the cap's pair (:func:`fit_accelerometer`) makes ``|f|`` right on the cap but leaves
the direction off by what the held value is wrong, ``~ b_n (1 - cos t)``: on a board with 0.1-0.2 g offsets, degrees
across the cap (robot paths 60-69: the corrected direction's RMS error 14.4 -> 2.75 deg; with 0.015 g offsets
0.80 -> 0.23 deg).  The gyro knows the directions between dwells (``f_{d+1} = Q^T f_d``, ``Q`` its turn between
them: linear in ``A`` and ``b``); added as rows (its scale and axes at their prior, 1.4 deg over 60 deg) it did not
help on those paths (2.75 -> 2.91 deg, 0.23 -> 0.20 deg): the gyro's own errors and the dwells' ends, where the
robot still accelerates, weigh as much as what it pins; it is not used.  What does pin it: the gyro-aided fit
(:func:`calibrate.tumble.gyro.with_gyro`) with the held offsets and scales as parameters beside the gyro's matrix,
moved along :attr:`AccelCalibration.held_steps` (the fitted ones follow, ``|f|`` on the still rows unchanged to first
order), each with a prior sigma of the board's determined ones (:func:`_pin_prior`): there the field and gravity
keep their angle and every row's direction is tied to the others' by the gyro's turns, which sees ``b_n (1 - cos
t)``.  A value seen off zero is applied (:meth:`AccelCalibration.pinned`; robot paths 60-69, bad-accel board: the
corrected direction's error 2.75 -> 0.55 deg, low-cost 0.22 -> 0.27; docs/benchmarks.md).

Estimator: :func:`scipy.optimize.least_squares` on ``(|A (a_k - b)| - g_0) / sigma`` with a Gaussian prior
(:data:`OFFSET_PRIOR`, :data:`SCALE_PRIOR`, :data:`CROSS_PRIOR`: loose, a real board read 0.77-1.30 g), robust
(``soft_l1``) then plain on the rows within :data:`~calibrate.tumble.ellipsoid.OUTLIER_SIGMAS`; ``sigma`` the rows'
robust scatter, the covariance from the Jacobian.  A parameter is applied only where the data determine it
(sigma at most :data:`MAX_OFFSET_SIGMA` of ``g_0`` for an offset, :data:`MAX_MATRIX_SIGMA` for an entry of ``A``)
and sees it (:data:`SEEN_SIGMAS` off zero): the least determined one, then the least seen, is held at zero (``b``)
or the identity's (``A``) and the rest refitted, until every parameter fitted is determined and seen; what is held
for want of determination is said in :meth:`AccelCalibration.words`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.special import chdtri

from ..diagnosis.forms import json_float
from ..noise import robust_sigma, second_difference_sigma, second_differences
from .ellipsoid import OUTLIER_SIGMAS

__all__ = ["AccelCalibration", "NoAccelCalibration", "fit_accelerometer", "rest_rows"]

REST_WINDOW_S = 0.5
"""The window (centred, s) over which a still row's reading holds within its noise: shorter than a robot's dwells."""

REST_PROBABILITY = 0.99
"""A row is still when its window's chi-square is below this quantile of white noise's."""

MIN_REST_ROWS = 50
"""Fewer still rows give no calibration."""

MAX_ROWS = 20000
"""At most this many still rows are fitted (every ``k``-th): a 700000-row tumble's took 13.5 s of CPU on all of them.
The sigmas are then the thinned rows' (conservative by ``sqrt(k)``)."""

OFFSET_PRIOR = 0.3
"""Prior sigma of each offset, fraction of ``g_0`` (a real board's read 0.77-1.30 g at rest)."""

SCALE_PRIOR = 0.1
"""Prior sigma of each diagonal entry of ``A - I``."""

CROSS_PRIOR = 0.05
"""Prior sigma of each off-diagonal entry of ``A``."""

MAX_OFFSET_SIGMA = 0.005
"""An offset is applied when its sigma is at most this fraction of ``g_0`` (0.3 deg of tilt); held at zero otherwise.
Looser (0.02, a third of the MPU-9250's +-60 mg zero-g tolerance) left the cross terms free to trade with the
offsets across a robot's cap: the corrected direction's error on robot paths 60-69 rose from 0.23 to 0.44 deg
(low-cost board) and 2.75 to 2.91 deg (bad-accel board); holding nothing, to 18-19 deg (both before
:data:`SEEN_SIGMAS`, which took the first to 0.22; ``tools/bench_accel_fit.py``)."""

MAX_MATRIX_SIGMA = 0.005
"""An entry of ``A`` is applied when its sigma is at most this (0.3 deg of tilt); held at the identity's otherwise."""

SEEN_SIGMAS = 3.0
"""A determined parameter is applied only when it is this many sigmas off zero (the identity's), as the gyro matrix
(:func:`compass.calibration.gyro_matrix_seen`): a board without accelerometer errors keeps its readings."""

TRADE_CORRELATION = 0.9
"""An offset and a cross term correlated beyond this trade with each other (a cap): the cross term is held."""

_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
_NAMES = ("scale xx", "scale yy", "scale zz", "cross xy", "cross xz", "cross yz", "offset x", "offset y", "offset z")


class NoAccelCalibration(ValueError):
    """The recording does not give the accelerometer's calibration (in words)."""


@dataclass(frozen=True)
class AccelCalibration:
    """The accelerometer's correction ``f = matrix @ (a - offset)`` and what the data determined of it.

    Attributes
    ----------
    offset, offset_sigma : ndarray, shape (3,)
        ``b``, recording units; zero (its sigma NaN) where held or not seen.
    matrix, matrix_sigma : ndarray, shape (3, 3)
        ``A``, symmetric, dimensionless; the identity's entries (their sigma NaN) where held or not seen.
    one_g : float
        ``g_0``: what 1 g reads, recording units (the corrected reading's size at rest).
    held : tuple of str
        The parameters held for want of determination (the still rows' directions do not fix them), named as
        :data:`_NAMES`.
    unseen : tuple of str
        The parameters determined but not seen off zero (:data:`SEEN_SIGMAS`): left as read.
    n_rest : int
        Still rows fitted (:func:`rest_rows`, outliers out).
    spread_before, spread_after : float
        Robust sigma of ``|a| / g_0 - 1`` over the still rows, raw and corrected.
    to_pin : tuple of str
        The held offsets and scales the gyro-aided fit may determine (:func:`_pinnable`, :func:`_pin_prior`).
    pin_prior : ndarray, shape (len(to_pin),)
        Their prior sigmas (:func:`_pin_prior`).
    held_steps : ndarray, shape (len(to_pin), 9)
        Per parameter of :attr:`to_pin`, the change of all nine (:data:`_NAMES`' order) per unit of it with the
        determined ones refitted to the still rows (to first order: ``|f|`` on them unchanged; :func:`_held_steps`);
        what :meth:`held_change` moves.
    from_gyro : tuple of str
        The parameters the still rows left held that the gyro-aided fit determined (:meth:`pinned`).
    moved : tuple of str
        The others that moved with them along :attr:`held_steps`, their sigmas grown by it (:meth:`pinned`).
    """

    offset: np.ndarray
    offset_sigma: np.ndarray
    matrix: np.ndarray
    matrix_sigma: np.ndarray
    one_g: float
    held: tuple
    unseen: tuple
    n_rest: int
    spread_before: float
    spread_after: float
    to_pin: tuple = ()
    pin_prior: np.ndarray = field(default_factory=lambda: np.zeros(0))
    held_steps: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))
    from_gyro: tuple = ()
    moved: tuple = ()

    def apply(self, accel) -> np.ndarray:
        """Corrected readings ``A (a - b)``, shape (..., 3), recording units, the accelerometer's frame."""
        return (np.asarray(accel, dtype=float) - self.offset) @ self.matrix.T

    def params(self) -> np.ndarray:
        """The nine parameters (:data:`_NAMES`' order): ``A - I``'s entries, then ``b``."""
        return np.r_[[self.matrix[i, j] - (i == j) for i, j in _PAIRS], self.offset]

    def held_change(self, accel) -> np.ndarray:
        """``d f / d c``: the corrected rows' change per unit of each of :attr:`to_pin` moved along
        :attr:`held_steps`, shape (n, 3, len(to_pin)), recording units per unit."""
        d = np.asarray(accel, dtype=float) - self.offset
        out = [d @ (_matrix(step) - np.eye(3)).T - self.matrix @ step[6:] for step in self.held_steps]
        return np.stack(out, axis=2) if out else np.zeros((len(d), 3, 0))

    def pinned(self, values, sigmas) -> AccelCalibration:
        """This calibration with :attr:`to_pin` moved by ``values`` along :attr:`held_steps` (the gyro-aided fit's,
        :func:`calibrate.tumble.gyro.with_gyro`), those with a finite sigma (``sigmas``) stated, leaving :attr:`held`
        for :attr:`from_gyro`; the others (value zero, sigma NaN: not seen) stay held.  Every parameter the steps
        move has the pinned ones' sigmas through its step added to its variance (``sum_c (step_c sigma_c)^2``); one
        not seen off zero that they move leaves :attr:`unseen` with that sigma (the words name them)."""
        sigmas = np.asarray(sigmas, float)
        applied = np.isfinite(sigmas)
        change = np.where(applied, values, 0.0) @ self.held_steps
        p = self.params() + change
        before = np.r_[_sym_values(self.matrix_sigma), self.offset_sigma]
        added = np.sum((sigmas[applied, None] * self.held_steps[applied]) ** 2, axis=0)
        sig = np.where(added > 0.0, np.sqrt(np.nan_to_num(before) ** 2 + added), before)
        sig[[_NAMES.index(n) for n in self.to_pin]] = sigmas
        pinned = tuple(n for n, s in zip(self.to_pin, sigmas) if np.isfinite(s))
        return replace(self, offset=p[6:], matrix=_matrix(p), offset_sigma=sig[6:], matrix_sigma=_sym(sig[:6]),
                       held=tuple(n for n in self.held if n not in pinned), to_pin=(), pin_prior=np.zeros(0),
                       unseen=tuple(n for n in self.unseen if change[_NAMES.index(n)] == 0.0),
                       held_steps=np.zeros((0, 9)), from_gyro=pinned,
                       moved=tuple(n for n, c in zip(_NAMES, change) if c != 0.0 and n not in pinned))

    def words(self) -> str:
        """What was fitted and what held, for the report and the file."""
        scale = ", ".join(f"{100 * (self.matrix[i, i] - 1):+.2f}" for i in range(3))
        off = ", ".join(f"{100 * v / self.one_g:+.2f}" for v in self.offset)
        if len(self.held) + len(self.unseen) == len(_NAMES):
            text = f"accelerometer left as read: nothing seen off zero or determined from {self.n_rest} still rows"
        else:
            text = (f"accelerometer calibrated from {self.n_rest} still rows: offsets {off} % of 1 g, scales {scale} "
                    f"% (against 1 g read as the still rows' median |a|, {self.one_g:.4g}), |a| at rest spread "
                    f"{100 * self.spread_before:.2f} -> {100 * self.spread_after:.2f} % of 1 g")
        if self.held:
            text += (f"; not determined by the still rows' directions (held at zero / the identity): "
                     f"{', '.join(self.held)}")
        if self.from_gyro:
            text += (f"; not determined by the still rows' |a|, fitted beside the gyro-aided fit (the directions "
                     f"the gyro turned between them): {', '.join(self.from_gyro)}")
            if self.moved:
                text += f" (refitted with it: {', '.join(self.moved)})"
        if self.unseen:
            text += f"; not seen off zero (left as read): {', '.join(self.unseen)}"
        return text

    def to_json(self) -> dict:
        """The file's ``accelerometer`` block (SPEC section 2, tumble kind)."""
        return {"offset": self.offset.tolist(), "matrix": self.matrix.tolist(),
                "offset_sigma": [json_float(v) for v in self.offset_sigma],
                "matrix_sigma": [[json_float(v) for v in row] for row in self.matrix_sigma],
                "one_g": self.one_g, "unit": "recording units", "n_rest": self.n_rest, "held": list(self.held),
                "unseen": list(self.unseen), "from_gyro": list(self.from_gyro),
                "words": self.words()}


def rest_rows(accel: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    r"""Rows whose reading holds still over :data:`REST_WINDOW_S` (centred) within its white noise.

    ``chi2_k = sum_j |a_j - mean|^2 / sigma^2`` over the rows ``j`` of row ``k``'s window, ``sigma`` each axis's
    white noise (median over axes, from second differences); still when below the :data:`REST_PROBABILITY`
    quantile of the chi-square with ``3 (m - 1)`` degrees of freedom.  Needs no ``|a|``: a board whose ``|a|``
    is 30 % off at rest passes; a turn of 1 deg/s moves gravity by 0.0087 g in a second, a robot's moves far more.

    Parameters
    ----------
    accel : ndarray, shape (n, 3)
        Any unit.
    t_s : ndarray, shape (n,)
        Non-decreasing, s.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    accel, t_s = np.asarray(accel, float), np.asarray(t_s, float)
    n = len(accel)
    sigma = float(np.median(second_difference_sigma(second_differences(accel)))) if n >= 3 else 0.0
    if not sigma > 0:
        return np.zeros(n, dtype=bool)
    first = np.searchsorted(t_s, t_s - REST_WINDOW_S / 2.0, side="left")
    last = np.searchsorted(t_s, t_s + REST_WINDOW_S / 2.0, side="right")
    c1 = np.vstack([np.zeros((1, 3)), np.cumsum(accel, axis=0)])
    c2 = np.concatenate([[0.0], np.cumsum(np.sum(accel**2, axis=1))])
    m = last - first
    s1 = c1[last] - c1[first]
    chi2 = (c2[last] - c2[first] - np.sum(s1**2, axis=1) / m) / sigma**2
    dof = 3 * (m - 1)
    return (m >= 3) & (chi2 < chdtri(np.maximum(dof, 1), 1.0 - REST_PROBABILITY))


def _matrix(p: np.ndarray) -> np.ndarray:
    a = np.eye(3)
    for (i, j), v in zip(_PAIRS, p[:6]):
        a[i, j] += v
        if i != j:
            a[j, i] += v
    return a


class _Problem:
    """Residuals and Jacobian of the still rows' ``|A (a - b)| - g_0`` (over ``sigma``) and of the prior, the
    parameters ``free`` marks fitted (the others held at zero)."""

    def __init__(self, accel, one_g, sigma, free):
        self.accel, self.one_g, self.sigma, self.free = accel, one_g, sigma, free
        self.prior = np.r_[np.full(3, SCALE_PRIOR), np.full(3, CROSS_PRIOR), np.full(3, OFFSET_PRIOR * one_g)]

    def full(self, x):
        p = np.zeros(9)
        p[self.free] = x
        return p

    def residual(self, x):
        p = self.full(x)
        f = (self.accel - p[6:]) @ _matrix(p).T
        return np.r_[(np.linalg.norm(f, axis=1) - self.one_g) / self.sigma, x / self.prior[self.free]]

    def jacobian(self, x):
        p = self.full(x)
        d = self.accel - p[6:]
        f = d @ _matrix(p).T
        u = f / np.linalg.norm(f, axis=1, keepdims=True)
        cols = [u[:, i] * d[:, j] + (u[:, j] * d[:, i] if i != j else 0.0) for i, j in _PAIRS]
        cols += list((-u @ _matrix(p)).T)
        jac = np.column_stack(cols)[:, self.free] / self.sigma
        return np.vstack([jac, np.diag(1.0 / self.prior[self.free])])


def _fit(accel, one_g, sigma, free, x0):
    """Robust then plain fit of the ``free`` parameters: (parameters, sigmas, covariance, inliers)."""
    prob = _Problem(accel, one_g, sigma, free)
    bound = (3.0 * prob.prior)[free]  # keeps A from a sign flip of an axis, which leaves |f| unchanged
    robust = least_squares(prob.residual, np.clip(x0, -0.9 * bound, 0.9 * bound), jac=prob.jacobian, loss="soft_l1",
                           f_scale=3.0, method="trf", bounds=(-bound, bound), x_scale="jac")
    r = prob.residual(robust.x)[:len(accel)] * sigma
    sigma = max(float(robust_sigma(r)), 1e-9 * one_g)
    keep = np.abs(r) < OUTLIER_SIGMAS * sigma
    plain = _Problem(accel[keep], one_g, sigma, free)
    final = least_squares(plain.residual, robust.x, jac=plain.jacobian, method="lm")
    r = final.fun[:np.count_nonzero(keep)]
    chi2 = float(r @ r) / max(len(r) - len(final.x), 1)
    cov = np.linalg.pinv(final.jac.T @ final.jac) * max(chi2, 1.0)
    return final.x, np.sqrt(np.clip(np.diag(cov), 0.0, None)), cov, keep


def fit_accelerometer(accel: np.ndarray, t_s: np.ndarray) -> AccelCalibration:
    """The accelerometer's offsets and symmetric matrix from the still rows (module docstring).

    Parameters
    ----------
    accel : ndarray, shape (n, 3)
        Accelerometer (specific force, +1 g up at rest), recording units, its own (the housing) frame.
    t_s : ndarray, shape (n,)
        Time of each row, s, non-decreasing.

    Returns
    -------
    AccelCalibration

    Raises
    ------
    NoAccelCalibration
        Fewer than :data:`MIN_REST_ROWS` still rows, or no parameter determined (said in words).
    """
    accel, t_s = np.asarray(accel, float), np.asarray(t_s, float)
    ok = np.all(np.isfinite(accel), axis=1) & np.isfinite(t_s)
    still = np.zeros(len(accel), dtype=bool)
    still[ok] = rest_rows(accel[ok], t_s[ok])
    if np.count_nonzero(still) < MIN_REST_ROWS:
        raise NoAccelCalibration(f"only {np.count_nonzero(still)} rows where the accelerometer held still "
                                 f"(at least {MIN_REST_ROWS} needed): the accelerometer is taken as read")
    rows = accel[still][::-(-np.count_nonzero(still) // MAX_ROWS)]  # every k-th, at most MAX_ROWS
    norm = np.linalg.norm(rows, axis=1)
    one_g = float(np.median(norm))
    sigma = max(float(robust_sigma(norm)), 1e-9 * one_g)
    free, undetermined = np.ones(9, dtype=bool), np.zeros(9, dtype=bool)
    x, sig, cov, keep = _fit(rows, one_g, sigma, free, np.zeros(9))
    limit = np.r_[np.full(6, MAX_MATRIX_SIGMA), np.full(3, MAX_OFFSET_SIGMA * one_g)]
    while True:  # hold what is not determined, then what is not seen off zero; refit the rest each time
        bad = ~(sig <= limit[free])
        unseen = ~(np.abs(x) > SEEN_SIGMAS * sig)
        if not bad.any() and not unseen.any():
            break
        start = np.zeros(9)
        start[free] = x
        if bad.any():
            k = _to_hold(np.flatnonzero(free), sig / limit[free], cov)
            free[k], undetermined[k] = False, True
        else:
            free[np.flatnonzero(free)[np.argmin(np.abs(x) / sig)]] = False
        if undetermined.all():
            raise NoAccelCalibration("no offset or scale of the accelerometer is determined by the still rows' "
                                     "directions: the accelerometer is taken as read")
        if not free.any():  # every parameter determined is within its noise of zero: the readings are right
            x = sig = np.zeros(0)
            break
        x, sig, cov, keep = _fit(rows, one_g, sigma, free, start[free])
    p = np.zeros(9)
    p[free], sigmas = x, np.full(9, np.nan)
    sigmas[free] = sig
    cal = AccelCalibration(p[6:], sigmas[6:], _matrix(p), _sym(sigmas[:6]), one_g,
                           tuple(n for n, u in zip(_NAMES, undetermined) if u),
                           tuple(n for n, f, u in zip(_NAMES, free, undetermined) if not f and not u),
                           int(np.count_nonzero(keep)),
                           float(robust_sigma(norm / one_g - 1.0)), 0.0)
    prior = _pin_prior(p, undetermined)
    pin = undetermined & (prior > 0) & np.array([_pinnable(n) for n in _NAMES])
    if pin.any():
        cal = replace(cal, to_pin=tuple(n for n, k in zip(_NAMES, pin) if k), pin_prior=prior[pin],
                      held_steps=_held_steps(_Problem(rows[keep], one_g, sigma, np.ones(9, bool)), p, ~undetermined,
                                             pin))
    after = np.linalg.norm(cal.apply(rows), axis=1) / one_g - 1.0
    return replace(cal, spread_after=float(robust_sigma(after)))


def _pinnable(name: str) -> bool:
    """Whether a held parameter goes to the gyro-aided fit (:func:`calibrate.tumble.gyro.with_gyro`): an offset or
    a scale, the cap's pair along its axis.  A held cross term trades with the offset across the axis
    (:func:`_to_hold`); fitted beside too (a first version: the default windows, every value applied), the pair
    wandered (low-cost board, robot paths 60-64: the corrected direction's error 0.23 -> 0.80 deg, offsets across the
    axis up to 0.5 m/s^2 off; ``tools/bench_accel_fit.py``)."""
    return name.startswith(("offset", "scale"))


def _pin_prior(p: np.ndarray, held: np.ndarray) -> np.ndarray:
    """The prior sigma of each parameter for the gyro-aided fit (:class:`AccelCalibration`'s ``to_pin``): a held
    offset's, the RMS of the board's determined offsets (those not seen off zero as zero), a held scale's, of its
    determined scales (the axes of one chip share a tolerance); zero (not fitted) where none is determined."""
    out = np.zeros(9)
    for group in (slice(0, 3), slice(6, 9)):
        known = ~held[group]
        out[group] = np.sqrt(np.mean(p[group][known] ** 2)) if known.any() else 0.0
    return out


def _held_steps(prob: _Problem, p: np.ndarray, free: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Per ``held`` parameter, the change of all nine per unit of it with the ``free`` ones refitted (first order, on
    ``prob``'s rows: ``-J_free^+ J_held``; the other parameters stay), shape (count of held, 9).  ``free``: the
    determined ones, those not seen off zero too (held at zero for their size only, they keep the cap's determined
    combination: on the low-cost board, robot path 65, the offset along the axis pinned at its truth with the
    scale along it left at zero took the corrected direction's error 0.12 -> 0.35 deg; moved too, 0.12)."""
    jac = prob.jacobian(p)[:len(prob.accel)]
    steps = np.zeros((np.count_nonzero(held), 9))
    steps[:, held] = np.eye(len(steps))
    if free.any():
        steps[:, free] = -np.linalg.lstsq(jac[:, free], jac[:, held], rcond=None)[0].T
    return steps


def _to_hold(index: np.ndarray, ratio: np.ndarray, cov: np.ndarray) -> int:
    """The parameter to hold next (of ``index``, the free ones): the least determined (the largest ``ratio``, sigma
    over its limit), or the cross term it trades with (correlation beyond :data:`TRADE_CORRELATION`) when it is an
    offset:
    on a cap the offset across the cap's axis ``n`` and the cross term of that axis with ``n`` differ only in
    ``t^2``, and a board's offsets (tens of mg) outweigh its cross-axis sensitivity (the datasheet's 2 %)."""
    k = int(np.argmax(ratio))
    corr = cov[k] / np.sqrt(cov[k, k] * np.diag(cov))
    corr[k] = 0.0
    j = int(np.argmax(np.abs(corr)))
    if index[k] >= 6 and 3 <= index[j] < 6 and abs(corr[j]) > TRADE_CORRELATION:
        return int(index[j])
    return int(index[k])


def _sym_values(m: np.ndarray) -> np.ndarray:
    """The six entries of the symmetric ``m`` in :data:`_PAIRS`' order."""
    return np.array([m[i, j] for i, j in _PAIRS])


def _sym(v: np.ndarray) -> np.ndarray:
    out = np.zeros((3, 3))
    for (i, j), s in zip(_PAIRS, v):
        out[i, j] = out[j, i] = s
    return out
