"""Installation calibration: the product's hard and soft iron in H on top of a bench model.

The bench model gives the field the module sees in its housing frame, ``b = field(raw)``.  Inside
the product (SPEC section 2) that is ``b = S B_H + h``, with ``S = I + D`` (``D`` symmetric: the
induced magnetisation of soft iron; six entries) and ``h`` the hard iron.  Every row of a rotation
of the product keeps the Earth's field fixed, so with ``B_H = S^{-1} (b - h)`` and ``u`` the
accelerometer's up direction

.. math::

    r_{1,i} = \\frac{|B_{H,i}| - F}{\\sigma_b}, \\qquad
    r_{2,i} = \\frac{u_i \\cdot B_{H,i} / |B_{H,i}| + \\sin\\delta}
                   {\\sqrt{(\\sigma_b^2/|B|^2 + \\sigma_u^2)(1 - \\mu_i^2)}}

(the constancy of |B| and of the field-gravity angle; ``F``, ``delta`` the site's |B| and dip,
fitted; ``sigma_b`` is the bench's white noise and ``|B|`` in the angle's noise the median measured
one, both held fixed: a noise model that changed with ``S`` or ``F`` would let the fit buy
chi-square by flattening or shrinking the field), and with ``heading_ref_deg`` a third residual, the product's heading from the two-vector
solution (gravity first) against the reference, which also fixes the yaw of the housing in the
product (ArduPilot's large-vehicle calibration uses a known yaw the same way).  Weak priors close
the problem: ``h ~ N(0, 100 uT)``, each entry of ``D ~ N(0, 0.05)`` (a product's soft iron is a few
%), and with a site the WMM's |B| and dip with their uncertainties.  What the rotations do not
determine stays at its prior: a parameter the rows pin no better than five noise floors
is *undetermined* (held at the prior's mean), and the report says so in words.  A level swing, for instance, keeps the vertical
field constant: the vertical hard iron and the vertical soft iron ``S_zz`` then only shift and
scale a constant (the points lie on a circle, which many ellipsoids contain, down to a flat
disk); they are held at zero (:func:`_undetermined_mask`), while ``S_xz``, ``S_yz`` (symmetric ``D``)
show in the vertical channel's once-a-turn swing; the overall scale of ``S`` trades with ``F``:
without a site's |B| it is fixed by ``trace(S) = 3``.  ``scipy.optimize.least_squares`` fits all parameters together; the
covariance is ``(J^T J)^{-1}`` times the reduced chi-square when above 1.

The residual diagnosis (SPEC section 4) tries what the recording can show, a drifting hard iron
(``offset_drift``, linear in ``t_s``) and a temperature-dependent one (``temperature``, linear in
``temp_c``), keeps one when its delta-BIC is decisive (the loop's :data:`calibrate.diagnosis.evidence.DECISIVE_BIC`)
and then judges the |B| residual against the bench's noise floor (chi-square 5 sigma above its
dof: ``unexplained``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from compass.attitude import two_vector_rotation
from compass.frames import heading_pitch_roll
from compass.installed import SOFT_IRON_ENTRIES, installed_model, soft_iron_basis
from compass.calibration_file import header
from compass.model import SensorModel

from ..diagnosis.evidence import DECISIVE_BIC
from ..contract import Calibration, Calibrator, CannotCalibrate
from .card import DeviationCard, deviation_card

__all__ = ["InstallationCalibrator", "InstallationCalibration", "PARAMETERS"]

PRIOR_HARD_IRON_UT = 20.0
PRIOR_SOFT_IRON = 0.05
_TRACE_TOLERANCE = 1e-6  # without a site's |B|: trace(D) = 0 to this (a constraint, as a stiff prior)
UNDETERMINED_NOISE = 5.0
_LEVEL_DEG = 2.0  # a swing whose up direction stays this close (RMS) to its mean is level  # a parameter pinned no better than this many noise floors is held at its prior
_QUIET = 0.02  # rows whose |a| is within 2 % of g
PARAMETERS = ("hard_iron_x", "hard_iron_y", "hard_iron_z") + tuple(f"soft_iron_{e}" for e in SOFT_IRON_ENTRIES)

_WORDS = {
    "hard_iron_x": "the hard iron along X",
    "hard_iron_y": "the hard iron along Y",
    "hard_iron_z": ("the vertical hard iron (Z): the vertical field never changed, so a vertical offset only looks "
                    "like another dip and |B| (the heeling error it causes when the product tilts is not corrected)"),
    "soft_iron_xx": "the soft iron along X (S_xx)",
    "soft_iron_yy": "the soft iron along Y (S_yy)",
    "soft_iron_zz": "the vertical soft iron (S_zz): the vertical field never changed",
    "soft_iron_xy": "the horizontal cross soft iron (S_xy)",
    "soft_iron_xz": ("the field induced along X by the vertical field (S_xz): constant while the vertical field is, "
                     "so it is merged with the X hard iron (right at this site's vertical field only)"),
    "soft_iron_yz": ("the field induced along Y by the vertical field (S_yz): merged with the Y hard iron (right "
                     "at this site's vertical field only)"),
    "scale": ("the overall scale of the soft iron: it trades with |B| at the site, so trace(S) = 3 is assumed "
              "(give --site to tie |B| to the WMM's); heading and tilt do not depend on it"),
}


@dataclass(frozen=True)
class _Data:
    b: np.ndarray  # bench-model field in H, (n, 3)
    u: np.ndarray  # unit up, (n, 3)
    sigma_b: float  # white noise of each field component, field units
    sigma_dir: float  # the same over the median |b|: the field direction's noise, rad
    sigma_u: float
    heading_ref: np.ndarray | None
    effects: dict  # name -> (n,) regressor
    heading_sigma_deg: float = 0.5  # the reference's noise (re-estimated from the first fit's residual)


@dataclass(frozen=True)
class _Fit:
    x: np.ndarray
    covariance: np.ndarray
    chi2_data: float
    chi2_mag: float
    n_rows: int
    n_obs: int
    effects: tuple
    residual_rms_ut: float
    heading_rms_deg: float | None
    fixed: np.ndarray  # parameters held at the prior's mean (undetermined)


@dataclass(frozen=True)
class InstallationCalibration(Calibration):
    """The installation calibrated on top of a bench model (SPEC section 2's installed file).

    Attributes
    ----------
    kind : {"tumble", "swing"}
    hard_iron_ut, hard_iron_sigma_ut : ndarray, shape (3,)
        ``h`` in H and its 1-sigma (the base model's field units: uT when it knows |B|).
    soft_iron : ndarray, shape (3, 3)
        ``S`` in H.
    soft_iron_sigma : ndarray, shape (6,)
        1-sigma of the entries :data:`compass.installed.SOFT_IRON_ENTRIES`.
    covariance : ndarray, shape (9, 9)
        Of ``(h, D entries)``.
    field_magnitude, dip_deg, dip_sigma_deg : float
        The site's |B| (field units) and dip as the fit found them.
    yaw_deg, yaw_sigma_deg : float or None
        The housing's yaw in the product (``R_product<-housing = Rz(yaw)``), with ``heading_ref_deg``.
    undetermined : tuple of str
        What the rotations did not determine, in words.
    card_before, card_after : DeviationCard or None
        A swing's deviation card: the bench model alone, and installed (against ``heading_ref_deg``
        when recorded, else against the installed heading, so ``card_after`` is None).
    diagnosis : dict
        SPEC section 4's block.
    n_rows : int
    residual_rms_ut : float
        RMS of ``|B_H| - F`` over the rows.
    model : SensorModel
        The installed runtime model.
    base_document : dict
        The bench calibration, whole.
    site : dict or None
        SPEC's ``site`` block, when a site was given.
    """

    kind: str
    hard_iron_ut: np.ndarray
    hard_iron_sigma_ut: np.ndarray
    soft_iron: np.ndarray
    soft_iron_sigma: np.ndarray
    covariance: np.ndarray
    field_magnitude: float
    dip_deg: float
    dip_sigma_deg: float
    yaw_deg: float | None
    yaw_sigma_deg: float | None
    undetermined: tuple
    card_before: DeviationCard | None
    card_after: DeviationCard | None
    diagnosis: dict
    n_rows: int
    residual_rms_ut: float
    model: SensorModel
    base_document: dict = field(repr=False)
    site: dict | None = None

    calibration_kind = "installed"

    @property
    def parameters(self) -> dict:
        """Name -> (value, sigma): hard iron (field units), soft-iron entries, |B|, dip, yaw."""
        out = {name: (float(v), float(s)) for name, v, s in zip(
            PARAMETERS, np.concatenate([self.hard_iron_ut, _entries(self.soft_iron)]),
            np.concatenate([self.hard_iron_sigma_ut, self.soft_iron_sigma]))}
        out["field_magnitude"] = (self.field_magnitude, None)
        out["dip_deg"] = (self.dip_deg, self.dip_sigma_deg)
        if self.yaw_deg is not None:
            out["yaw_deg"] = (self.yaw_deg, self.yaw_sigma_deg)
        return out

    @property
    def warnings(self) -> tuple:
        """What the rotations did not determine, in words."""
        return tuple(f"not determined by this recording: {w}" for w in self.undetermined)

    @property
    def alignment(self) -> np.ndarray | None:
        return None if self.yaw_deg is None else Rotation.from_euler("z", self.yaw_deg, degrees=True).as_matrix()

    def to_json(self) -> dict:
        """The installed calibration file (SPEC section 2)."""
        sigma = {name: float(s) for name, s in zip(PARAMETERS, np.sqrt(np.diag(self.covariance)))}
        out = header("installed") | {
            "base": self.base_document,
            "installation": {
                "kind": self.kind,
                "hard_iron_ut": self.hard_iron_ut.tolist(),
                "soft_iron": self.soft_iron.tolist(),
                "alignment": None if self.alignment is None else self.alignment.tolist(),
                "yaw_deg": self.yaw_deg, "yaw_sigma_deg": self.yaw_sigma_deg,
                "sigma": sigma,
                "covariance": self.covariance.tolist(),
                "parameters": list(PARAMETERS),
                "undetermined": list(self.undetermined),
                "field_magnitude": self.field_magnitude, "dip_deg": self.dip_deg, "dip_sigma_deg": self.dip_sigma_deg,
                "n_rows": self.n_rows, "residual_rms": self.residual_rms_ut,
                "deviation_card": None if self.card_before is None else {
                    "before": self.card_before.to_json(),
                    "after": None if self.card_after is None else self.card_after.to_json()},
            },
            "dip_deg": self.dip_deg,
            "dip_sigma_deg": self.dip_sigma_deg,
            "field_ut": self.base_document.get("field_ut"),
            "diagnosis": self.diagnosis,
        }
        if self.site is not None:
            out["site"] = self.site
        return out

    def report(self) -> str:
        """A human-readable fit report: values +- sigma, what is undetermined, the card, the diagnosis."""
        unit = "uT" if self.base_document.get("field_ut") else "x |B_bench|"
        h, hs = self.hard_iron_ut, self.hard_iron_sigma_ut
        lines = [f"Installation calibration ({self.kind}, {self.n_rows} rows) on top of the bench model",
                 f"  hard iron in H: x {h[0]:+.3f} +- {hs[0]:.3f}, y {h[1]:+.3f} +- {hs[1]:.3f}, "
                 f"z {h[2]:+.3f} +- {hs[2]:.3f} {unit}",
                 "  soft iron S - I (entries " + ", ".join(
                     f"{e} {v:+.4f} +- {s:.4f}" for e, v, s in zip(SOFT_IRON_ENTRIES, _entries(self.soft_iron),
                                                                  self.soft_iron_sigma)) + ")",
                 f"  field at the site: |B| {self.field_magnitude:.3f} {unit}, dip {self.dip_deg:.3f} +- "
                 f"{self.dip_sigma_deg:.3f} deg; |B| residual {self.residual_rms_ut:.3f} {unit} RMS"]
        if self.yaw_deg is not None:
            lines.append(f"  yaw of the housing in the product: {self.yaw_deg:+.3f} +- {self.yaw_sigma_deg:.3f} deg")
        if self.undetermined:
            lines.append("  not determined by this recording (held at the prior; the sigmas say how little is known):")
            lines += [f"    - {w}" for w in self.undetermined]
        if self.card_before is not None:
            lines.append(f"  deviation card, bench model only: {self.card_before.line()}")
            if self.card_after is not None:
                lines.append(f"  deviation card, installed:        {self.card_after.line()}")
        d = self.diagnosis
        lines.append(f"  diagnosis: effects {', '.join(d['effects']) or 'none'}; |B| residual {d['residual_rms_before']:.3f}"
                     f" -> {d['residual_rms_after']:.3f} against a noise floor of {d['noise_floor']:.3f}; "
                     f"unexplained {d['unexplained']}")
        for e in d.get("effect_parameters", []):
            (key, values), (_, sigmas) = e["parameters"].items()
            ref = ", ".join(f"{k} {v:.6g}" for k, v in e["reference"].items())
            per = {"hard_iron_ut_per_s": "s", "hard_iron_ut_per_c": "degC"}[key]
            lines.append(f"    {e['name']}: hard iron change "
                         + ", ".join(f"{a} {v:+.4g} +- {sv:.2g}" for a, v, sv in zip("xyz", values, sigmas))
                         + f" uT per {per}; the hard iron above is at {ref} (the runtime uses it there)")
        lines += [f"    {line}" for line in d.get("remarks", [])]
        return "\n".join(lines)

    def plots(self, recording=None, folder=".") -> list:
        """Write the deviation card (a swing) into ``folder``; returns the paths written."""
        from pathlib import Path

        from .card import plot_cards

        if self.card_before is None:
            return []
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / "deviation_card.png"
        plot_cards(self.card_before, self.card_after, path,
                   f"Deviation card of the {self.kind} ({'against heading_ref_deg' if self.card_after is not None else 'against the installed heading'})")
        return [path]


def _entries(soft: np.ndarray) -> np.ndarray:
    d = soft - np.eye(3)
    return np.array([d[0, 0], d[1, 1], d[2, 2], d[0, 1], d[0, 2], d[1, 2]])


class InstallationCalibrator(Calibrator):
    """Fit the installation of a bench-calibrated module in its product (module docstring).

    Parameters
    ----------
    base : str, Path or compass.calibration_file.CalibrationFile, optional
        The bench calibration (``--base``); default the recording's ``# base:`` metadata (a path
        relative to the recording).
    site : str or compass.site.Site, optional
        Where the installation was recorded (``LAT,LON[,ALT_M]``): the WMM's |B| and dip become
        priors, the ``site`` block is written, and a true ``heading_ref_deg`` is turned magnetic.
    date : str, optional
        With ``site``: the day, ``YYYY-MM-DD`` (default today, UTC).
    accel_noise_g : float
        Accelerometer white noise per axis, fraction of g.
    diagnose : bool
        Run the residual diagnosis.
    """

    kind = "installed"
    plot_files = ("deviation_card.png",)

    def __init__(self, *, base=None, site=None, date=None, accel_noise_g: float = 0.002, diagnose: bool = True):
        self.base = base
        self.site = site
        self.date = date
        self.accel_noise_g = accel_noise_g
        self.diagnose = diagnose

    def fit(self, rec) -> InstallationCalibration:
        """Calibrate from an :class:`compass.io.installation.InstallationRecording`.

        Raises
        ------
        CannotCalibrate
            No bench calibration, one that is not the recording's sensor, too few quiet rows, a turn
            too small to say anything, or a true heading reference without a site.
        """
        bench, site = _bench(self.base, rec), _site(self.site, self.date)
        base, base_document = bench.model, bench.data
        missing = [c for c in base.channels if c not in rec.channels]
        extra = [c for c in rec.channels if c not in base.channels]
        if missing or extra:
            raise CannotCalibrate(f"{rec.path}: its channels ({', '.join(rec.channels)}) are not the bench "
                                  f"calibration's ({', '.join(base.channels)})")
        order = [rec.channels.index(c) for c in base.channels]
        rec = replace(rec, channels=base.channels, raw=rec.raw[:, order])
        b, in_range = base.field(rec.raw, rec.temp_c)
        a_norm = np.linalg.norm(rec.accel, axis=1)
        quiet = (np.abs(a_norm / np.median(a_norm) - 1.0) < _QUIET) & np.all(np.isfinite(b), axis=1)
        if np.sum(quiet) < 30:
            raise CannotCalibrate(f"{rec.path}: only {int(np.sum(quiet))} rows read gravity alone (|a| within "
                                      f"2 % of g); turn the product slowly and record at rest")
        p = base.solver
        sigma_b = float(np.sqrt(np.trace(p @ np.diag(base.component_noise**2) @ p.T) / 3.0))
        u = rec.accel / a_norm[:, None]
        heading_ref, declination = rec.heading_ref_deg, None
        if heading_ref is not None and rec.heading_ref_true:
            if site is None:
                raise CannotCalibrate(f"{rec.path}: heading_ref_deg is a true heading (# heading_ref: true): give "
                                          f"--site so that the declination can be taken off")
            declination = site.field().declination_deg
            heading_ref = heading_ref - declination
        effects = {}
        if rec.t_s is not None and np.ptp(rec.t_s[quiet]) > 0:
            t = rec.t_s[quiet]
            effects["offset_drift"] = (t - t.mean()) / np.ptp(t)
        if rec.temp_c is not None and np.ptp(rec.temp_c[quiet]) > 0.5:
            effects["temperature"] = rec.temp_c[quiet] - rec.temp_c[quiet].mean()
        data = _Data(b[quiet], u[quiet], sigma_b, sigma_b / float(np.median(np.linalg.norm(b[quiet], axis=1))),
                     self.accel_noise_g,
                     None if heading_ref is None else heading_ref[quiet], effects)
        turn = _turn_deg(data.b, data.u)
        if turn < 90.0:
            raise CannotCalibrate(f"{rec.path}: the field turned through only {turn:.0f} deg about the vertical: "
                                      f"a swing needs a full turn of heading, a tumble every orientation")
        # a level swing holds the vertical hard and soft iron at zero: the site's |B| and dip would then
        # be met by bending the horizontal soft iron instead, so they are not used as priors there
        priors = {} if _is_level(data) else _priors(base, site)
        base_fit = _fit(data, (), priors)
        if data.heading_ref is not None:  # weigh the reference by its own noise, from what the fit leaves of it
            data = replace(data, heading_sigma_deg=max(base_fit.heading_rms_deg, 0.01))
            base_fit = _fit(data, (), priors, base_fit.x, base_fit.fixed)
        current, steps, remarks = base_fit, [{"model": "base", "residual_rms": base_fit.residual_rms_ut}], []
        if self.diagnose:
            current, steps, remarks = _diagnose(data, priors, base_fit, steps)
        return _result(rec, data, current, steps, remarks, quiet, in_range, priors, base, base_document, site)

def _bench(base, rec):
    """The bench calibration: ``base`` (path or loaded file), else the recording's ``# base:`` metadata."""
    from pathlib import Path

    from compass.calibration_file import CalibrationFile, CalibrationFileError, load

    if isinstance(base, CalibrationFile):
        bench = base
    else:
        if base is None:
            if not rec.metadata.get("base"):
                raise CannotCalibrate(f"{rec.path}: an installation is calibrated on top of a bench calibration: "
                                      f"give --base BENCH.json (or '# base: BENCH.json' in the recording)")
            base = Path(rec.path).parent / rec.metadata["base"].strip()
        try:
            bench = load(base)
        except CalibrationFileError as exc:
            raise CannotCalibrate(f"--base {exc}") from None
    if bench.kind == "installed":
        raise CannotCalibrate(f"{bench.path}: already an installed calibration; give the bench calibration as --base")
    if bench.model.noise is None:
        raise CannotCalibrate(f"{bench.path}: the bench calibration has no noise_floor: the rows cannot be weighted")
    return bench


