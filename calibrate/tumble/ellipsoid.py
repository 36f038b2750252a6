"""Ellipsoid fits of a tumble (hard and soft iron): the three kinds, their statistics and the automatic choice.

See :mod:`calibrate.tumble` for the model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np
from scipy.linalg import cho_factor, cho_solve, sqrtm
from scipy.optimize import OptimizeResult, least_squares, leastsq

from compass.frames import row_norms

from ..noise import robust_sigma
from .coverage import Coverage, sphere_coverage

ELLIPSOIDS = ("offset", "diagonal", "full")


_N_PARAMS = {"offset": 4, "diagonal": 6, "full": 9}


OUTLIER_SIGMAS = 4.0
"""Samples farther than this many robust sigmas from the fitted ellipsoid are dropped."""


MAX_RELATIVE_SIGMA = 0.01
"""A kind is determined when every standard error (offset / field, soft-iron element) is below this."""


MAX_RADIUS_RATIO = 3.0
"""A fit whose field norm exceeds this many times the samples' extent (95th percentile of their
distance from their median) is degenerate: a huge sphere through a nearly flat patch of samples,
as when the field changed partway (a magnet attached to the device)."""


MAX_NFEV = 400


ROBUST_ROWS = 20000
"""Most samples a robust (``soft_l1``) fit uses; more are thinned evenly (:func:`robust_rows`).

