r"""Gyro-aided tumble calibration: the turns the gyro measured between samples pin what |m| alone cannot.

Model (maximum likelihood in the spirit of Kok and Schon, "Magnetometer calibration using inertial
sensors", IEEE Sensors J. 16(14), 2016), in the housing frame H (the accelerometer's and the gyro's,
one IMU), NWU world (SPEC section 1):

.. math:: x_k = D\,u_k + h + e_k, \qquad u_k = R_k^T b_W, \qquad b_W = (\cos\delta, 0, -\sin\delta),

.. math:: \hat a_k = R_k^T \hat z + f_k \quad (\text{still rows}), \qquad
          R_k = Q_j\,\Delta R_k(\beta, G), \quad \Delta R_k = \prod_{i \in j,\, i \le k} \mathrm{Exp}\big(G\,(\phi_i - \beta\,\Delta t_i)\big),

with ``x_k`` the raw magnetometer (recording units; with a latency ``tau`` against the gyro it reads
``u(t_k - tau) = (I + tau [w_k]x) u_k`` to first order, ``w_k`` the gyro's rate less its bias, and
``tau`` is fitted, see "Latency" below), ``D = F (C S)^{-1}`` its whole response (soft
iron ``S``, symmetric, det 1; ``C`` = ``mag_to_accel``; ``F`` = |B| in recording units: ``D`` has 9
free numbers and no gauge, the field ``b_W`` being a unit vector), ``h`` the hard iron, ``delta`` the
dip, ``phi_i`` the gyro's turn over the rows up to sample ``i`` (:func:`compass.io.tumble.gyro_turns`, the
gyro's frame and scale), ``beta`` its bias (rad/s, in the gyro's reading, fitted), ``G`` (3 x 3, 9 numbers, fitted
about the identity) the gyro's scale and axis errors against the housing (the accelerometer's frame): the
housing's rate is ``G (w - beta)``, ``w`` the reading (a gyro reading ``w = G^-1 w_true + beta``), and ``Q_j = R_world<-housing`` at the start of window ``j``
(its heading free, its tilt pinned by the accelerometer).  ``e_k`` is white magnetometer noise
(sigma from second differences), ``f_k`` the accelerometer direction's noise and hand motion (robust
sigma); the loss is the sum of both, weighted, robust (``soft_l1``) then plain on the inliers.

What the data determine (derivation; checked numerically by the Jacobian's rank in
``tests/calibrate/tumble/test_gyro.py``).  The ellipsoid sees only ``|C S (x - h)| = F``, which
is unchanged by ``C S -> P C S`` for any rotation ``P``: the rotation to the housing is invisible
to it, and ``S`` is determined only where the field's directions span the sphere (the present fit
needs every half-axis seen).  With the gyro, ``x_k - h = D \Delta R_k^T v_j`` (``v_j = Q_j^T b_W``):
a change ``D -> D P``, ``v_j -> P^T v_j`` that leaves every ``x_k`` unchanged needs ``P`` to commute
with every turn ``\Delta R_k``, and a change of ``h`` must be a constant ``D`` times field.  Hence:

- turns about two or more non-parallel axes, of any size: ``P = I``; all of ``D`` (the soft iron
  *and* the rotation to the housing) and ``h`` are determined, however small the fraction of the
  sphere the field swept - their precision grows with the angles turned;
- turns about one housing axis ``n`` only (a level robot joint, a swing): ``u_k = (v.n) n +
  Rot(n, -theta_k) v_perp``, so ``x_k = [h + (v.n) D n] + D Rot(n, -theta_k) v_perp``, and five
  combinations stay undetermined: ``D n`` (the response to the field along the turn axis, 3 numbers)
  against the hard iron; the size of ``D`` across ``n`` against ``|v_perp|`` (the field's angle to
  ``n``, 1: only their product appears); and ``P = Rot(n, phi)``, which commutes with every turn
  (the rotation to the housing about ``n``, 1; with gravity it trades against the dip).  ``D``'s
  shape across ``n`` is determined.  This is what the words then name as undetermined;
- no turn: nothing beyond the present fit.

Gyro errors.  Integrating the gyro accumulates its errors: the bias is fitted (a constant bias
error ``d beta`` turns ``R_k`` by ``d beta t``), and so are the scale and axis errors ``G`` (a low-cost
IMU's: the MPU-9250's sensitivity tolerance is +-3 %, its cross-axis sensitivity +-2 %), which turn ``R_k``
by ``dG`` times the angle turned.  What the turns determine of ``G`` (derivation, checked by the Jacobian's rank
without ``G``'s prior in ``tests/calibrate/tumble/test_gyro.py``): a turn about the housing axis ``n`` exercises
only ``G n``; its component along ``n`` (the scale) is the turn's angle, which the field and gravity see, and its
components across ``n`` tilt the turn's axis, which gravity sees (and the field, through ``D``).  So turns about
every axis determine all 9 numbers, turns about two (``n1``, ``n2``) the 6 of ``G n1``, ``G n2`` (``G`` across both,
3 numbers, is never exercised), a turn about one axis 3 (6 left).  A rotation of the gyro's frame against the
housing (``G``'s antisymmetric part) is not absorbed by the windows' free orientations: gravity in the housing frame
pins them.  ``G`` against the bias: the bias turns by ``d beta t``, ``G`` by ``dG`` times the angle, told apart
when the rate varies (a constant spin about ``n`` cannot tell the scale along ``n`` from the bias along ``n``).
``G`` against the latency: the latency follows the instantaneous rate, ``G`` the integrated turn.  A Gaussian prior
(:data:`GYRO_MATRIX_PRIOR`: 3 % on the diagonal, 2 % across, the datasheet's tolerances) keeps what the turns do not
see at the identity, its sigma at the prior's; the runtime (``--gyro-matrix``, off by default: on BROAD the
matrix fitted on one trial cost the others, docs/benchmarks.md) applies only the entries the data saw off the
identity (beyond 3 sigmas, the sigma under 0.5 %), and never one beyond 3 prior sigmas, a model mismatch
(:func:`compass.calibration.gyro_matrix_seen`).  What stays unmodelled (a bias that wanders, an accelerometer's own
scale errors, which tilt gravity unevenly) grows with the angle turned and the time.
Each window restarts the integration with its own ``Q_j``: a window closes after
:data:`WINDOW_TURN_DEG` of turn or :data:`WINDOW_S` seconds, and before any step over :data:`GAP_S` (a
restart, lines lost, a pause: the gyro's rate times the gap is not the turn made, so none is integrated
across it; :func:`still_mask` compares rows within :data:`STILL_WINDOW_S`, which no such step fits in), so
a 1 % scale error costs at most
~0.6 deg of orientation inside a window if it were not fitted (an 0.3 uT noise on a 50 uT field is 0.34 deg
per sample),
while each window still holds turns large enough to see the rotation between the sensors.  The
windows keep the information that ties them together: one field (``|B|``, dip) and the gravity of
every still row (:func:`still_mask`: ``|a|`` near g and the direction still once the gyro's turns
are taken out, not a robot's moves, whose tilt would read as a turn the gyro did not make).

Latency.  A magnetometer ``tau`` late reads the housing-frame field of ``t - tau``; turning at ``w``
the housing sees it turned back by ``tau w``: ``x_k = D (u_k + tau w_k x u_k) + h``.  ``|x - h|``
through ``D^-1`` is unchanged, so the ellipsoid cannot see ``tau``; the turns can, and nothing else
in the model mimics it: the regressor ``D (w_k x u_k)`` follows the *instantaneous* rate, while a
change of ``D`` follows ``u_k``, the gyro bias the *integrated* turn, a window's orientation a
constant.  It is determined whenever the rate varies (``sigma_tau ~ sigma_m / (|B| rms|w_perp| sqrt n)``);
a prior of :data:`LATENCY_PRIOR_S` keeps it defined when the housing hardly turns.  Left out, it
goes where it can: on a simulated full tumble 20 ms late the hard iron moved 0.42 % of |B| and the
residual rose from 0.30 to 0.74 uT; fitted, the latency came back at 19.98 +/- 0.05 ms (BROAD: 12.7 ms,
on trials 01 and 06 alike).  The first-order form leaves ``(tau |w|)^2 / 2`` of the field: 0.2 % at
20 ms and 4 rad/s.

Cost.  ``n`` rows (``n_s`` of them still), ``n_w`` windows (a fast recording closes one every
60 deg: 482 on BROAD 06's 125 s, 1151 on a simulated 300 s fast rotation), 26 global parameters
(``D``, ``h``, ``delta``, ``beta``, ``tau``, ``G``; 17 before ``G``) and 3 per window.  The joint least squares over all
``17 + 3 n_w`` (1463 on BROAD 06) with scipy's ``trf`` and ``lsmr`` on the sparse Jacobian took ~40
outer iterations per pass, each an ``lsmr`` solve of ~120 sparse products on ``3 (n + n_s)`` rows, the
prefix products and the Jacobian recomputed on every row each time; 10-40 s of CPU on BROAD 06's
8755 rows, minutes on 35000.  The windows' orientations enter each window's rows only, so they are
projected out (:class:`_Problem`): the outer least squares sees the 26 globals and a dense ``m x 26``
reduced Jacobian (analytic: the chain rule through the prefix products, ``G_k``, then the projection);
each window's orientation is solved inside by Newton steps on its own 3 x 3 problem, which for the
plain loss is a quadratic form of per-window sums formed once per outer evaluation (a step costs
nothing per row).  Per outer evaluation: the prefix products ``O(n log L)`` (``L`` the longest
window's rows), the sums and the Jacobian ``O(26 n)``.  The robust (``soft_l1``) fit needs the rows'
weights at every window step, so it runs on at most :data:`ROBUST_ROWS` rows (every ``k``-th of each
window): it only starts the plain fit and sets the outlier test, which judges every row with every
window's orientation solved on all its rows.  The plain fit (Gauss-Newton on the 26 x 26 normal
equations, :func:`calibrate.tumble.ellipsoid.plain_fit`) uses every inlier: its Cramer-Rao bound is
the whole recording's, unchanged by the thinning (``tools/bench_gyro_tumble.py --timing``: the
parameters within 0.002 sigma of the joint fit's on simulated recordings, 0.05 sigma on BROAD 06's every
4th row; on its every 2nd row, where the trim removes 5 %, the two keep different border samples and
differ by 0.3 sigma, each the plain optimum of its own samples).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import sparse
from scipy.linalg import polar
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.special import chdtri

from compass.calibration import MAX_GYRO_MATRIX_ERROR, gyro_matrix_mismatch, gyro_matrix_seen, latency_seen
from compass.filter import FilterConfig

from ..diagnosis.blocks import TIME_BLOCKS, time_blocks, widened_in_time
from ..diagnosis.robust import extra_sigma
from ..diagnosis.forms import json_float
from ..noise import robust_sigma, second_difference_sigma, second_differences
from .alignment import Misalignment, field_gravity_angles, static_mask
from .diagnosis import NOT_CONVERGED_WARNING, UNEXPLAINED_WARNING, diagnose_tumble, unexplained_cost as diagnosis_cost
from .ellipsoid import MAX_RELATIVE_SIGMA, OUTLIER_SIGMAS, EllipsoidFit, plain_fit
from .motion import FAST_MOTION_WARNING
from .result import TumbleResult

__all__ = ["GyroFit", "GyroMismatch", "falls_back", "fit_with_gyro", "with_gyro", "still_mask", "turn_axes",
           "turn_rates", "GAP_S", "GYRO_MATRIX_PRIOR", "LATENCY_PRIOR_S", "WINDOW_S", "WINDOW_TURN_DEG",
           "MAX_ROTATION_SIGMA_DEG", "STILL_WINDOW_S", "STILL_PROBABILITY"]

WINDOW_S = 10.0
"""A window of integrated gyro turns closes after this long, s."""

WINDOW_TURN_DEG = 60.0
"""... or after the housing turned this much since the window's start, deg."""