def _site(site, date):
    from compass.site import Site

    if site is None:
        if date is not None:
            raise CannotCalibrate("--date needs --site LAT,LON[,ALT_M]: the date only chooses the field at a site")
        return None
    try:
        return site if isinstance(site, Site) else Site.parse(site, date)
    except ValueError as exc:
        raise CannotCalibrate(str(exc)) from None


def _priors(base: SensorModel, site) -> dict:
    priors = {}
    if site is not None:
        f = site.field()
        if base.field_ut is not None:
            priors["field"] = (f.field_ut, f.field_sigma_ut)
        priors["dip"] = (f.dip_deg, f.dip_sigma_deg)
    return priors


def _result(rec, data, fit, steps, remarks, quiet, in_range, priors, base, base_document,
            site) -> InstallationCalibration:
    x, cov = fit.x, fit.covariance
    h, d = x[:3], x[3:9]
    soft = np.eye(3) + np.einsum("k,kij->ij", d, soft_iron_basis())
    cov9 = cov[:9, :9]
    sig = np.sqrt(np.diag(cov))
    yaw = None if data.heading_ref is None else float(x[11])
    yaw_sigma = None if yaw is None else float(sig[11])
    undetermined = _undetermined(fit, scale_free="field" not in priors)
    alignment = None if yaw is None else Rotation.from_euler("z", yaw, degrees=True).as_matrix()
    model = installed_model(base, h, soft, cov9, alignment)
    card_before = card_after = None
    if rec.kind == "swing":
        card_before, card_after = _cards(base, model, rec, quiet, data, alignment)
    noise_floor = data.sigma_b
    dof = fit.n_rows - 1
    unexplained = bool(fit.chi2_mag > dof + 5.0 * np.sqrt(2.0 * dof))
    remarks = list(remarks)
    if unexplained:
        remarks.append("the |B| residual stays above the bench's noise floor: structure the installation model "
                       "does not explain (a nonlinear or field-dependent iron, a field that changed during the "
                       "recording, or a bench model that does not fit this sensor)")
    diagnosis = {"noise_floor": noise_floor,
                 "effect_parameters": _effect_parameters(rec, quiet, data, fit, sig),
                 "noise_floor_source": "the bench calibration's channel noise, through its sensing matrix",
                 "steps": steps, "effects": list(fit.effects),
                 "residual_rms_before": steps[0]["residual_rms"], "residual_rms_after": fit.residual_rms_ut,
                 "unexplained": unexplained, "remarks": remarks,
                 "rows_used": int(np.sum(quiet)), "rows_out_of_range": int(np.sum(~in_range))}
    return InstallationCalibration(
        rec.kind, h, sig[:3], soft, sig[3:9], cov9, float(x[9]), float(x[10]), float(sig[10]), yaw, yaw_sigma,
        undetermined, card_before, card_after, diagnosis, int(np.sum(quiet)), fit.residual_rms_ut, model,
        base_document, None if site is None else site.to_json())