The robust fits only give the plain fit its start and the outlier test its parameters; the plain
fit on every inlier gives the result, its standard errors and its chi-square.  From 20000 samples
the start is within ``sqrt(n / 20000)`` of the full data's standard errors of the optimum (a few
Gauss-Newton steps), and a sample's residual moves by about ``noise sqrt(k / 20000)``, 2 % of the
noise for 9 parameters, against a threshold of ``OUTLIER_SIGMAS`` noise sigmas: only samples within
that of the threshold can change side.  ``tools/bench_scale.py`` shows the calibration unchanged
within a small fraction of its sigma; at most this many samples, nothing changes at all.
"""


@dataclass(frozen=True)
class EllipsoidFit:
    """One ellipsoid kind fitted to the samples.

    Attributes
    ----------
    ellipsoid : str
    hard_iron, hard_iron_sigma : ndarray, shape (3,)
        Offset ``h`` and its standard error, recording units.
    soft_iron, soft_iron_sigma : ndarray, shape (3, 3)
        ``S`` normalised to ``det S = 1`` and its element-wise standard error.
    field_norm, field_norm_sigma : float
        Geometric-mean radius ``F``, recording units.
    residuals : ndarray, shape (n,)
        ``|S (x - h)| - F`` of every sample (outliers included), recording units.
    inliers : ndarray of bool, shape (n,)
    rss : float
        Sum of squared residuals over ``inliers``.
    bic : float
        On the common sample set of the comparison (NaN if not compared).
    determined : bool
    reason : str
        Why the kind is not determined (empty if it is).
    success : bool
    message : str
    params : ndarray
        Fit parameters in normalised units: ``(h - centre) / radius``, then the shape of ``L``.
    centre, radius : ndarray (3,), float
        The normalisation (algebraic sphere fit), recording units.
    degenerate : bool
        The field norm exceeds ``MAX_RADIUS_RATIO`` times the samples' extent (see ``reason``).
    """

    ellipsoid: str
    hard_iron: np.ndarray
    hard_iron_sigma: np.ndarray
    soft_iron: np.ndarray
    soft_iron_sigma: np.ndarray
    field_norm: float
    field_norm_sigma: float
    residuals: np.ndarray
    inliers: np.ndarray
    rss: float
    bic: float
    determined: bool
    reason: str
    success: bool
    message: str
    params: np.ndarray
    centre: np.ndarray
    radius: float
    degenerate: bool = False

    @property
    def n_params(self) -> int:
        return _N_PARAMS[self.ellipsoid]

    def calibrated(self, mag: np.ndarray) -> np.ndarray:
        """``S (x - h)``, shape (n, 3), recording units (det S = 1)."""
        return (np.asarray(mag, dtype=float) - self.hard_iron) @ self.soft_iron.T


def shape_matrix(ellipsoid: str, p: np.ndarray) -> np.ndarray:
    """Lower-triangular L (S^2 / F^2 = L L^T) from the shape parameters."""
    if ellipsoid == "offset":
        return np.exp(p[0]) * np.eye(3)
    if ellipsoid == "diagonal":
        return np.diag(np.exp(p[:3]))
    low = np.diag(np.exp(p[:3]))
    low[1, 0], low[2, 0], low[2, 1] = p[3:6]
    return low


def _shape_params(ellipsoid: str, m: np.ndarray) -> np.ndarray:
    """Start values for ``ellipsoid`` from a positive-definite ``S^2 / F^2`` matrix ``m``."""
    if ellipsoid == "offset":
        return np.array([0.5 * np.log(np.mean(np.diag(m)))])
    if ellipsoid == "diagonal":
        return 0.5 * np.log(np.diag(m))
    low = np.linalg.cholesky(m)
    return np.concatenate([np.log(np.diag(low)), [low[1, 0], low[2, 0], low[2, 1]]])


def radial_residual(p, ellipsoid, y):
    low = shape_matrix(ellipsoid, p[3:])
    z = (y - p[:3]) @ low
    return np.sqrt(np.einsum("ij,ij->i", z, z)) - 1.0


_JACOBIAN_CHUNK_ROWS = 16384
"""Rows :func:`radial_jacobian` computes at a time: its temporaries then stay in the CPU's cache (1.5x faster
on a 700000-sample tumble than all rows at once)."""


def _radial_columns(p, ellipsoid, low, y):
    """``|z|`` of each row of ``y`` (shape (m,)) and the transposed Jacobian of :func:`radial_residual` (shape
    (k, m)): each column of the Jacobian is a contiguous row here, and so is each coordinate of ``d`` and ``z``
    (twice as fast as the same products on (m, 3) rows on a 700000-sample tumble)."""
    d = np.ascontiguousarray((y - p[:3]).T)
    z = low.T @ d
    norm = np.sqrt(np.einsum("ij,ij->j", z, z))
    u = z / norm
    jac_t = np.empty((len(p), len(y)))
    np.matmul(-low, u, out=jac_t[:3])
    if ellipsoid == "offset":
        jac_t[3] = norm
    elif ellipsoid == "diagonal":
        np.multiply(z, u, out=jac_t[3:6])
    else:
        np.multiply(d * np.diag(low)[:, None], u, out=jac_t[3:6])
        np.multiply(d[1:], u[:1], out=jac_t[6:8])  # d_y u_x, d_z u_x
        np.multiply(d[2], u[1], out=jac_t[8])  # d_z u_y
    return norm, jac_t


def radial_jacobian(p, ellipsoid, y, out=None):
    """Analytic Jacobian of :func:`radial_residual`, shape (n, 3 + shape parameters).

    With ``d = y - h``, ``z = d L`` and ``u = z / |z|``: ``dr/dh = -L u`` and ``dr/dL_ij = d_i u_j``;
    the diagonal of ``L`` is ``exp`` of its parameter, so ``dr/dp_k = d_k u_k L_kk`` there.  ``out``
    (that shape, e.g. a block of a larger Jacobian) receives it instead of a new array.
    """
    low = shape_matrix(ellipsoid, p[3:])
    jac = np.empty((len(y), len(p))) if out is None else out
    for start in range(0, len(y), _JACOBIAN_CHUNK_ROWS):
        rows = slice(start, start + _JACOBIAN_CHUNK_ROWS)
        jac[rows] = _radial_columns(p, ellipsoid, low, y[rows])[1].T
    return jac


def _unpack(ellipsoid, p, centre, radius):
    """(h, S det 1, F) in recording units from normalised parameters."""
    low = shape_matrix(ellipsoid, p[3:])
    a = np.real(sqrtm(low @ low.T)) / radius  # S / F, maps raw units onto the unit sphere
    a = (a + a.T) / 2.0
    f_norm = np.linalg.det(a) ** (-1.0 / 3.0)
    return centre + radius * p[:3], a * f_norm, f_norm


GAUSS_NEWTON_STEPS = 6
"""Most Gauss-Newton steps :func:`plain_fit` takes before it hands over to MINPACK's Levenberg-Marquardt."""
GAUSS_NEWTON_TOL = 1e-6
""":func:`plain_fit` has converged when the chi-square the next Gauss-Newton step would remove is below this
many reduced chi-squares: the step is under ``sqrt(1e-6)``, a thousandth of a standard error, in every direction."""
AT_LIMIT_TOL = 1e-2
"""A fit MINPACK stopped at its evaluation limit is at its minimum in fact when the next Gauss-Newton step would
remove less than this many reduced chi-squares: the step is under a tenth of a standard error in every direction,
so its numbers are the minimum's to the data's precision (:func:`plain_fit`)."""