GAP_S = FilterConfig.max_gap_s
"""A step between samples longer than this is a gap (the runtime filter's ``max_gap_s``, 0.5 s, beyond which it
restarts): across it the gyro's ``rate x step`` is not the turn made (a restart of the module's clock, lines lost on a
stream without one, a pause in the recording), so a window closes there (:func:`_windows`) and the rate at a sample
beside it is taken from its other side (:func:`turn_rates`)."""

MIN_WINDOW_SAMPLES = 5

MAX_ROTATION_SIGMA_DEG = 0.5
"""The rotation to the housing is determined when each component's sigma is below this, deg."""

MAX_NFEV = 100

ROBUST_F_SCALE = 3.0
"""The robust fit's ``soft_l1`` scale, noise sigmas."""

ROBUST_ROWS = 4000
"""About the most samples the robust fit uses (every ``k``-th of each window): it gives the plain fit its start and the
outlier test its parameters, which then judges every sample, each window's orientation solved on all its rows;
the plain fit uses every sample kept (:func:`_robust_rows`)."""

LATENCY_PRIOR_S = 0.05
"""Prior sigma of the magnetometer's latency against the gyro, s: a loose bound (real boards: 0-30 ms)
that keeps the latency defined when the housing hardly turned, where the data cannot see it."""

_FIXED_S = 1e-9
"""The prior sigma that holds the latency at zero (``fit_latency=False``), s."""

GYRO_SCALE_PRIOR = 0.03
"""Prior sigma of each of the gyro matrix's diagonal entries (``G - I``): the MPU-9250's sensitivity scale
factor tolerance, +-3 % at 25 C (InvenSense PS-MPU-9250A-01 rev 1.1, table 1)."""

GYRO_CROSS_PRIOR = 0.02
"""Prior sigma of each off-diagonal entry: the same sheet's cross-axis sensitivity, +-2 %."""

GYRO_MATRIX_PRIOR = np.where(np.eye(3, dtype=bool), GYRO_SCALE_PRIOR, GYRO_CROSS_PRIOR).ravel()
"""Prior sigma of ``G - I``, row-major (9): what the data do not determine stays at the identity."""

_FIXED_GYRO = np.full(9, 1e-9)
"""The prior sigma that holds ``G`` at the identity (``fit_gyro_matrix=False``)."""

STILL_WINDOW_S = 0.5
"""The window (centred, s) over which a gravity row's direction, carried by the gyro, must hold still
(:func:`still_mask`): a few of a robot's moves' time scales (1-3 s moves) and shorter than its dwells."""

MIN_SIGMA_A = 1e-4
"""The least noise an accelerometer's direction is given, rad (a noise-free simulation's)."""

STILL_PROBABILITY = 0.99
"""A row is still when its window's chi-square is below this quantile of the noise's (:func:`still_mask`)."""

ACCEL_WINDOW_FACTOR = 3.0
"""The accelerometer's held parameters (:func:`with_gyro`) are fitted with windows this many times longer
(:data:`WINDOW_TURN_DEG`, :data:`WINDOW_S`).  Each window's orientation is a nuisance parameter: with the default
windows the offset along a robot cap's axis came out biased by the magnetometer's noise (Neyman and Scott's
problem: on robot paths without lever arm or flange translation, bad-accel seeds 60, 61, 62, 64, by -1.29, -0.45,
-0.57, -0.20 m/s^2 at 5-12 stated sigmas; -0.09, -0.19, -0.12, -0.01 with windows three times as long; with the
magnetometer's noise 0.1 uT instead of 0.7 the bias fell 25 times).  The gyro matrix is fitted afterwards with the
default windows on the corrected rows, as without a held parameter."""

ACCEL_SEEN_SIGMAS = 5.0
"""A held parameter fitted beside (:data:`ACCEL_WINDOW_FACTOR`) is applied when this many of its stated sigmas off
zero, and stays held otherwise.  The stated sigma is the still rows' white scatter's and does not hold what remains of
the windows' bias: on development paths 60-69 the low-cost board's offset along the cap's axis came out 3.3 of them
off (seed 66: -0.053 +/- 0.013 against -0.010 m/s^2), and with 3 (the accelerometer's own
:data:`~calibrate.tumble.accelerometer.SEEN_SIGMAS`) applied, the board's corrected direction's error rose 0.218 ->
0.260 deg (``tools/bench_accel_fit.py``)."""

ACCEL_PIN_FLOOR = 0.05
"""A held parameter fitted beside is applied only when it moves the reading of 1 g by more than this fraction of g
(an offset over ``one_g``, a scale as it is), besides :data:`ACCEL_SEEN_SIGMAS`.  What remains of the windows' bias
(:data:`ACCEL_WINDOW_FACTOR`) is systematic: on development paths 60-69 the low-cost board's offset along the cap's
axis (truth within +-0.11 m/s^2) came out -0.003 to -0.275 m/s^2, every one negative, seeds 66 and 69 at 5.5 and 6.6
stated sigmas, and applied there it cost the filter's heading (``tools/bench_robot.py --first-seed 65``: seed 66 2.72
-> 2.89 deg, 69 0.88 -> 1.26).  0.05 g is about a MEMS accelerometer's zero-g tolerance (MPU-9250: +-60 mg across,
+-80 mg along z): below it a pin is not told from that bias.  The bad-accel board's values on 60-69, 0-4 and 100-104
read 0.83-2.4 m/s^2 (0.08-0.24 g), all applied as before, and 0.48 on seed 2 (4.8 sigmas: held either way)."""

MIN_INLIER_FRACTION = 0.5
"""A fit that keeps fewer of the samples says the model does not hold (:class:`GyroMismatch`)."""


class GyroMismatch(ValueError):
    """The gyro-aided model does not describe the recording (most samples rejected), in words."""


_AXES = "xyz"


@dataclass(frozen=True)
class GyroFit:
    """The gyro-aided fit of a tumble.

    Attributes
    ----------
    hard_iron, hard_iron_sigma : ndarray, shape (3,)
        Recording units.
    soft_iron, soft_iron_sigma : ndarray, shape (3, 3)
        ``S``, symmetric, det 1 (the calibrated field in recording units is ``S (x - h)``).
    field_norm, field_norm_sigma : float
        ``F``, recording units.
    mag_to_accel : Rotation
        ``C``: calibrated magnetometer frame -> housing (accelerometer and gyro) frame.
    rotvec_deg, rotvec_sigma_deg : ndarray, shape (3,)
    dip_deg, dip_sigma_deg : float
    gyro_bias_rad_s, gyro_bias_sigma_rad_s : ndarray, shape (3,)
    latency_s, latency_sigma_s : float
        How late the magnetometer reads against the gyro, s (> 0: it reads the field of ``t - tau``).
    gyro_matrix, gyro_matrix_sigma : ndarray, shape (3, 3)
        ``G``: the housing-frame rate is ``G (w - beta)``, ``w`` the gyro's reading (dimensionless); the
        prior's sigma where the data saw nothing.
    n_windows, n_static : int
        Windows of integration; still accelerometer rows used (:func:`still_mask`).
    inliers : ndarray of bool, shape (n,)
        Samples kept after trimming (magnetometer residual within ``OUTLIER_SIGMAS``).
    mag_rms, noise : float
        Rms of the magnetometer residual per axis over the inliers, and the white-noise sigma it is
        weighed against (recording units).
    undetermined : tuple of str
        Parameters whose sigma exceeds the limits (:data:`calibrate.tumble.MAX_RELATIVE_SIGMA` of
        the field, :data:`MAX_ROTATION_SIGMA_DEG`), in words; empty when the fit is determined.
    turns : str
        How the housing turned (:func:`turn_axes`), in words.
    success : bool
    message : str
    accel, accel_sigma : ndarray, shape (k,)
        The accelerometer's parameters fitted beside (``accel_change`` of :func:`fit_with_gyro`; empty without).
    params : ndarray, shape (26 + k,) or None
        The global parameters (:class:`_Problem`: ``D`` row-major, ``h``, ``delta`` rad, ``beta`` rad/s, ``tau`` s,
        ``G - I`` row-major, the accelerometer's ``c``).
    covariance : ndarray, shape (26 + k, 26 + k) or None
        Their covariance, the windows' orientations marginalised (the sigmas above; None: singular).
    widened_covariance : ndarray, shape (26 + k, 26 + k) or None
        The same grown to cover structure in the residual that changes with time (:func:`_widened_covariance`): what
        :meth:`widened` states when the diagnosis finds the residual unexplained.
    """

    hard_iron: np.ndarray
    hard_iron_sigma: np.ndarray
    soft_iron: np.ndarray
    soft_iron_sigma: np.ndarray
    field_norm: float
    field_norm_sigma: float
    mag_to_accel: Rotation
    rotvec_deg: np.ndarray
    rotvec_sigma_deg: np.ndarray
    dip_deg: float
    dip_sigma_deg: float
    gyro_bias_rad_s: np.ndarray
    gyro_bias_sigma_rad_s: np.ndarray
    latency_s: float
    latency_sigma_s: float
    gyro_matrix: np.ndarray
    gyro_matrix_sigma: np.ndarray
    n_windows: int
    n_static: int
    inliers: np.ndarray
    mag_rms: float
    noise: float
    undetermined: tuple
    turns: str
    success: bool
    message: str
    accel: np.ndarray = field(default_factory=lambda: np.zeros(0))
    accel_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))
    params: np.ndarray | None = None
    covariance: np.ndarray | None = None
    widened_covariance: np.ndarray | None = None

    def widened(self) -> "GyroFit":
        """This fit with the magnetometer's sigmas from :attr:`widened_covariance` (the parameters, and what is
        determined, as they are: the widening covers structure the model lacks, it adds no information); itself
        without one.

        The gyro's own sigmas (bias, latency, matrix) and the accelerometer's stay the naive ones: the structure is
        the field's (``|m| - F``, :func:`calibrate.tumble.diagnosis.diagnose_tumble`), and the runtime reads the gyro
        block's sigmas as the gyro's scale error (:func:`compass.calibration.gyro_scale_error`), which a widening
        here would change in the filter without a benchmark of it."""
        if self.params is None or self.widened_covariance is None:
            return self
        wide = _sigmas(self.params, self.widened_covariance)
        return replace(self, covariance=self.widened_covariance,
                       **{k: v for k, v in wide.items() if k in _MAGNETIC_SIGMAS})

    @property
    def latency_known(self) -> bool:
        """Whether the data saw a latency: beyond 3 sigma of zero, and the sigma well inside the prior
        (:func:`compass.calibration.latency_seen`, the rule the runtime reads the file's latency by)."""
        return latency_seen(self.latency_s, self.latency_sigma_s)

    @property
    def determined(self) -> bool:
        return self.success and not self.undetermined

    @property
    def gyro_matrix_usable(self) -> bool:
        """Whether the fitted gyro matrix goes into the file: every sigma given and every entry of ``G - I`` within
        :data:`compass.calibration.MAX_GYRO_MATRIX_ERROR` (a fit that wandered where the turns saw nothing, as a
        translation, is neither; the reader would refuse it)."""
        return bool(np.all(np.isfinite(self.gyro_matrix_sigma))
                    and np.all(np.abs(self.gyro_matrix - np.eye(3)) <= MAX_GYRO_MATRIX_ERROR))

    def to_json(self) -> dict:
        """The file's ``tumble.gyro`` block (JSON-ready; ``gyro_matrix`` null when not :attr:`gyro_matrix_usable`)."""
        usable = self.gyro_matrix_usable
        return {"method": "gyro", "n_windows": self.n_windows, "window_s": WINDOW_S, "window_turn_deg": WINDOW_TURN_DEG,
                "gyro_bias_rad_s": self.gyro_bias_rad_s.tolist(),
                "gyro_bias_sigma_rad_s": [json_float(v) for v in self.gyro_bias_sigma_rad_s],
                "mag_latency_s": self.latency_s, "mag_latency_sigma_s": json_float(self.latency_sigma_s),
                "gyro_matrix": self.gyro_matrix.tolist() if usable else None,
                "gyro_matrix_sigma": [[json_float(v) for v in row] for row in self.gyro_matrix_sigma] if usable else None,
                "mag_residual_rms": self.mag_rms, "noise": self.noise, "n_static": self.n_static,
                "n_outliers": int(np.count_nonzero(~self.inliers)), "turns": self.turns,
                "undetermined": list(self.undetermined), "words": self.words()}

    def _latency_words(self) -> str:
        """The fitted latency, when the data saw one; the runtime filter can only delay the gyro's side."""
        if not self.latency_known:
            return ""
        ms = f"{1e3 * abs(self.latency_s):.1f} +/- {1e3 * self.latency_sigma_s:.1f} ms"
        if self.latency_s > 0:
            return f"; the magnetometer {ms} late against the gyro, fitted: the runtime filter's mag_latency_s"
        return (f"; the magnetometer {ms} early against the gyro (the gyro is the late one), fitted: "
                "the runtime filter's mag_latency_s cannot compensate it")

    def _gyro_matrix_words(self) -> str:
        """The gyro's scale and axis errors the data saw (:func:`compass.calibration.gyro_matrix_seen`, the rule the
        runtime reads the file's matrix by), the entries that are a model mismatch
        (:func:`compass.calibration.gyro_matrix_mismatch`: never applied), and the turn axes whose response it did
        not see."""
        usable = self.gyro_matrix_usable
        seen = gyro_matrix_seen(self.gyro_matrix, self.gyro_matrix_sigma) & usable
        error = 100 * (self.gyro_matrix - np.eye(3))
        mismatch = gyro_matrix_mismatch(self.gyro_matrix) & usable
        odd = "".join(f"; a model mismatch in the gyro matrix: {_AXES[i]}{_AXES[j]} {error[i, j]:+.2f} % is beyond 3 "
                      "of the prior's sigmas (its datasheet tolerance), the fit took up what its model leaves out: "
                      "not applied" for i, j in zip(*np.nonzero(mismatch)))
        if not seen.any():
            return odd + "; the gyro's scale and axes not seen off the identity: the runtime leaves the gyro as read"
        scale = ", ".join(f"{error[i, i]:+.2f}" if seen[i, i] else "unseen" for i in range(3))
        cross = np.abs(error[seen & ~np.eye(3, dtype=bool)])
        sigma = 100 * np.max(self.gyro_matrix_sigma[seen])
        words = (odd + f"; the gyro's scale x, y, z {scale} % (max sigma {sigma:.2f} %)"
                 + (f", its axes off by up to {np.max(cross):.2f} %" if cross.size else "")
                 + ", fitted: the runtime applies it only with --gyro-matrix (off by default: on BROAD's real "
                 "recordings it did not carry over, docs/benchmarks.md)")
        unseen = [_AXES[j] for j in range(3) if not seen[:, j].any()]
        return words + (f" (turns about {', '.join(unseen)} not seen: left as read)" if unseen else "")

    def words(self) -> str:
        """What the gyro-aided fit determined, for the coverage words."""
        base = (f"with the gyro's turns ({self.turns}; {self.n_windows} windows of integration, gyro bias "
                + ", ".join(f"{np.degrees(b):+.3f}" for b in self.gyro_bias_rad_s) + " deg/s"
                + self._latency_words() + self._gyro_matrix_words() + ")")
        if self.determined:
            return base + ": the soft iron and the rotation to the housing are determined"
        if self.undetermined:  # said first: a fit that wandered along what the data leave free fails too
            return base + ": still undetermined: " + "; ".join(self.undetermined)
        return base + f": the fit did not converge ({self.message})"