def _effect_parameters(rec, quiet, data: _Data, fit: _Fit, sig: np.ndarray) -> list[dict]:
    """The claimed effects' fitted hard-iron change in H with sigmas, per second of ``t_s`` or per degC of
    ``temp_c``; ``hard_iron_ut`` is the hard iron at each effect's reference (the quiet rows' mean)."""
    *_, extra = _split(fit.x, data, fit.effects)
    first = 12 if data.heading_ref is not None else 11
    entries = []
    for i, (name, g) in enumerate(extra.items()):
        s3 = sig[first + 3 * i:first + 3 * i + 3]
        if name == "offset_drift":  # regressor (t - mean) / span
            t = rec.t_s[quiet]
            span = float(np.ptp(t))
            entries.append({"name": name, "form": "linear in t_s", "reference": {"t_s": float(t.mean())},
                            "parameters": {"hard_iron_ut_per_s": (g / span).tolist(),
                                           "hard_iron_ut_per_s_sigma": (s3 / span).tolist()}})
        else:  # temperature: regressor temp_c - mean
            entries.append({"name": name, "form": "linear in temp_c",
                            "reference": {"temp_c": float(rec.temp_c[quiet].mean())},
                            "parameters": {"hard_iron_ut_per_c": g.tolist(), "hard_iron_ut_per_c_sigma": s3.tolist()}})
    return entries