class Normal(NamedTuple):
    """The normal equations of a least-squares problem at a point: ``r^T r``, ``J^T J``, ``J^T r`` and the rows."""

    chi2: float
    jtj: np.ndarray
    jtr: np.ndarray
    rows: int



def radial_normal(p, ellipsoid, y) -> Normal:
    """:class:`Normal` of :func:`radial_residual` and :func:`radial_jacobian` over ``y``, summed a chunk of
    :data:`_JACOBIAN_CHUNK_ROWS` rows at a time: the normal equations of a Gauss-Newton step without the
    ``(n, k)`` Jacobian (:func:`plain_fit`'s ``normal``)."""
    k = len(p)
    low = shape_matrix(ellipsoid, p[3:])
    chi2, jtj, jtr = 0.0, np.zeros((k, k)), np.zeros(k)
    for start in range(0, len(y), _JACOBIAN_CHUNK_ROWS):
        norm, jac_t = _radial_columns(p, ellipsoid, low, y[start:start + _JACOBIAN_CHUNK_ROWS])
        r = norm - 1.0
        chi2 += float(r @ r)
        jtj += jac_t @ jac_t.T
        jtr += jac_t @ r
    return Normal(chi2, jtj, jtr, len(y))


def plain_fit(fun, x0: np.ndarray, jac, args=(), max_nfev: int = MAX_NFEV, normal=None) -> OptimizeResult:
    """Least squares ``min |fun(x)|^2`` from a close start: Gauss-Newton on the normal equations, else MINPACK.

    The plain fits start from a robust fit or from a neighbouring optimum, a few standard errors from
    their own, where the model is linear to far below the noise: Gauss-Newton steps
    ``(J^T J) dx = -J^T r`` (``J^T J`` is ``k x k``) reach it in one or two steps.  Each step costs a
    residual, a Jacobian and ``J^T J``; MINPACK's ``lmder`` (:func:`scipy.optimize.leastsq`) adds an
    unblocked pivoted QR of the ``(m, k)`` Jacobian per step and more steps (its ``ftol`` on the
    relative reduction), 80 % of the fit's time on a 700000-sample tumble (``tools/bench_scale.py``).
    Converged is :data:`GAUSS_NEWTON_TOL`: the step left untaken moves no parameter by more than a
    thousandth of its standard error.  A step that does not lower the chi-square, a singular ``J^T J``
    or no convergence within :data:`GAUSS_NEWTON_STEPS` hands over to ``lmder`` from ``x0`` (with
    ``least_squares``' tolerances; it keeps no ``least_squares`` copies of the Jacobian): Gauss-Newton
    cannot go on where the model is far from linear (a degenerate fit), where ``lmder``'s trust region
    from the start is the safer path.

    ``normal(x, *args) -> Normal``, when given, gives Gauss-Newton its normal equations
    summed without the ``(m, k)`` Jacobian (:func:`radial_normal`: a chunk of rows at a time, in cache,
    the residual and the Jacobian from one pass): the result then holds neither ``fun`` nor ``jac``
    unless ``lmder`` took over.

    Returns
    -------
    OptimizeResult
        ``x``, ``chi2`` (``r^T r``) and ``jtj`` (``J^T J``) at ``x``, ``fun`` and ``jac`` at ``x`` (None when
        ``normal`` gave the Gauss-Newton optimum), ``success``, ``message``, ``nfev``, as ``least_squares``'.
    """
    x = np.array(x0, dtype=float)
    r = j = None
    if normal is None:
        r = fun(x, *args)
        dof, chi2 = max(r.size - x.size, 1), float(r @ r)
    else:
        chi2, jtj, g, rows = normal(x, *args)
        dof = max(rows - x.size, 1)
    nfev = 1
    for _ in range(GAUSS_NEWTON_STEPS):
        if normal is None:
            j = jac(x, *args)
            jtj, g = j.T @ j, j.T @ r
        try:
            dx = -cho_solve(cho_factor(jtj), g)
        except ValueError:  # LinAlgError (not positive definite) is one, and so are non-finite entries
            break
        drop = float(-(g @ dx))  # the linear model's chi-square drop, dx^T J^T J dx
        if not np.isfinite(drop):
            break
        if drop <= GAUSS_NEWTON_TOL * chi2 / dof:
            return OptimizeResult(x=x, fun=r, jac=j, chi2=chi2, jtj=jtj, success=True, nfev=nfev,
                                  message=f"Gauss-Newton converged: the next step removes {drop:.2g} of chi-square "
                                          f"{chi2:.6g} ({dof} degrees of freedom)")
        j = None
        with np.errstate(over="ignore", invalid="ignore"):  # a wild step (a near-singular J^T J) is only tried
            if normal is None:
                r_new = fun(x + dx, *args)
                chi2_new = float(r_new @ r_new)
            else:
                chi2_new, jtj_new, g_new, _ = normal(x + dx, *args)
        nfev += 1
        if not chi2_new < chi2:
            break
        x, chi2 = x + dx, chi2_new
        if normal is None:
            r = r_new
        else:
            jtj, g = jtj_new, g_new
    del r
    with np.errstate(over="ignore", invalid="ignore"):  # its trial steps too: one that overflows is rejected
        x, _, info, message, status = leastsq(fun, x0, args=args, Dfun=jac, full_output=True, ftol=1e-8, xtol=1e-8,
                                              gtol=1e-8, maxfev=max_nfev)
    nfev += int(info["nfev"])
    del info  # MINPACK's (m, k) work array
    r, j = fun(x, *args), jac(x, *args)
    chi2, jtj = float(r @ r), j.T @ j
    success = status in (1, 2, 3, 4)
    if not success:  # stopped at its evaluation limit: at the minimum in fact, or still on its way?
        message = _at_the_limit(message, chi2, jtj, j.T @ r, max(r.size - x.size, 1))
        success = message.startswith("at its minimum")
    return OptimizeResult(x=x, fun=r, jac=j, chi2=chi2, jtj=jtj, success=success, message=message, nfev=nfev)