def turn_axes(turns_rad: np.ndarray) -> str:
    """How the housing turned, in words, from the gyro's turns (rad, housing frame, shape (n, 3)).

    The principal axes of ``sum phi phi^T``: one axis carrying nearly all the turning (the other
    two below 1 % of it in angle squared) is "about one axis only".
    """
    phi = np.asarray(turns_rad, float)
    w, v = np.linalg.eigh(phi.T @ phi)
    total = float(np.degrees(np.sum(np.linalg.norm(phi, axis=1))))
    main = v[:, -1] * np.sign(v[np.argmax(np.abs(v[:, -1])), -1])
    if w[1] < 1e-2 * w[2]:
        return (f"turned {total:.0f} deg in all, about one axis only, housing ({main[0]:+.2f}, {main[1]:+.2f}, "
                f"{main[2]:+.2f})")
    return f"turned {total:.0f} deg in all, about several axes"


def turn_rates(turns_rad: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """The gyro's rate at each sample (rad/s, housing frame, shape (n, 3)) from the turns between samples.

    ``turns_rad[k]`` covers ``(t_k-1, t_k]``; the rate at ``t_k`` is the mean over ``(t_k-1, t_k+1]``
    (centred; one-sided at either end and beside a step over :data:`GAP_S`, whose turn is the rate after the gap
    times its length, not the rate at ``t_k``; zero where no time passed).
    """
    turns, dt = np.asarray(turns_rad, float), np.asarray(dt_s, float)
    used = (dt <= GAP_S) & (np.arange(len(dt)) > 0)  # row 0's turn and the steps over a gap tell no rate
    turns, dt = np.where(used[:, None], turns, 0.0), np.where(used, dt, 0.0)
    span_turn = turns.copy()
    span_dt = dt.copy()
    span_turn[:-1] += turns[1:]
    span_dt[:-1] += dt[1:]
    return np.divide(span_turn, span_dt[:, None], out=np.zeros_like(span_turn), where=span_dt[:, None] > 0)


def still_mask(accel: np.ndarray, turns_rad: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    r"""Rows where the accelerometer reads gravity alone: :func:`~calibrate.tumble.alignment.static_mask`'s ``|a|``
    test, and its direction still over :data:`STILL_WINDOW_S` once the gyro's turns are taken out.

    A sideways acceleration ``a`` changes ``|a|`` by ``a^2 / 2g`` (0.5 % at 1 m/s^2, within the ``|a|`` test's 2 %)
    but tilts the direction by ``a / g`` (5.8 deg): a robot's moves pass the ``|a|`` test.  Gravity alone turns
    with the housing only, ``d a_hat / dt = -w x a_hat``, so carried by the gyro into one frame, ``R_j a_hat_j``
    (``R_j`` the gyro's orientation at row ``j``), it is constant.  Over the rows ``j`` within the window of row
    ``k`` the statistic is ``chi2_k = sum_j w_j |R_j a_hat_j - mean|^2`` (the weighted mean; 2 degrees of freedom a
    row less 2), with ``1 / w_j = sigma_a^2 + sigma_G^2 theta_jk^2``: ``sigma_a`` the accelerometer's white noise
    over ``|a|`` (rad, per axis, from second differences; at least :data:`MIN_SIGMA_A`), ``theta_jk`` the angle
    turned between the rows (rad, the gyro's path) and ``sigma_G^2 = (s^2 + 2 c^2) / 3`` what the gyro matrix's
    prior (scale ``s``, axes ``c``, :data:`GYRO_MATRIX_PRIOR`) turns a carried direction by, per axis and radian
    (a 60 deg turn: 1.4 deg).  A row is still when ``chi2_k`` is below the :data:`STILL_PROBABILITY` quantile
    of its chi-square times ``m``, the median over the rows of the ``|a|`` test of ``chi2_k`` over its chi-square's
    median (at least 1): a hand's small accelerations, which the fit weighs as the accelerometer's noise (its
    robust sigma), are the median, a robot's moves the tail (without ``m``, 26 of the 2678 rows of BROAD 01's
    slow rotation would stay; with it, 1991).  Numbers: noise of 0.005 g a row is 0.29 deg; 1 m/s^2 that comes or
    goes within the window tilts its rows by up to 5.8 deg, 400 times the noise's variance a row, far beyond the
    quantile (~70 for 24 rows at 48 Hz).  An acceleration that holds over the whole window tilts its rows alike
    and is not seen (a robot's minimum-jerk moves change theirs within a few tenths of a second); nor is the
    gyro's bias modelled (0.5 deg/s over the window: 0.13 deg).  The rows of a window span at most
    :data:`STILL_WINDOW_S`, no longer than :data:`GAP_S`: no direction is carried across a gap.

    Parameters
    ----------
    accel : ndarray, shape (n, 3)
        Accelerometer (specific force, +1 g up at rest), any unit, housing frame.
    turns_rad : ndarray, shape (n, 3)
        The gyro's turn from the previous row to each (rotation vector, rad, housing frame; row 0 ignored).
    t_s : ndarray, shape (n,)
        Time of each row, s, non-decreasing.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    accel, turns, t_s = (np.asarray(a, dtype=float) for a in (accel, turns_rad, t_s))
    n = len(accel)
    norm = np.linalg.norm(accel, axis=1)
    sigma_a = max(float(np.median(second_difference_sigma(second_differences(accel)))) / float(np.median(norm)),
                  MIN_SIGMA_A)
    step = turns.copy()
    step[0] = 0.0
    quat = Rotation.from_rotvec(step).as_quat()
    shift = 1
    while shift < n:  # R_j = Exp(phi_1) ... Exp(phi_j): the prefix products (Hillis-Steele scan)
        quat[shift:] = _qmul(quat[:-shift], quat[shift:])
        shift *= 2
    carried = Rotation.from_quat(quat).apply(accel / np.maximum(norm, 1e-300)[:, None])
    path = np.cumsum(np.linalg.norm(step, axis=1))
    var_g = (GYRO_SCALE_PRIOR**2 + 2.0 * GYRO_CROSS_PRIOR**2) / 3.0
    first = np.searchsorted(t_s, t_s - STILL_WINDOW_S / 2.0, side="left")
    last = np.searchsorted(t_s, t_s + STILL_WINDOW_S / 2.0, side="right") - 1
    rows = np.arange(n)
    s0, s1, count = np.zeros(n), np.zeros((n, 3)), np.zeros(n)
    for offset in range(int(np.min(first - rows)), int(np.max(last - rows)) + 1):
        j = rows + offset
        inside = (j >= first) & (j <= last)
        j = np.clip(j, 0, n - 1)
        w = np.where(inside, 1.0 / (sigma_a**2 + var_g * (path[j] - path) ** 2), 0.0)
        s0 += w
        s1 += w[:, None] * carried[j]
        count += inside
    chi2 = s0 - np.sum(s1**2, axis=1) / s0  # sum w |v|^2 - |sum w v|^2 / sum w, |v| = 1
    dof = np.maximum(2.0 * (count - 1.0), 1.0)
    static = static_mask(accel) & (count > 1)
    scale = max(float(np.median(chi2[static] / chdtri(dof[static], 0.5))), 1.0) if np.any(static) else 1.0
    return static & (chi2 <= scale * chdtri(dof, 1.0 - STILL_PROBABILITY))


def _windows(turns: np.ndarray, dt: np.ndarray, factor: float = 1.0) -> np.ndarray:
    """Index of the window of each sample: a window closes after ``factor`` times WINDOW_TURN_DEG or WINDOW_S (once it
    holds MIN_WINDOW_SAMPLES), and before any step over :data:`GAP_S`, however few samples it holds (the turn across a
    gap is unknown: the sample after it starts a window, whose first turn is not used)."""
    limit, longest = np.radians(factor * WINDOW_TURN_DEG), factor * WINDOW_S
    out = np.empty(len(turns), dtype=int)
    j, angle, time, count = 0, 0.0, 0.0, 0
    step = np.linalg.norm(turns, axis=1)
    for k in range(len(turns)):
        full = count >= MIN_WINDOW_SAMPLES and (angle + step[k] > limit or time + dt[k] > longest)
        if count and (dt[k] > GAP_S or full):
            j, angle, time, count = j + 1, 0.0, 0.0, 0
        elif count:
            angle, time = angle + step[k], time + dt[k]
        out[k] = j
        count += 1
    return out


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-last quaternions, shape (..., 4)."""
    px, py, pz, pw = np.moveaxis(p, -1, 0)
    qx, qy, qz, qw = np.moveaxis(q, -1, 0)
    return np.stack([pw * qx + px * qw + py * qz - pz * qy, pw * qy - px * qz + py * qw + pz * qx,
                     pw * qz + px * qy - py * qx + pz * qw, pw * qw - px * qx - py * qy - pz * qz], axis=-1)


def _skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` of each row, shape (..., 3, 3)."""
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def _so3_jacobian(phi: np.ndarray, sign: float) -> np.ndarray:
    """Right (``sign`` -1) or left (+1) Jacobian of SO(3) at each row of ``phi``, shape (..., 3, 3)."""
    theta = np.linalg.norm(phi, axis=-1)[..., None, None]
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)
    k = _skew(phi)
    return np.eye(3) + sign * a * k + b * (k @ k)


WINDOW_STEPS = 50
"""Most Newton steps of the windows' orientations for one set of global parameters."""

WINDOW_TOL_RAD = 1e-10
"""The windows' orientations are solved when no window's step turns it by more than this, rad."""

_HALVINGS = 30
_RCOND = 1e-10
"""A window's direction with less than this of its largest curvature is free (not moved, not counted)."""
_UP = np.array([0.0, 0.0, 1.0])


def _soft_l1_weights(r: np.ndarray, f_scale: float | None) -> tuple[np.ndarray, np.ndarray]:
    """(``rho'``, ``rho' + 2 z rho''``) of each residual for scipy's ``soft_l1`` loss, ``rho(z) = 2 (sqrt(1 + z) - 1)``,
    ``z = (r / f_scale)^2`` (``f_scale`` None: the plain loss, both 1).

    The first weighs the gradient and the residuals' curvature, the second the Gauss-Newton part of the
    Hessian: the curvature scipy's ``least_squares`` scales the Jacobian by.
    """
    if f_scale is None:
        return np.ones_like(r), np.ones_like(r)
    s = 1.0 / np.sqrt(1.0 + (r / f_scale) ** 2)
    return s, s**3


def _soft_l1_cost(r: np.ndarray, f_scale: float | None) -> np.ndarray:
    """``f_scale^2 rho((r / f_scale)^2)`` of each residual (scipy's ``soft_l1``; ``f_scale`` None: ``r^2``)."""
    if f_scale is None:
        return r**2
    return 2.0 * f_scale**2 * (np.sqrt(1.0 + (r / f_scale) ** 2) - 1.0)


@dataclass(frozen=True)
class _Rows:
    """What the rows need from the global parameters, the windows' orientations aside."""

    p: np.ndarray
    d: np.ndarray  # D, (3, 3)
    b_w: np.ndarray
    db_w: np.ndarray  # d b_W / d delta
    tau: float
    rel: np.ndarray  # Delta R_k, (n, 3, 3)
    psi: np.ndarray  # the raw turn less the bias, (n, 3) (zero at a window's first row)
    phi: np.ndarray  # G psi: the turn, (n, 3)
    gyro: np.ndarray  # G, (3, 3)
    rate_b: np.ndarray  # the raw rate less the bias, (n, 3)
    omega: np.ndarray  # G (rate - beta), (n, 3)
    resp: np.ndarray  # D M_k Delta R_k^T / sigma_m: the reading's response to the window's field Q_j^T b_W, (n, 3, 3)
    e: np.ndarray  # (x_k - h) / sigma_m, (n, 3)
    a_unit: np.ndarray  # the still rows' gravity direction f / |f|, f = a + (d a / d c) c, (n_s, 3)
    a_norm: np.ndarray  # |f|, (n_s,)


@dataclass(frozen=True)
class _Sums:
    """Each window's loss as a quadratic in its field ``v = Q^T b_W`` and gravity ``g = Q^T z`` (rows weighted by ``W``):
    ``c - 2 v.t + v^T s v - 2 g.u + g^T a g``."""

    s: np.ndarray  # sum resp^T W resp, (n_w, 3, 3)
    t: np.ndarray  # sum resp^T W e, (n_w, 3)
    a: np.ndarray  # sum Delta R W Delta R^T / sigma_a^2, (n_w, 3, 3)
    u: np.ndarray  # sum Delta R W a / sigma_a^2, (n_w, 3)


def _window_newton(q: np.ndarray, b_w: np.ndarray, grad: _Sums, gn: _Sums) -> np.ndarray:
    """Each window's Newton step ``d`` (n_w, 3; ``Q -> Exp(d) Q``) on the loss given by its sums.

    With ``b' = Exp(-d) b = b + b x d + (d (d.b) - b |d|^2) / 2`` to second order (world frame), the
    loss ``b'^T S b' - 2 b'.T`` (``S = Q s Q^T``, ``T = Q t``; the same for gravity) has the half
    gradient ``[b]x^T m``, ``m = S b - T``, and the half Hessian ``[b]x^T S [b]x + (m b^T + b m^T) / 2
    - (m.b) I``.  ``grad`` gives ``m`` and the gradient (weights ``rho'``), ``gn`` the Gauss-Newton part
    (``rho' + 2 z rho''``).  Where that Hessian has a negative curvature (far from the minimum) the
    window takes the reweighted Gauss-Newton step (``[b]x^T S [b]x`` of ``grad``); a direction its rows
    leave free is not moved (pseudo-inverse).
    """
    q_t = np.transpose(q, (0, 2, 1))
    h_gn = np.zeros((len(q), 3, 3))
    h = np.zeros((len(q), 3, 3))
    half = np.zeros((len(q), 3))
    for vec, s1, t1, s2 in ((b_w, grad.s, grad.t, gn.s), (_UP, grad.a, grad.u, gn.a)):
        k = _skew(vec)
        m = q @ (s1 @ (q_t @ vec)[..., None]) - q @ t1[..., None]  # (n_w, 3, 1)
        half += (k.T @ m)[..., 0]
        h_gn += k.T @ q @ s1 @ q_t @ k
        outer = m * vec
        h += k.T @ q @ s2 @ q_t @ k + 0.5 * (outer + np.transpose(outer, (0, 2, 1))) \
            - (vec @ m)[..., None] * np.eye(3)
    eig = np.linalg.eigvalsh(h)
    newton = eig[:, 0] > -_RCOND * eig[:, -1]  # a free direction (no gravity: the turn about b_W) is no curvature
    h_gn[newton] = h[newton]
    return -(np.linalg.pinv(h_gn, rcond=_RCOND, hermitian=True) @ half[..., None])[..., 0]


class _Problem:
    """The gyro-aided model on fixed rows (see the module docstring), the windows' orientations projected out.

    The global parameters ``p`` (26): ``D`` (9, row-major), ``h`` (3), ``delta`` (1, rad), ``beta`` (3,
    rad/s), ``tau`` (1, s: the magnetometer's latency against the gyro), ``E = G - I`` (9, row-major: the gyro's
    scale and axes; the turn's derivative ``d phi_i = dE (phi_i^raw - beta dt_i)``, chained through the prefix
    products as ``beta``'s, :meth:`_turn_derivatives`), then the accelerometer's held parameters ``c`` (k, with
    ``accel_change``: :func:`fit_with_gyro`; their prior rows after the gyro matrix's).  The windows' orientations
    ``Q_j`` are not parameters of the outer least squares: for each ``p`` every window's is solved
    (:meth:`residual`: Newton steps on each window's 3 x 3 problem, all windows at once, each started
    from its last solution; with the plain loss a window's loss is a quadratic form in its field and
    gravity, :class:`_Sums`, so a step costs nothing per row), and :meth:`jacobian` is the Jacobian of
    that reduced residual (variable projection, Golub and Pereyra 1973, in Kaufman's form)::

        J = J_g - J_l (J_l^T W J_l)^+ J_l^T W J_g,

    ``J_g`` the residual's derivative w.r.t. ``p`` at fixed orientations, ``J_l`` w.r.t. each window's
    turn (``Q_j -> Exp(d) Q_j``: a block of 3 columns per window, one window per row), ``W`` the loss's
    curvature.  The reduced problem has the joint problem's minimum, and there ``J^T J`` is the Schur
    complement of the joint normal equations' window blocks: the global covariance with the windows
    marginalised.  The last residuals are the priors (:data:`N_PRIOR`): ``tau``'s, ``tau / tau_prior_s`` (a tiny
    prior fixes the latency at zero), and ``E``'s, ``E / gyro_prior`` (a tiny one fixes ``G`` at the identity).  ``f_scale`` None is the plain loss; a number, scipy's ``soft_l1`` with that
    scale, which the windows' steps then minimise too.
    """

    N_GLOBAL = 26
    """The global parameters before the accelerometer's ``c`` (:attr:`n_global` with them)."""
    N_PRIOR = 10
    """The prior residuals at the end before ``c``'s: the latency's (1) and the gyro matrix's (9)."""

    def __init__(self, mag, turns, dt, window, accel, static, q_start, sigma_m, sigma_a, rate,
                 tau_prior_s=LATENCY_PRIOR_S, f_scale=None, gyro_prior=None, accel_change=None, accel_prior=None):
        self.mag, self.turns, self.dt, self.window, self.rate = mag, turns, dt, window, rate
        self.accel, self.static = accel[static], np.flatnonzero(static)
        k = 0 if accel_change is None else accel_change.shape[2]
        self.accel_change = np.zeros((len(self.static), 3, 0)) if k == 0 else accel_change[static]
        self.accel_prior = np.ones(0) if k == 0 else np.asarray(accel_prior, float)
        self.n_global, self.n_prior = self.N_GLOBAL + k, self.N_PRIOR + k
        self.window_a = window[self.static]
        self.orientation = q_start  # Q_j of each window, Rotation: the solution at the lowest loss so far (the next start)
        self._lowest = np.inf  # that loss
        self.sigma_m, self.sigma_a, self.tau_prior_s, self.f_scale = sigma_m, sigma_a, tau_prior_s, f_scale
        self.gyro_prior = GYRO_MATRIX_PRIOR if gyro_prior is None else np.asarray(gyro_prior, float).ravel()
        n, n_s = len(mag), len(self.static)
        self.n_w = int(window[-1]) + 1
        starts = np.r_[0, np.flatnonzero(np.diff(window)) + 1]
        self.first = np.zeros(n, dtype=bool)
        self.first[starts] = True
        lengths = np.diff(np.r_[starts, n])
        self.slot = np.arange(n) - np.repeat(starts, lengths)  # position within the window
        self.longest = int(lengths.max())  # rows in the longest window
        self._sum_m = sparse.csr_matrix((np.ones(n), (window, np.arange(n))), shape=(self.n_w, n))
        self._sum_a = sparse.csr_matrix((np.ones(n_s), (self.window_a, np.arange(n_s))), shape=(self.n_w, n_s))
        self._last = None  # (p, _Rows, orientations (n_w, 3, 3)) of the last residual

    def _relative(self, beta, gyro):
        """``Delta R_k`` (matrices, shape (n, 3, 3)) and the turns ``psi`` (raw, less the bias) and ``phi = G psi``."""
        psi = self.turns - np.outer(self.dt, beta)  # the raw turn less the bias
        psi[self.first] = 0.0  # a window starts at its first sample
        phi = psi @ gyro.T
        quat = Rotation.from_rotvec(phi).as_quat()
        shift = 1
        while shift < self.longest:  # prefix products within each window (Hillis-Steele scan, segmented)
            later = np.flatnonzero(self.slot >= shift)  # rows whose row `shift` back is in their window
            quat[later] = _qmul(quat[later - shift], quat[later])
            shift *= 2
        return Rotation.from_quat(quat).as_matrix(), psi, phi

    def _turn_derivatives(self, rows: _Rows) -> tuple[np.ndarray, np.ndarray]:
        """``G_k`` (d of ``Delta R_k``'s turn / d beta, up to sign; (n, 3, 3)) and its derivative w.r.t. ``E = G - I``
        (row-major, (n, 3, 9)), both in the window's start frame (only the Jacobian needs them)."""
        turn = rows.rel @ _so3_jacobian(rows.phi, -1.0)  # a change d phi_i turns every later Delta R_k by Exp(turn d phi_i)
        turn[self.first] = 0.0
        step = np.concatenate([turn @ rows.gyro * self.dt[:, None, None],  # d phi_i = -G d beta dt_i
                               (turn[..., :, None] * rows.psi[:, None, None, :]).reshape(-1, 3, 9)], axis=2)  # dE psi_i
        cum = np.cumsum(step, axis=0)
        cum -= cum[self.first][self.window]  # the first row of each window holds zero
        return cum[..., :3], cum[..., 3:]

    def rows(self, p) -> _Rows:
        """What the rows need from the global parameters ``p``."""
        d = p[:9].reshape(3, 3)
        delta, beta, tau = p[12], p[13:16], float(p[16])
        gyro = np.eye(3) + p[17:26].reshape(3, 3)
        rel, psi, phi = self._relative(beta, gyro)
        rate_b = self.rate - beta
        omega = rate_b @ gyro.T
        late = np.eye(3) + tau * _skew(omega)  # u(t_k - tau) = (I + tau [w]x) u(t_k), first order
        resp = (d / self.sigma_m) @ late @ np.transpose(rel, (0, 2, 1))
        f = self.accel + self.accel_change @ p[self.N_GLOBAL:]
        a_norm = np.linalg.norm(f, axis=1)
        return _Rows(p, d, np.array([np.cos(delta), 0.0, -np.sin(delta)]),
                     np.array([-np.sin(delta), 0.0, -np.cos(delta)]), tau, rel, psi, phi, gyro, rate_b, omega, resp,
                     (self.mag - p[9:12]) / self.sigma_m, f / a_norm[:, None], a_norm)

    def residuals(self, rows: _Rows, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The magnetometer's (n, 3) and the accelerometer's residuals (n_s, 3) at the windows' orientations
        ``q`` (matrices, (n_w, 3, 3)), in noise sigmas."""
        v = (q.transpose(0, 2, 1) @ rows.b_w)[self.window]  # Q^T b_W
        r_m = rows.e - (rows.resp @ v[..., None])[..., 0]
        up = (np.transpose(rows.rel[self.static], (0, 2, 1)) @ q[self.window_a, 2, :, None])[..., 0]  # Delta R^T Q^T z
        return r_m, (rows.a_unit - up) / self.sigma_a

    def _sums(self, rows: _Rows, w_m=None, w_a=None) -> _Sums:
        """The windows' :class:`_Sums` with the rows' weights (None: 1)."""
        resp_w = rows.resp if w_m is None else w_m[..., None] * rows.resp
        resp_t = np.transpose(rows.resp, (0, 2, 1))
        s = self._sum_m @ (resp_t @ resp_w).reshape(-1, 9)
        t = self._sum_m @ (np.transpose(resp_w, (0, 2, 1)) @ rows.e[..., None])[..., 0]
        rel_a = rows.rel[self.static]
        if w_a is None:
            a = np.bincount(self.window_a, minlength=self.n_w)[:, None] * np.eye(3).ravel()
            u = self._sum_a @ (rel_a @ rows.a_unit[..., None])[..., 0]
        else:
            rel_w = rel_a * w_a[:, None, :]
            a = self._sum_a @ (rel_w @ np.transpose(rel_a, (0, 2, 1))).reshape(-1, 9)
            u = self._sum_a @ (rel_w @ rows.a_unit[..., None])[..., 0]
        return _Sums(s.reshape(-1, 3, 3), t, a.reshape(-1, 3, 3) / self.sigma_a**2, u / self.sigma_a**2)

    def _robust_cost(self, r_m, r_a) -> np.ndarray:
        """Each window's ``soft_l1`` loss, (n_w,)."""
        return (self._sum_m @ _soft_l1_cost(r_m, self.f_scale).sum(axis=1)
                + self._sum_a @ _soft_l1_cost(r_a, self.f_scale).sum(axis=1))

    @staticmethod
    def _plain_change(sums: _Sums, q, trial, b_w) -> tuple[np.ndarray, np.ndarray]:
        """Each window's change of the plain loss from ``q`` to ``trial`` and the rounding it allows (n_w,)."""
        change, scale = 0.0, 0.0
        for vec, s, t in ((b_w, sums.s, sums.t), (_UP, sums.a, sums.u)):
            v0, v1 = np.transpose(q, (0, 2, 1)) @ vec, np.transpose(trial, (0, 2, 1)) @ vec
            quad = (s @ v0[..., None])[..., 0]
            change = change - 2.0 * np.sum((v1 - v0) * t, axis=1) + np.sum((v1 - v0) * (s @ (v1 + v0)[..., None])[..., 0],
                                                                            axis=1)
            scale = scale + np.abs(np.sum(v0 * quad, axis=1)) + np.abs(np.sum(v0 * t, axis=1))
        return change, 1e-13 * scale

    def _solve_windows(self, rows: _Rows) -> tuple[Rotation, np.ndarray]:
        """Every window's orientation (Rotation and matrices (n_w, 3, 3)) that minimises its loss at ``rows``' global
        parameters (Newton steps from :attr:`orientation`, :func:`_window_newton`, a window's step halved while it
        raises that window's loss)."""
        q_rot = self.orientation
        q = q_rot.as_matrix()
        plain = self.f_scale is None
        if plain:
            grad = gn = self._sums(rows)
        for _ in range(WINDOW_STEPS):
            if not plain:
                r_m, r_a = self.residuals(rows, q)
                (w_m, c_m), (w_a, c_a) = _soft_l1_weights(r_m, self.f_scale), _soft_l1_weights(r_a, self.f_scale)
                grad, gn, cost = self._sums(rows, w_m, w_a), self._sums(rows, c_m, c_a), self._robust_cost(r_m, r_a)
            step = _window_newton(q, rows.b_w, grad, gn)
            if not np.max(np.abs(step)) > WINDOW_TOL_RAD:
                break
            for _ in range(_HALVINGS):
                trial_rot = Rotation.from_rotvec(step) * q_rot
                trial = trial_rot.as_matrix()
                if plain:
                    change, slack = self._plain_change(grad, q, trial, rows.b_w)
                    worse = ~(change <= slack)
                else:
                    worse = ~(self._robust_cost(*self.residuals(rows, trial)) <= cost * (1.0 + 1e-12))
                if not worse.any():
                    break
                step[worse] *= 0.5
            else:  # a window whose loss no step lowers stays
                step[worse] = 0.0
                trial_rot = Rotation.from_rotvec(step) * q_rot
                trial = trial_rot.as_matrix()
            q_rot, q = trial_rot, trial
        return q_rot, q

    def residual(self, p):
        """The residual at ``p``, every window's orientation solved (in noise sigmas; the prior last).

        The windows' solution becomes the next solve's start only when the loss is the lowest so far: the outer
        least squares' trial steps it rejects (a far step, where a window's solution can turn half a turn) do not
        leave their windows' solutions as the start at its own iterate, where a window would stay in that minimum.
        """
        p = np.array(p, dtype=float)
        rows = self.rows(p)
        q_rot, q = self._solve_windows(rows)
        self._last = (p, rows, q)
        r_m, r_a = self.residuals(rows, q)
        r = np.concatenate([r_m.ravel(), r_a.ravel(), [rows.tau / self.tau_prior_s], self.prior_e(p),
                            p[self.N_GLOBAL:] / self.accel_prior])
        loss = float(np.sum(_soft_l1_cost(r, self.f_scale)))
        if loss <= self._lowest:
            self._lowest, self.orientation = loss, q_rot
        return r

    def prior_e(self, p) -> np.ndarray:
        """The gyro matrix's prior residuals, ``(G - I) / sigma`` (9)."""
        return p[17:26] / self.gyro_prior

    def global_jacobian(self, rows: _Rows, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``J_g``: the residual's derivative w.r.t. ``p`` at the fixed orientations ``q``, magnetometer
        (n, 3, n_global) and accelerometer rows (n_s, 3, n_global)."""
        n, s = len(self.mag), self.static
        d, tau, omega = rows.d / self.sigma_m, rows.tau, rows.omega
        q_t = np.transpose(q, (0, 2, 1))
        v = (q_t @ rows.b_w)[self.window]
        u = (np.transpose(rows.rel, (0, 2, 1)) @ v[..., None])[..., 0]  # Delta R^T Q^T b_W: the field at t_k
        w_u = np.cross(omega, u)
        blocks = np.zeros((n, 3, self.n_global))
        for i in range(3):
            blocks[:, i, 3 * i:3 * i + 3] = -(u + tau * w_u) / self.sigma_m
        blocks[:, :, 9:12] = -np.eye(3) / self.sigma_m
        blocks[:, :, 12] = -(rows.resp @ (q_t @ rows.db_w)[self.window][..., None])[..., 0]
        # dr/dbeta = D M Delta R^T [v]x G_k - tau D [u]x G (M = I + tau [w]x, w = G (rate - beta));
        # dr/dE = -D M Delta R^T [v]x G^E_k + tau D [u]x (dE (rate - beta)); dr/dtau = -D (w x u)
        k_u = _skew(u)
        g, g_e = self._turn_derivatives(rows)
        turned = rows.resp @ _skew(v)  # the reading's response to a turn of Delta R_k
        blocks[:, :, 13:16] = turned @ g - tau * d @ k_u @ rows.gyro
        blocks[:, :, 16] = -w_u @ d.T
        late_e = (k_u[..., :, None] * rows.rate_b[:, None, None, :]).reshape(n, 3, 9)  # [u]x dE (rate - beta)
        blocks[:, :, 17:26] = tau * d @ late_e - turned @ g_e
        a_blocks = np.zeros((len(s), 3, self.n_global))  # accelerometer rows: up = Delta R^T Q^T z
        a_turn = np.transpose(rows.rel[s], (0, 2, 1)) @ _skew(q[self.window_a, 2, :]) / self.sigma_a
        a_blocks[:, :, 13:16] = a_turn @ g[s]
        a_blocks[:, :, 17:26] = -(a_turn @ g_e[s])
        u, change = rows.a_unit, self.accel_change  # d (f / |f|) = (I - u u^T) df / |f|
        along = np.einsum("ni,nik->nk", u, change)
        a_blocks[:, :, self.N_GLOBAL:] = ((change - u[..., None] * along[:, None])
                                          / (rows.a_norm * self.sigma_a)[:, None, None])
        return blocks, a_blocks

    def jacobian(self, p):
        """The reduced residual's Jacobian at ``p`` (dense, (m, n_global); see the class docstring)."""
        p = np.array(p, dtype=float)
        if self._last is None or not np.array_equal(p, self._last[0]):
            self.residual(p)
        _, rows, q = self._last
        j_m, j_a = self.global_jacobian(rows, q)
        r_m, r_a = self.residuals(rows, q)
        c_m, c_a = _soft_l1_weights(r_m, self.f_scale)[1], _soft_l1_weights(r_a, self.f_scale)[1]
        sums = self._sums(rows, None if self.f_scale is None else c_m, None if self.f_scale is None else c_a)
        # J_l = -resp Q^T [b]x (magnetometer), -Delta R^T Q^T [z]x / sigma_a (accelerometer)
        q_t = np.transpose(q, (0, 2, 1))
        k_b, k_z = q_t @ _skew(rows.b_w), q_t @ _skew(_UP)
        h = (np.transpose(k_b, (0, 2, 1)) @ sums.s @ k_b + np.transpose(k_z, (0, 2, 1)) @ sums.a @ k_z)
        resp_t_w = np.transpose(rows.resp, (0, 2, 1)) * c_m[:, None, :]
        rel_w = rows.rel[self.static] * c_a[:, None, :] / self.sigma_a
        flat = 3 * self.n_global  # explicit: no accelerometer row kept in any window leaves j_a empty, and -1 with it
        c = (np.transpose(k_b, (0, 2, 1)) @ (self._sum_m @ (resp_t_w @ j_m).reshape(len(j_m), flat)).reshape(-1, 3, self.n_global)
             + np.transpose(k_z, (0, 2, 1)) @ (self._sum_a @ (rel_w @ j_a).reshape(len(j_a), flat)).reshape(-1, 3, self.n_global))
        x = np.linalg.pinv(h, rcond=_RCOND, hermitian=True) @ -c  # (n_w, 3, n_global): each window's turn per unit of p
        j_m += rows.resp @ (k_b @ x)[self.window]  # J_g - J_l x, -J_l = resp Q^T [b]x
        j_a += np.transpose(rows.rel[self.static], (0, 2, 1)) @ (k_z @ x)[self.window_a] / self.sigma_a
        prior = np.zeros((self.n_prior, self.n_global))
        prior[0, 16] = 1.0 / self.tau_prior_s
        prior[1:10, 17:26] = np.eye(9) / self.gyro_prior
        prior[10:, self.N_GLOBAL:] = np.diag(1.0 / self.accel_prior)
        return np.vstack([j_m.reshape(-1, self.n_global), j_a.reshape(-1, self.n_global), prior])


def _start_orientations(mag_h, a_unit, window, b_w):
    """``Q_j0`` of each window from its first sample: tilt from gravity, heading from the field (TRIAD)."""
    starts = np.r_[0, np.flatnonzero(np.diff(window)) + 1]
    out = []
    up = np.array([0.0, 0.0, 1.0])
    for k in starts:
        m = mag_h[k] / np.linalg.norm(mag_h[k])
        out.append(Rotation.align_vectors([up, b_w], [a_unit[k], m], weights=[np.inf, 1.0])[0].as_quat())
    return Rotation.from_quat(np.array(out))


def fit_with_gyro(mag, accel, turns_rad, t_s, *, hard_iron, soft_iron, field_norm, mag_to_accel=None,
                  dip_deg=None, noise=None, fit_latency=True, fit_gyro_matrix=True, accel_change=None,
                  accel_prior=None) -> GyroFit:
    """Fit the gyro-aided model from a start (the present tumble fit's values).

    Parameters
    ----------
    mag : ndarray, shape (n, 3)
        Raw magnetometer, recording units, in time order.
    accel : ndarray, shape (n, 3)
        Accelerometer (specific force, +1 g up at rest), any unit, housing frame.
    turns_rad : ndarray, shape (n, 3)
        The gyro's turn from the previous sample to each (rotation vector, rad, housing frame; row 0
        ignored): :func:`compass.io.tumble.gyro_turns`.
    t_s : ndarray, shape (n,)
        Time of each sample, s.
    hard_iron, soft_iron, field_norm, mag_to_accel, dip_deg :
        The start: ``h`` (recording units), ``S`` (det 1), ``F``, ``C`` (None: identity), dip (None:
        from the field-gravity angle).
    noise : float, optional
        White-noise sigma per axis (recording units); default from second differences.
    fit_latency : bool
        Fit the magnetometer's latency against the gyro (prior sigma :data:`LATENCY_PRIOR_S`); False
        holds it at zero (the model before the latency, for comparison).
    fit_gyro_matrix : bool
        Fit the gyro's scale and axes ``G`` (prior :data:`GYRO_MATRIX_PRIOR`); False holds it at the
        identity (the model before it, for comparison).
    accel_change : ndarray, shape (n, 3, k), optional
        The accelerometer's parameters ``c`` (k) fitted beside: a row reads gravity along ``accel + accel_change @
        c`` (``accel``'s unit per unit of ``c``; :meth:`calibrate.tumble.accelerometer.AccelCalibration.held_change`,
        the parameters its still rows left held); None: none.
    accel_prior : ndarray, shape (k,), optional
        Their prior sigmas (Gaussian, about zero).  With them the windows are :data:`ACCEL_WINDOW_FACTOR` times
        longer.

    Returns
    -------
    GyroFit

    Raises
    ------
    ValueError
        Inputs of different lengths, non-finite, or a time that decreases.
    GyroMismatch
        Fewer than 20 still rows (:func:`still_mask`), or the model rejects most samples (said in words).
    """
    mag, accel, turns = (np.asarray(a, dtype=float) for a in (mag, accel, turns_rad))
    t_s = np.asarray(t_s, dtype=float)
    n = len(mag)
    for label, a, shape in (("accel", accel, (n, 3)), ("turns_rad", turns, (n, 3)), ("t_s", t_s, (n,))):
        if a.shape != shape:
            raise ValueError(f"{label} must have shape {shape}, got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{label} holds non-finite values")
    dt = np.diff(t_s, prepend=t_s[0])
    if np.any(dt < 0):
        raise ValueError("t_s must be non-decreasing")
    static = still_mask(accel, turns, t_s)
    if np.count_nonzero(static) < 20:
        raise GyroMismatch(f"only {np.count_nonzero(static)} still accelerometer rows; the gyro-aided fit needs 20")
    if noise is None:
        noise = float(np.median(second_difference_sigma(second_differences(mag))))
    accel_norm = np.linalg.norm(accel, axis=1, keepdims=True)
    if not np.all(accel_norm > 0):
        raise GyroMismatch(f"{np.count_nonzero(~(accel_norm > 0))} accelerometer rows read zero (the first is "
                           f"sample {int(np.flatnonzero(~(accel_norm[:, 0] > 0))[0])}): the windows' tilt needs "
                           "gravity's direction")
    a_unit = accel / accel_norm
    c0 = np.eye(3) if mag_to_accel is None else np.asarray(mag_to_accel, float)
    t0 = c0 @ np.asarray(soft_iron, float)
    mag_h = (mag - hard_iron) @ t0.T
    if dip_deg is None:
        cos = np.sum(mag_h[static] * a_unit[static], axis=1) / np.linalg.norm(mag_h[static], axis=1)
        dip_deg = float(np.degrees(np.median(np.arccos(np.clip(cos, -1, 1)))) - 90.0)
    delta0 = np.radians(dip_deg)
    k = 0 if accel_change is None else np.shape(accel_change)[2]
    if k and (accel_prior is None or np.shape(accel_prior) != (k,) or not np.all(np.asarray(accel_prior) > 0)
              or np.shape(accel_change) != (len(mag), 3, k)):
        raise ValueError(f"accel_change must be (n, 3, k) with accel_prior (k,) positive sigmas; got "
                         f"{np.shape(accel_change)} and {np.shape(accel_prior)}")
    window = _windows(turns, dt, 1.0 if k == 0 else ACCEL_WINDOW_FACTOR)
    rate = turn_rates(turns, dt)
    b_w = np.array([np.cos(delta0), 0.0, -np.sin(delta0)])
    q_start = _start_orientations(mag_h, a_unit, window, b_w)
    p0 = np.concatenate([(field_norm * np.linalg.inv(t0)).ravel(), hard_iron, [delta0], np.zeros(3), [0.0],
                         np.zeros(9), np.zeros(k)])
    prior = LATENCY_PRIOR_S if fit_latency else _FIXED_S
    prob = _Problem(mag, turns, dt, window, accel, static, q_start, max(noise, 1e-12), 1.0, rate, prior,
                    f_scale=ROBUST_F_SCALE, gyro_prior=GYRO_MATRIX_PRIOR if fit_gyro_matrix else _FIXED_GYRO,
                    accel_change=None if k == 0 else np.asarray(accel_change, float), accel_prior=accel_prior)
    r_a = prob.residuals(prob.rows(p0), q_start.as_matrix())[1]  # the accelerometer's scatter at the start
    prob.sigma_a = max(float(robust_sigma(np.linalg.norm(r_a, axis=1))), MIN_SIGMA_A)
    thin, _ = _on_rows(prob, t_s, rate, _robust_rows(window), f_scale=ROBUST_F_SCALE)
    # scipy applies the loss to every residual, the priors' (latency, G) too: beyond ROBUST_F_SCALE prior sigmas
    # they pull less than quadratically in this stage; the plain stage after it has the Gaussian prior
    robust = least_squares(thin.residual, p0, jac=thin.jacobian, loss="soft_l1", f_scale=ROBUST_F_SCALE, method="trf",
                           x_scale="jac", max_nfev=MAX_NFEV)
    prob.orientation = thin.orientation  # every window keeps rows: the same windows
    fun = prob.residual(robust.x)  # every row's residual, every window's orientation solved on all its rows
    r = fun[:3 * n].reshape(n, 3)
    inliers = np.linalg.norm(r, axis=1) < OUTLIER_SIGMAS * np.sqrt(3.0)
    keep_a = np.linalg.norm(fun[3 * n:-prob.n_prior].reshape(-1, 3), axis=1) < OUTLIER_SIGMAS * np.sqrt(3.0)
    if np.count_nonzero(inliers) < MIN_INLIER_FRACTION * n or np.count_nonzero(keep_a) < 20:
        raise GyroMismatch(f"the magnetometer and the gyro disagree: the fit rejected {n - np.count_nonzero(inliers)} of "
                           f"{n} samples beyond {OUTLIER_SIGMAS:g} noise sigmas (a magnetometer late against the gyro, "
                           "a disturbed field, a gyro off scale)")
    kept, used = _on_rows(prob, t_s, rate, np.flatnonzero(inliers), f_scale=None, keep_a=keep_a)
    final = plain_fit(kept.residual, robust.x, kept.jacobian, max_nfev=MAX_NFEV)
    chi2 = float(final.fun @ final.fun) / max(final.fun.size - final.x.size - 3 * len(used), 1)  # and the windows'
    cov = _global_covariance(final.jac, chi2)
    wide = None if cov is None else _widened_covariance(final, kept, t_s[inliers], cov / chi2, cov)
    return _result(final, cov, kept, inliers, noise, turns, n_w=len(used), widened_cov=wide)


def _widened_covariance(final, prob: _Problem, t_s: np.ndarray, bread: np.ndarray, naive: np.ndarray) -> np.ndarray:
    r"""The global parameters' covariance grown to cover structure in the residual that changes with time.

    The plain fit's residual ``r`` (in noise sigmas: the magnetometer's ``3 n`` rows, the still accelerometer's
    ``3 n_s``, then the priors') and its reduced Jacobian ``J`` (the windows' orientations projected out,
    :class:`_Problem`) are those of a least squares in the global parameters alone, so a structure ``s`` in the data
    rows the model lacks moves them by ``B J^T s`` (``B = (J^T J)^{-1}``, every row's, the priors' too: they inform the
    parameters, they carry no structure).  The naive covariance takes ``s`` for white noise.  Here the rows are
    clustered in :data:`~calibrate.diagnosis.blocks.TIME_BLOCKS` blocks of consecutive samples (a sample's three
    magnetometer rows and its accelerometer rows share its block) and the covariance is the naive one grown to the CR2
    sandwich over them (:func:`~calibrate.diagnosis.blocks.widened_in_time` without ``hard``).  A window's rows are
    tied by its orientation, solved on them; the windows (``WINDOW_S``, 10 s at most) are short beside a block (an
    eighth of the recording), so few cross a block's border.

    The hard-iron walk model of :mod:`calibrate.diagnosis.blocks` is not used: its competitor, a level per block of
    each sort of row, is the radial residual's (a field whose size changed); in this vector residual a world field
    that wanders is turned with the housing, which a block that sees a narrow band of orientations cannot tell from
    a hard iron's level, and the walk model took it for one.  Measured on a simulated 60 s fast tumble with the gyro
    (seeds 0-7, a smooth random walk of 1 uT rms added): with a hard iron walking, the hard iron's error over its
    sigma had an rms of 10 naive, 1.5 with the walk model, 0.6 with CR2 alone; with the world field wandering, 20,
    4.2 and 1.8.  CR2 over blocks treats the blocks as independent; a wander over the whole session is not, and there
    it errs low (:mod:`calibrate.diagnosis.blocks`).

    Parameters
    ----------
    final : OptimizeResult
        The plain fit on ``prob`` (``fun``, ``jac``).
    prob : _Problem
        The inliers' problem.
    t_s : ndarray, shape (n,)
        Its samples' times, s.
    bread, naive : ndarray, shape (k, k)
        ``(J^T J)^{-1}`` and the fit's covariance (the bread scaled by its chi-square).

    Returns
    -------
    ndarray, shape (k, k)
    """
    n, n_s = len(prob.mag), len(prob.static)
    n_data = 3 * (n + n_s)
    block = time_blocks(t_s)
    blocks = np.concatenate([np.repeat(block, 3), np.repeat(block[prob.static], 3)])
    return widened_in_time(final.jac[:n_data], final.fun[:n_data], blocks, naive, bread=bread)


def _robust_rows(window: np.ndarray) -> np.ndarray:
    """The rows the robust fit uses: all, or every ``k``-th of each window (from its first, where its integration
    starts), ``k`` the smallest that leaves :data:`ROBUST_ROWS` of the whole (about: each window's first row
    stays), but no larger than leaves :data:`MIN_WINDOW_SAMPLES` of a median window's rows."""
    n = len(window)
    starts = np.r_[0, np.flatnonzero(np.diff(window)) + 1]
    median = float(np.median(np.diff(np.r_[starts, n])))
    every = max(min(-(-n // ROBUST_ROWS), int(median // MIN_WINDOW_SAMPLES)), 1)
    slot = np.arange(n) - np.repeat(starts, np.diff(np.r_[starts, n]))
    return np.flatnonzero(slot % every == 0)


def _on_rows(prob: _Problem, t_s, rate, rows, *, f_scale, keep_a=None) -> tuple[_Problem, np.ndarray]:
    """``prob`` on ``rows`` only (``f_scale`` its loss), and the windows that keep rows: a dropped sample's turn and
    time go to the next kept one; the accelerometer's still rows among ``rows`` stay (those of them
    ``keep_a`` marks, when given); a window left without rows goes."""
    turns = np.diff(np.cumsum(prob.turns, axis=0)[rows], axis=0, prepend=np.zeros((1, 3)))
    dt = np.diff(t_s[rows], prepend=t_s[rows[0]])
    static = np.zeros(len(prob.mag), dtype=bool)
    static[prob.static if keep_a is None else prob.static[keep_a]] = True
    accel = np.zeros((len(prob.mag), 3))
    accel[prob.static] = prob.accel
    change = np.zeros((len(prob.mag),) + prob.accel_change.shape[1:])
    change[prob.static] = prob.accel_change
    used = np.unique(prob.window[rows])
    remap = np.full(prob.n_w, -1)
    remap[used] = np.arange(len(used))
    return _Problem(prob.mag[rows], turns, dt, remap[prob.window[rows]], accel[rows], static[rows],
                    prob.orientation[used], prob.sigma_m, prob.sigma_a, rate[rows], prob.tau_prior_s, f_scale,
                    prob.gyro_prior, change[rows], prob.accel_prior), used


def _global_covariance(jac: np.ndarray, chi2: float) -> np.ndarray | None:
    """Covariance of the global parameters (26, and the accelerometer's ``c``), the windows' orientations
    marginalised (None if singular).

    ``jac`` is the reduced Jacobian of the plain fit (:class:`_Problem`): ``J^T J`` is the Schur
    complement of the joint normal equations' block-diagonal window part, each 3 x 3 block
    pseudo-inverted (a window whose orientation the data leave partly free adds nothing).  Scaled to
    unit diagonal before judging its condition (``D`` is of order |B|, ``beta`` of order 0.01 rad/s).
    """
    schur = jac.T @ jac
    d = np.sqrt(np.clip(np.diag(schur), 1e-300, None))
    scaled = schur / np.outer(d, d)
    if not np.all(np.isfinite(scaled)) or np.linalg.cond(scaled) > 1e12:
        return None
    return np.linalg.inv(scaled) / np.outer(d, d) * chi2


def _unpack(q):
    """(h, S det 1, F, C as matrix, dip rad) from the parameters; ``C S`` the polar decomposition of ``T = F D^-1``
    (by the SVD: a rotation however ill-conditioned ``D``, as along what a one-axis turn leaves free)."""
    d = q[:9].reshape(3, 3)
    f_norm = np.cbrt(np.linalg.det(d))
    c, s = polar(f_norm * np.linalg.inv(d))
    return q[9:12], (s + s.T) / 2.0, float(f_norm), c, float(q[12])


_MAGNETIC_SIGMAS = ("hard_iron_sigma", "soft_iron_sigma", "field_norm_sigma", "rotvec_sigma_deg", "dip_sigma_deg")
"""The sigmas :meth:`GyroFit.widened` takes from the widened covariance."""


def _sigmas(q: np.ndarray, cov: np.ndarray | None) -> dict:
    """The stated sigmas of :class:`GyroFit` from the global parameters ``q`` and their covariance (None:
    singular, every sigma infinite): ``S``, ``F`` and the rotation to the housing through :func:`_unpack`'s
    derivatives by ``D``, the others read off the diagonal."""
    h, s, f_norm, c, delta = _unpack(q)
    if cov is None:
        return dict(hard_iron_sigma=np.full(3, np.inf), soft_iron_sigma=np.full((3, 3), np.inf),
                    field_norm_sigma=np.inf, rotvec_sigma_deg=np.full(3, np.inf), dip_sigma_deg=np.inf,
                    gyro_bias_sigma_rad_s=np.full(3, np.inf), latency_sigma_s=np.inf,
                    gyro_matrix_sigma=np.full((3, 3), np.inf), accel_sigma=np.full(len(q) - _Problem.N_GLOBAL, np.inf))
    rot = Rotation.from_matrix(c)
    grads = np.empty((9 + 1 + 3, 9))  # d(S, F, rotvec) / d(D)
    for j in range(9):
        step = np.zeros_like(q)
        step[j] = 1e-7 * max(abs(q[j]), f_norm)
        _, s_j, f_j, c_j, _ = _unpack(q + step)
        grads[:9, j] = (s_j - s).ravel() / step[j]
        grads[9, j] = (f_j - f_norm) / step[j]
        grads[10:, j] = (Rotation.from_matrix(c_j) * rot.inv()).as_rotvec() / step[j]
    var = np.einsum("ij,jk,ik->i", grads, cov[:9, :9], grads)
    sig = np.sqrt(np.clip(var, 0, None))
    diag = np.clip(np.diag(cov), 0, None)
    return dict(hard_iron_sigma=np.sqrt(diag[9:12]), soft_iron_sigma=sig[:9].reshape(3, 3), field_norm_sigma=float(sig[9]),
                rotvec_sigma_deg=np.degrees(sig[10:]), dip_sigma_deg=float(np.degrees(np.sqrt(diag[12]))),
                gyro_bias_sigma_rad_s=np.sqrt(diag[13:16]), latency_sigma_s=float(np.sqrt(diag[16])),
                gyro_matrix_sigma=np.sqrt(diag[17:26]).reshape(3, 3), accel_sigma=np.sqrt(diag[_Problem.N_GLOBAL:]))


def _result(final, cov, prob, inliers, noise, turns, n_w, widened_cov=None) -> GyroFit:
    q = final.x
    h, s, f_norm, c, delta = _unpack(q)
    rot = Rotation.from_matrix(c)
    right_handed = np.linalg.det(q[:9].reshape(3, 3)) > 0
    success = bool(final.success) and right_handed
    message = str(final.message) if right_handed else "the response has a negative determinant: a reversed axis"
    n_mag = 3 * len(prob.mag)
    mag_rms = float(np.sqrt(np.mean((final.fun[:n_mag] * prob.sigma_m) ** 2)))
    sigmas = _sigmas(q, cov)
    sig_h, sig_s, sig_rot = sigmas["hard_iron_sigma"], sigmas["soft_iron_sigma"], sigmas["rotvec_sigma_deg"]
    undetermined = []
    bad_h = [_AXES[i] for i in range(3) if not sig_h[i] <= MAX_RELATIVE_SIGMA * f_norm]
    if bad_h:
        undetermined.append(f"hard iron along {', '.join(bad_h)} (sigma up to "
                            f"{100 * np.max(sig_h) / f_norm:.2g} % of the field)")
    bad_s = [f"{_AXES[i]}{_AXES[j]}" for i in range(3) for j in range(i, 3) if not sig_s[i, j] <= MAX_RELATIVE_SIGMA]
    if bad_s:
        undetermined.append(f"soft iron {', '.join(bad_s)} (sigma up to {100 * np.max(sig_s):.2g} %)")
    bad_r = [_AXES[i] for i in range(3) if not sig_rot[i] <= MAX_ROTATION_SIGMA_DEG]
    if bad_r:
        undetermined.append(f"the rotation to the housing about {', '.join(bad_r)} (sigma up to "
                            f"{np.max(sig_rot):.2g} deg)")
    return GyroFit(h, sig_h, s, sig_s, f_norm, sigmas["field_norm_sigma"], rot, np.degrees(rot.as_rotvec()), sig_rot,
                   float(np.degrees(delta)), sigmas["dip_sigma_deg"], q[13:16], sigmas["gyro_bias_sigma_rad_s"],
                   float(q[16]), sigmas["latency_sigma_s"], np.eye(3) + q[17:26].reshape(3, 3),
                   sigmas["gyro_matrix_sigma"], n_w, len(prob.static),
                   inliers, mag_rms, float(noise), tuple(undetermined), turn_axes(turns[inliers]), success, message,
                   q[_Problem.N_GLOBAL:], sigmas["accel_sigma"], np.array(q, dtype=float), cov, widened_cov)


_SUPERSEDED = ("used the ", "no magnetometer-accelerometer rotation fitted", UNEXPLAINED_WARNING, FAST_MOTION_WARNING,
               NOT_CONVERGED_WARNING)
"""Warnings of the present fit that a determined gyro-aided fit answers (its kind, its withheld rotation,
its residual's verdict, which is judged anew, the fast motion that withheld the rotation: the latency is fitted;
its convergence: the gyro-aided fit replaces it, and is used only converged)."""


def _unexplained_cost(naive: GyroFit, wide: GyroFit) -> dict:
    """The diagnosis's ``unexplained_cost`` of a gyro-aided fit: the hard iron's sigma per axis (recording units) and
    the rotation to the housing's per component (the field's direction in the housing, deg), naive and widened
    (the heading's is added once the dip is known, :meth:`~calibrate.tumble.diagnosis.TumbleDiagnosis.with_alignment`)."""
    names = [f"mag_to_accel.{a}" for a in _AXES]
    cost = diagnosis_cost(naive.hard_iron_sigma, wide.hard_iron_sigma, method=(
        f"the gyro-aided fit's own residual (magnetometer and still accelerometer rows) in {TIME_BLOCKS} blocks of "
        "consecutive samples, the CR2 sandwich over them (calibrate.tumble.gyro)"))
    return dict(cost, direction_deg=dict(zip(names, map(float, extra_sigma(wide.rotvec_sigma_deg, naive.rotvec_sigma_deg)))),
                direction_sigma_deg={k: {"naive": float(a), "widened": float(b)}
                                     for k, a, b in zip(names, naive.rotvec_sigma_deg, wide.rotvec_sigma_deg)})


def falls_back(result: TumbleResult) -> bool:
    """Whether the present fit fell back: a kind simpler than ``full``, or a rotation to the housing the
    data support withheld for the missing part of the sphere or for fast motion (one the BIC does not
    support is no fallback)."""
    withheld = result.misalignment is not None and result.misalignment.withheld is not None
    return not result.refused and (result.ellipsoid != "full" or withheld)


def ellipsoid_from(g: GyroFit, like: EllipsoidFit, mag: np.ndarray) -> EllipsoidFit:
    """The gyro-aided fit as a ``full`` :class:`EllipsoidFit` in ``like``'s normalisation (the diagnosis's form)."""
    low = np.linalg.cholesky((like.radius * g.soft_iron / g.field_norm) @ (like.radius * g.soft_iron / g.field_norm))
    params = np.concatenate([(g.hard_iron - like.centre) / like.radius, np.log(np.diag(low)),
                             [low[1, 0], low[2, 0], low[2, 1]]])
    resid = np.linalg.norm((mag - g.hard_iron) @ g.soft_iron.T, axis=1) - g.field_norm
    return replace(like, ellipsoid="full", hard_iron=g.hard_iron, hard_iron_sigma=g.hard_iron_sigma,
                   soft_iron=g.soft_iron, soft_iron_sigma=g.soft_iron_sigma, field_norm=g.field_norm,
                   field_norm_sigma=g.field_norm_sigma, residuals=resid, inliers=g.inliers,
                   rss=float(np.sum(resid[g.inliers] ** 2)), bic=np.nan, determined=True, reason="",
                   success=g.success, message=g.message, params=params, degenerate=False)


def misalignment_from(g: GyroFit, mag_cal: np.ndarray, accel: np.ndarray, static: np.ndarray) -> Misalignment:
    """The gyro-aided rotation and dip as a :class:`Misalignment`, with the field-gravity angle spread
    before and after the rotation and the BIC of the rotation against the dip alone on those angles, over the
    rows ``static`` marks (:func:`still_mask`'s)."""
    before = field_gravity_angles(mag_cal[static], accel[static])
    after = field_gravity_angles(mag_cal[static], accel[static], g.mag_to_accel)
    n = len(before)
    delta_bic = n * np.log(np.sum((after - after.mean()) ** 2) / np.sum((before - before.mean()) ** 2)) + 3 * np.log(n)
    return Misalignment(g.mag_to_accel, g.rotvec_deg, g.rotvec_sigma_deg, g.dip_deg, g.dip_sigma_deg,
                        int(np.count_nonzero(static)), float(np.std(before)), float(np.std(after)), float(delta_bic))


def _pin_accelerometer(result: TumbleResult, mag, accel, turns_rad, t_s, start_values: dict) -> TumbleResult:
    """``result`` with the accelerometer's held offsets and scales (``to_pin``) fitted beside a gyro-aided fit with
    windows :data:`ACCEL_WINDOW_FACTOR` times longer, those seen off zero (:data:`ACCEL_SEEN_SIGMAS`,
    :data:`ACCEL_PIN_FLOOR`) applied, the others held
    (:meth:`~calibrate.tumble.accelerometer.AccelCalibration.pinned`); ``result`` itself when nothing is held or that
    fit fails.  ``accel`` raw, recording units."""
    cal = result.accelerometer
    if cal is None or not cal.to_pin:
        return result
    try:
        g = fit_with_gyro(mag, cal.apply(accel), turns_rad, t_s, accel_change=cal.held_change(accel),
                          accel_prior=cal.pin_prior, **start_values)
    except (GyroMismatch, np.linalg.LinAlgError, ValueError):  # optional: the main fit says why, if it fails too
        return result
    if not (g.success and np.all(np.isfinite(g.accel)) and np.all(np.isfinite(g.accel_sigma))):
        return result
    floor = ACCEL_PIN_FLOOR * np.array([cal.one_g if name.startswith("offset") else 1.0 for name in cal.to_pin])
    seen = (np.abs(g.accel) > ACCEL_SEEN_SIGMAS * g.accel_sigma) & (np.abs(g.accel) > floor)
    return replace(result, accelerometer=cal.pinned(g.accel, np.where(seen, g.accel_sigma, np.nan)))


def with_gyro(result: TumbleResult, mag: np.ndarray, accel: np.ndarray, turns_rad: np.ndarray, t_s: np.ndarray,
              temp_c: np.ndarray | None = None, *, fit_latency: bool = True,
              fit_gyro_matrix: bool = True) -> TumbleResult:
    """The present tumble result, or the gyro-aided one where that one is determined.

    Parameters
    ----------
    result : TumbleResult
        :func:`calibrate.tumble.calibrate_tumble`'s on the same samples (the start values).
    mag, accel, turns_rad, t_s, temp_c, fit_latency, fit_gyro_matrix :
        As :func:`fit_with_gyro` (``temp_c`` for the diagnosis); ``accel`` raw, corrected here by ``result``'s
        accelerometer calibration (:meth:`TumbleResult.corrected_accel`), whose held offsets and scales are first
        fitted beside a gyro-aided fit (:func:`_pin_accelerometer`; the returned result carries them only where the
        gyro-aided fit is used).

    Returns
    -------
    TumbleResult
        When the gyro-aided fit is determined: a ``full`` ellipsoid and the rotation to the housing
        from it, the residual diagnosis of it as fitted (its own ``|m| - F``, not refitted to ``|m|`` alone; no
        effect is added: the gyro-aided model has none),
        the coverage warning saying what the gyro determined, and ``gyro`` its block.  Otherwise
        ``result`` with a warning saying what stays undetermined even with the gyro.
    """
    start = result.fit
    mis = result.misalignment
    start_values = {"hard_iron": start.hard_iron, "soft_iron": start.soft_iron, "field_norm": start.field_norm,
                    "mag_to_accel": result.mag_to_accel, "dip_deg": None if mis is None else mis.dip_deg,
                    "noise": result.noise, "fit_latency": fit_latency, "fit_gyro_matrix": fit_gyro_matrix}
    pinned = _pin_accelerometer(result, mag, accel, turns_rad, t_s, start_values)  # kept only if the fit is used
    accel = pinned.corrected_accel(accel)  # the accelerometer's own calibration: the gravity rows as the fit takes them
    try:
        g = fit_with_gyro(mag, accel, turns_rad, t_s, **start_values)
    except (GyroMismatch, np.linalg.LinAlgError) as exc:  # the present fit stands, said why
        return replace(result, warnings=result.warnings + (f"gyro-aided fit not used: {exc}",),
                       gyro={"method": "gyro", "used": False, "words": str(exc)})
    block = g.to_json()
    if not g.determined:
        return replace(result, warnings=result.warnings + (f"gyro-aided fit not used: {g.words()}",),
                       gyro=dict(block, used=False))
    fit = ellipsoid_from(g, start, mag)
    still = still_mask(accel, turns_rad, t_s)[g.inliers]
    diagnosis = diagnose_tumble(mag, fit, t_s=t_s, temp_c=temp_c, accel=accel, missing=result.coverage.missing,
                                candidates=(), refit=False)
    if diagnosis.block["unexplained"] and g.widened_covariance is not None:  # the sigmas grow to cover the structure
        naive, g = g, g.widened()
        fit = ellipsoid_from(g, start, mag)
        diagnosis = replace(diagnosis, fit=fit, block=dict(
            diagnosis.block, hard_iron_change=dict(diagnosis.block["hard_iron_change"], sigma=g.hard_iron_sigma.tolist()),
            unexplained_cost=_unexplained_cost(naive, g)))
        block = g.to_json()
    mis = misalignment_from(g, fit.calibrated(mag[g.inliers]), accel[g.inliers], still)
    diagnosis = diagnosis.with_alignment(mis, fit)
    superseded = _SUPERSEDED + ("incomplete coverage", f"the {result.ellipsoid} kind is poorly determined")
    kept = [w for w in result.warnings if not w.startswith(superseded)]
    words = [("incomplete coverage: " + result.coverage.words() + "; " if result.coverage.missing else "") + g.words()]
    if diagnosis.block["unexplained"]:
        words.append(UNEXPLAINED_WARNING)
    return replace(pinned, fit=diagnosis.fit, misalignment=mis, diagnosis=diagnosis,
                   warnings=tuple(words + kept), gyro=dict(block, used=True))