def _turn_deg(b: np.ndarray, u: np.ndarray) -> float:
    """Span of the field's azimuth about the up direction (the largest gap subtracted from 360), degrees."""
    east = np.cross(u, b)  # horizontal, perpendicular to the field's horizontal part
    ref = np.array([1.0, 0.0, 0.0]) if abs(np.mean(u, axis=0)[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x_axis = ref - np.einsum("ij,j->i", u, ref)[:, None] * u
    x_axis /= np.linalg.norm(x_axis, axis=1, keepdims=True)
    y_axis = np.cross(u, x_axis)
    azimuth = np.sort(np.degrees(np.arctan2(np.einsum("ij,ij->i", east, y_axis), np.einsum("ij,ij->i", east, x_axis))))
    gaps = np.diff(np.concatenate([azimuth, azimuth[:1] + 360.0]))
    return float(360.0 - gaps.max())


def _split(x: np.ndarray, data: _Data, effects: tuple):
    h, d, f, dip = x[:3], x[3:9], x[9], x[10]
    k = 11
    yaw = None
    if data.heading_ref is not None:
        yaw, k = x[11], 12
    extra = {name: x[k + 3 * i:k + 3 * i + 3] for i, name in enumerate(effects)}
    return h, d, f, dip, yaw, extra


def _field_h(x: np.ndarray, data: _Data, effects: tuple) -> np.ndarray:
    h, d, *_, extra = _split(x, data, effects)
    soft = np.eye(3) + np.einsum("k,kij->ij", d, soft_iron_basis())
    offset = h + sum(data.effects[name][:, None] * g[None, :] for name, g in extra.items())
    return np.linalg.solve(soft, (data.b - offset).T).T


def _residuals(x: np.ndarray, data: _Data, effects: tuple, priors: dict) -> np.ndarray:
    """Whitened residuals: |B| and field-gravity angle per row, the heading reference per row when
    recorded, then the priors (module docstring)."""
    h, d, f, dip, yaw, _ = _split(x, data, effects)
    bh = _field_h(x, data, effects)
    nb = np.linalg.norm(bh, axis=1)
    # the noise is held at the bench's (S is near I): a noise model that changed with S or |B| would let the
    # fit buy chi-square by flattening or shrinking the field
    mu = np.einsum("ij,ij->i", bh, data.u) / nb
    parts = [(nb - f) / data.sigma_b,
             (mu + np.sin(np.radians(dip))) / np.sqrt((data.sigma_dir**2 + data.sigma_u**2)
                                                     * np.maximum(1.0 - mu**2, 1e-6))]
    if yaw is not None:
        heading = _product_heading(data.u, bh, dip, yaw)
        parts.append((np.mod(heading - data.heading_ref + 180.0, 360.0) - 180.0) / data.heading_sigma_deg)
    parts.append(h / PRIOR_HARD_IRON_UT)
    parts.append(d / PRIOR_SOFT_IRON)
    if "field" in priors:
        parts.append(np.atleast_1d((f - priors["field"][0]) / priors["field"][1]))
    else:  # the scale of S trades with |B|: fixed by trace(S) = 3
        parts.append(np.atleast_1d((d[0] + d[1] + d[2]) / _TRACE_TOLERANCE))
    if "dip" in priors:
        parts.append(np.atleast_1d((dip - priors["dip"][0]) / priors["dip"][1]))
    return np.concatenate(parts)


def _product_heading(u, bh, dip, yaw) -> np.ndarray:
    """Heading of the product's forward axis: two-vector (gravity first) in H, turned by the yaw."""
    housing = two_vector_rotation(u, bh, dip, 0.0)
    return heading_pitch_roll(housing * Rotation.from_euler("z", -yaw, degrees=True))[0]


def _fit(data: _Data, effects: tuple, priors: dict, start: np.ndarray | None = None,
         fixed: np.ndarray | None = None) -> _Fit:
    """Least-squares fit; parameters in ``fixed`` (a mask, default: those the rows cannot determine,
    :func:`_undetermined_mask`) stay at their start (the prior's mean, zero)."""
    nb = np.linalg.norm(data.b, axis=1)
    if start is None:
        dip0 = float(np.degrees(np.arcsin(np.clip(-np.median(np.einsum("ij,ij->i", data.b, data.u) / nb), -1, 1))))
        start = np.concatenate([np.zeros(9), [np.median(nb), dip0]])
        if data.heading_ref is not None:
            bench = _product_heading(data.u, data.b, dip0, 0.0)
            diff = np.radians(data.heading_ref - bench)
            start = np.append(start, np.degrees(np.arctan2(np.mean(np.sin(diff)), np.mean(np.cos(diff)))))
        start = np.concatenate([start, np.zeros(3 * len(effects))])
    if fixed is None:
        fixed = _undetermined_mask(data, effects, priors, start)
    free = ~fixed

    def residuals(x_free):
        x = start.copy()
        x[free] = x_free
        return _residuals(x, data, effects, priors)

    lower = np.concatenate([[-500.0] * 3, [-0.5] * 6, [1e-6, -90.0], [-np.inf] * (len(x0 := start) - 11)])
    upper = np.concatenate([[500.0] * 3, [0.5] * 6, [np.inf, 90.0], [np.inf] * (len(x0) - 11)])
    result = least_squares(residuals, start[free], x_scale="jac", method="trf", bounds=(lower[free], upper[free]))
    x = start.copy()
    x[free] = result.x
    n = len(data.b)
    data_rows = result.fun[: (3 if data.heading_ref is not None else 2) * n]
    chi2 = float(data_rows @ data_rows)
    n_obs = len(data_rows)
    # every parameter's uncertainty, the held ones at their prior's, which the fitted ones inherit
    # through their sensitivity to them (a level swing's horizontal hard iron carries S_xz times the
    # unknown vertical field): cov = C_f + K P_h K^T, K = -(J_f^T J_f)^-1 J_f^T J_h
    jac = _jacobian(x, data, effects, priors)
    scale = max(1.0, chi2 / max(n_obs - int(free.sum()), 1))
    c_free = np.linalg.pinv(jac[:, free].T @ jac[:, free])
    k = np.zeros((len(x), int(fixed.sum())))
    k[free] = -c_free @ jac[:, free].T @ jac[:, fixed]
    k[fixed] = np.eye(int(fixed.sum()))
    held = (np.array([PRIOR_HARD_IRON_UT] * 3 + [PRIOR_SOFT_IRON] * 6 + [0.0] * (len(x) - 9)) ** 2)[fixed]
    cov = k @ np.diag(held) @ k.T
    cov[np.ix_(free, free)] += c_free * scale
    bh = _field_h(x, data, effects)
    mag = np.linalg.norm(bh, axis=1) - x[9]
    heading_rms = None
    if data.heading_ref is not None:
        heading_rms = float(np.sqrt(np.mean((result.fun[2 * n:3 * n] * data.heading_sigma_deg) ** 2)))
    return _Fit(x, cov, chi2, float(np.sum((mag / data.sigma_b) ** 2)), n, n_obs, tuple(effects),
                float(np.sqrt(np.mean(mag**2))), heading_rms, fixed)


def _jacobian(x: np.ndarray, data: _Data, effects: tuple, priors: dict) -> np.ndarray:
    """Forward-difference Jacobian of :func:`_residuals` (priors included) in every parameter."""
    base = _residuals(x, data, effects, priors)
    step = np.concatenate([np.full(3, 1e-3), np.full(6, 1e-5), [1e-3, 1e-4], np.full(len(x) - 11, 1e-4)])
    return np.column_stack([(_residuals(x + h * e, data, effects, priors) - base) / h
                            for h, e in zip(step, np.eye(len(x)))])


def _undetermined_mask(data: _Data, effects: tuple, priors: dict, x: np.ndarray) -> np.ndarray:
    """Hard and soft iron parameters the rows cannot determine, held at the prior's mean (zero).

    A swing that stays level within 2 degrees RMS never changes the vertical field: its vertical
    hard iron and ``S_zz`` are held (the classical swing's blind spot; the small rocking of a real
    swing would otherwise "determine" them from noise, pulled by whatever the other is held at).
    Then, linearised at ``x``, the parameter the rows pin worst is held while some are pinned no
    better than :data:`UNDETERMINED_NOISE` noise floors (a hard-iron component to ``5 sigma_b``, a
    soft-iron entry to ``5 sigma_b / |B|``): a flat direction can span several parameters.
    """
    mask = np.zeros(len(x), dtype=bool)
    if _is_level(data):
        mask[[2, 5]] = True  # hard_iron_z, soft_iron_zz
    jac = _jacobian(x, data, effects, priors)
    limit = UNDETERMINED_NOISE * data.sigma_b * np.array([1.0] * 3 + [1.0 / x[9]] * 6)
    while True:
        free = ~mask
        cov = np.linalg.pinv(jac[:, free].T @ jac[:, free])
        ratio = np.zeros(len(x))
        ratio[free] = np.sqrt(np.diag(cov)) / np.concatenate([limit, np.full(len(x) - 9, np.inf)])[free]
        worst = int(np.argmax(ratio))
        if ratio[worst] <= 1.0:
            return mask
        mask[worst] = True


def _is_level(data: _Data) -> bool:
    """The up direction stays within :data:`_LEVEL_DEG` (RMS) of its mean: a level swing."""
    mean_up = data.u.mean(axis=0)
    mean_up /= np.linalg.norm(mean_up)
    return bool(np.sqrt(np.mean(np.arccos(np.clip(data.u @ mean_up, -1.0, 1.0)) ** 2)) < np.radians(_LEVEL_DEG))


def _bic(fit: _Fit) -> float:
    return fit.chi2_data + len(fit.x) * np.log(fit.n_obs)


def _diagnose(data: _Data, priors: dict, base: _Fit, steps: list):
    """Add a drifting or temperature-dependent hard iron while the evidence is decisive; the
    candidates tried and not decisive are named with their delta-BIC."""
    current, remarks = base, []
    for _ in range(len(data.effects)):
        trials = []
        for name in data.effects:
            if name in current.effects:
                continue
            effects = current.effects + (name,)
            trial = _fit(data, effects, priors, np.concatenate([current.x, np.zeros(3)]),
                         np.concatenate([current.fixed, np.zeros(3, dtype=bool)]))
            trials.append((_bic(current) - _bic(trial), name, trial))
        if not trials:
            break
        gain, name, trial = max(trials, key=lambda t: t[0])
        if gain <= DECISIVE_BIC:
            remarks += [f"{n} tried: delta-BIC {g:.1f}, not decisive (above {DECISIVE_BIC:g} is)" for g, n, _ in trials]
            break
        words = {"offset_drift": "the hard iron drifts with time (linear in t_s)",
                 "temperature": "the hard iron changes with temp_c (linear)"}[name]
        steps.append({"added": name, "residual_rms": trial.residual_rms_ut, "delta_bic": float(gain),
                      "evidence": f"{words}: chi2 {current.chi2_data:.0f} -> {trial.chi2_data:.0f} for 3 parameters"})
        current = trial
    return current, steps, remarks


def _undetermined(fit: _Fit, scale_free: bool) -> tuple:
    """Words for what the rows did not determine: the fixed parameters, and the soft iron's scale
    when no site's |B| ties it."""
    out = [_WORDS[name] for name, fixed in zip(PARAMETERS, fit.fixed[:9]) if fixed]
    return tuple(out + ([_WORDS["scale"]] if scale_free else []))


def _cards(base: SensorModel, model: SensorModel, rec, quiet, data: _Data, alignment):
    """Deviation cards of a swing: the bench model alone and installed, against the reference heading."""
    from compass.attitude import solve_attitude
    from compass.installed import accel_to_product

    doc = {"model": "installed", "installation": {"alignment": None if alignment is None else alignment.tolist()}}
    accel = rec.accel[quiet]
    installed = solve_attitude(model, rec.raw[quiet], accel=accel_to_product(doc, accel),
                               temp_c=None if rec.temp_c is None else rec.temp_c[quiet]).heading_deg
    bench = solve_attitude(base, rec.raw[quiet], accel=accel,
                           temp_c=None if rec.temp_c is None else rec.temp_c[quiet]).heading_deg
    if data.heading_ref is not None:
        return deviation_card(bench, data.heading_ref), deviation_card(installed, data.heading_ref)
    return deviation_card(bench, installed), None