def _at_the_limit(message: str, chi2: float, jtj: np.ndarray, jtr: np.ndarray, dof: int) -> str:
    """Words for a fit MINPACK stopped with ``message`` (its evaluation limit): "at its minimum ..." when the next
    Gauss-Newton step would remove under :data:`AT_LIMIT_TOL` reduced chi-squares (under a tenth of a standard
    error), else how far it still had to go."""
    try:
        drop = float(jtr @ cho_solve(cho_factor(jtj), jtr))
    except ValueError:  # not positive definite, or non-finite: the minimum is not located
        return f"{message}; its normal equations are singular there: no minimum located"
    steps = np.sqrt(max(drop, 0.0) / max(chi2 / dof, 1e-300))  # the step's size in standard errors
    if drop <= AT_LIMIT_TOL * chi2 / dof:
        return (f"at its minimum, stopped at the evaluation limit ({message}): the next Gauss-Newton step moves it "
                f"{steps:.2g} standard errors and removes {drop:.2g} of chi-square {chi2:.6g}")
    return (f"{message}; the next Gauss-Newton step would still move it {steps:.3g} standard errors (chi-square "
            f"{chi2:.6g} less {drop:.3g})")


def robust_rows(n: int) -> slice:
    """Every ``ceil(n / ROBUST_ROWS)``-th row: at most :data:`ROBUST_ROWS` of ``n``, spread over the recording."""
    return slice(None, None, max(-(-n // ROBUST_ROWS), 1))


def _robust_start(ellipsoid, y, p0, trim: bool = True):
    """Robust fits (on :func:`robust_rows`) and the trimming: the plain fit's start and inliers (None unless
    ``trim``: the trimming over every row is left out for a kind whose inliers are not used); normalised units."""
    # only the parameters are kept from the robust fits: their results hold an (n, k) Jacobian each
    thin = y[robust_rows(len(y))]
    first_x = least_squares(radial_residual, p0, jac=radial_jacobian, args=(ellipsoid, thin), loss="soft_l1",
                            f_scale=0.02, method="trf", tr_solver="lsmr", max_nfev=MAX_NFEV).x
    sigma = max(robust_sigma(radial_residual(first_x, ellipsoid, thin)), 1e-9)
    start = least_squares(radial_residual, first_x, jac=radial_jacobian, args=(ellipsoid, thin), loss="soft_l1",
                          f_scale=2.0 * sigma, method="trf", tr_solver="lsmr", max_nfev=MAX_NFEV).x
    if not trim:
        return start, None
    r = radial_residual(start, ellipsoid, y)
    sigma = max(robust_sigma(r), 1e-9)
    return start, np.abs(r - np.median(r)) < OUTLIER_SIGMAS * sigma


def _algebraic_start(x: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the linear least-squares sphere ``|x|^2 = 2 c.x + k``."""
    design = np.column_stack([2.0 * x, np.ones(len(x))])
    sol, *_ = np.linalg.lstsq(design, np.sum(x**2, axis=1), rcond=None)
    centre = sol[:3]
    return centre, float(np.sqrt(max(sol[3] + centre @ centre, 1e-30)))


def fit_covariance(res, n_obs: int) -> np.ndarray:
    """Parameter covariance from :func:`plain_fit`'s ``J^T J``, scaled by the reduced chi-square (inf if singular)."""
    k = len(res.x)
    if np.linalg.cond(res.jtj) > 1e12:
        return np.full((k, k), np.inf)
    return np.linalg.inv(res.jtj) * res.chi2 / max(n_obs - k, 1)


def propagate(ellipsoid, p, cov, centre, radius):
    """Standard errors of h, S (det 1) and F from the covariance of the normalised parameters."""
    k = _N_PARAMS[ellipsoid]
    h, s, f_norm = _unpack(ellipsoid, p, centre, radius)
    sig_h = radius * np.sqrt(np.clip(np.diag(cov)[:3], 0.0, None))
    grads_s, grads_f = np.empty((9, k)), np.empty(k)
    for j in range(k):
        step = np.zeros(k)
        step[j] = 1e-6
        _, s_j, f_j = _unpack(ellipsoid, p + step, centre, radius)
        grads_s[:, j] = (s_j - s).ravel() / 1e-6
        grads_f[j] = (f_j - f_norm) / 1e-6
    cov = cov[:k, :k]
    with np.errstate(invalid="ignore"):
        sig_s = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", grads_s, cov, grads_s), 0.0, None)).reshape(3, 3)
        sig_f = float(np.sqrt(max(grads_f @ cov @ grads_f, 0.0)))
    return h, sig_h, s, sig_s, f_norm, sig_f


def _ellipsoid_fit(ellipsoid, x, y, centre, radius, p0, inliers) -> EllipsoidFit:
    """The plain fit of one kind on ``inliers`` from ``p0`` (normalised units), in recording units."""
    res = plain_fit(radial_residual, p0, radial_jacobian, args=(ellipsoid, y[inliers]), normal=radial_normal)
    h, sig_h, s, sig_s, f_norm, sig_f = propagate(ellipsoid, res.x, fit_covariance(res, int(np.count_nonzero(inliers))),
                                                   centre, radius)
    resid_all = row_norms((x - h) @ s.T) - f_norm
    return EllipsoidFit(ellipsoid, h, sig_h, s, sig_s, f_norm, sig_f, resid_all, inliers, float(np.sum(resid_all[inliers] ** 2)),
                   np.nan, True, "", bool(res.success), res.message, res.x, centre, radius)


def fit_ellipsoid(mag: np.ndarray, ellipsoid: str = "auto") -> tuple[EllipsoidFit, tuple, Coverage]:
    """Fit the ellipsoid kinds and choose one.

    Parameters
    ----------
    mag : ndarray, shape (n, 3)
        Raw magnetometer samples (repeats removed), recording units, magnetometer frame.
    ellipsoid : {"auto", "offset", "diagonal", "full"}
        ``auto`` takes the determined kind with the lowest BIC; a named kind is fitted as asked
        (the result warns through ``determined`` when the data do not support it).

    Returns
    -------
    chosen : EllipsoidFit
    candidates : tuple of EllipsoidFit
        The kinds fitted, simplest first, with BIC on a common sample set.
    coverage : Coverage
        Of the field directions about the offset-only centre.

    Raises
    ------
    ValueError
        ``ellipsoid`` unknown, or fewer samples than the full kind's parameters.
    """
    if ellipsoid not in ("auto",) + ELLIPSOIDS:
        raise ValueError(f"ellipsoid must be 'auto' or one of {ELLIPSOIDS}, got {ellipsoid!r}")
    x = np.asarray(mag, dtype=float)
    if len(x) < 12:
        raise ValueError(f"a tumble calibration needs at least 12 samples, got {len(x)}")
    centre, radius = _algebraic_start(x)
    y = (x - centre) / radius
    names = ELLIPSOIDS if ellipsoid == "auto" else ELLIPSOIDS[: ELLIPSOIDS.index(ellipsoid) + 1]

    # each kind's robust fit starts from the previous one's; the most flexible kind's trimming sets the common
    # samples, on which every kind's plain fit is made (once: a plain fit on a kind's own inliers would be
    # refitted on the common ones)
    starts = []
    p = np.zeros(4)
    for name in names:
        if starts:
            low = shape_matrix(names[len(starts) - 1], starts[-1][0][3:])
            p = np.concatenate([starts[-1][0][:3], _shape_params(name, low @ low.T)])
        starts.append(_robust_start(name, y, p, trim=name == names[-1]))
    common = starts[-1][1]
    fits = [_ellipsoid_fit(name, x, y, centre, radius, start, common) for name, (start, _) in zip(names, starts)]
    coverage = sphere_coverage(x[common] - fits[0].hard_iron)
    n = int(np.count_nonzero(common))
    extent = float(np.percentile(row_norms(x[common] - np.median(x[common], axis=0)), 95))
    final = []
    for fit in fits:
        bic = n * np.log(fit.rss / n) + fit.n_params * np.log(n)
        rel = max(np.max(fit.hard_iron_sigma) / fit.field_norm, np.max(fit.soft_iron_sigma),
                  fit.field_norm_sigma / fit.field_norm)
        reason = ""
        degenerate = not fit.field_norm <= MAX_RADIUS_RATIO * extent
        if degenerate:
            reason = (f"degenerate: a sphere of radius {fit.field_norm:.4g} ({fit.field_norm / max(extent, 1e-300):.3g} "
                      f"times the samples' extent {extent:.4g}) with hard iron {np.linalg.norm(fit.hard_iron):.4g}; "
                      "the samples lie on no ellipsoid around the device: the field changed during the recording "
                      "(a magnet or magnetised part attached or moved partway) or the device barely turned")
        elif not np.isfinite(rel) or rel > MAX_RELATIVE_SIGMA:
            reason = (f"standard errors up to {100 * rel:.2g} % of the field" if np.isfinite(rel)
                      else "singular covariance")
        elif fit.ellipsoid != "offset" and coverage.missing:
            reason = f"the field was never along {', '.join(coverage.missing)}"
        final.append(replace(fit, bic=float(bic), determined=not reason, reason=reason, degenerate=degenerate))
    if ellipsoid != "auto":
        return final[-1], tuple(final), coverage
    usable = [f for f in final if f.determined] or final[:1]
    return min(usable, key=lambda f: f.bic), tuple(final), coverage


def sym_sqrt(ellipsoid, p_shape):
    """Symmetric positive-definite ``A`` with ``A^2 = L L^T`` (the calibration's shape, normalised units)."""
    low = shape_matrix(ellipsoid, p_shape)
    w, v = np.linalg.eigh(low @ low.T)
    return (v * np.sqrt(w)) @ v.T
