"""Installation calibration: the product's hard and soft iron in H on top of a bench model.

:class:`InstallationCalibrator` reads the bench model's field from a tumble or a swing of the
product, keeps the rows that read gravity alone, fits the iron (:mod:`calibrate.installation.model`,
which writes the model down), runs the residual diagnosis (:mod:`calibrate.installation.diagnosis`)
and returns an :class:`InstallationResult`: the report, a swing's deviation card and the
installed calibration file (SPEC section 2).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from compass.axes import check_axes
from compass.installed import SOFT_IRON_ENTRIES, installed_model, soft_iron_basis
from compass.calibration import header, to_dict
from compass.io.units import note
from compass.model import SensorModel

from ..contract import CalibrationResult, Calibrator, CannotCalibrate, FitStatistics, fit_report
from .card import DeviationCard, deviation_card
from .diagnosis import UNEXPLAINED_WARNING, InstallationDiagnosis, diagnose_installation
from .model import (N_CORE, InstallationFit, Rows, debiased, fit_installation, is_level, parameter_names,
                    prior_hard_iron)

__all__ = ["InstallationCalibrator", "InstallationResult", "NOT_SEEN_BY_SWING", "PARAMETERS"]

_QUIET = 0.02  # rows whose |a| is within 2 % of g
_MIN_ROWS = 30  # fewest quiet rows fitted
_MIN_TURN_DEG = 90.0  # least turn of the field about the vertical fitted
PARAMETERS = ("hard_iron_x", "hard_iron_y", "hard_iron_z") + tuple(f"soft_iron_{e}" for e in SOFT_IRON_ENTRIES)

NOT_SEEN_BY_SWING = (
    "not seen by a swing: the accelerometer disturbed slowly (a hand-held swing's sway, about 1 s and 2 % of g):\n"
    "    it tilts the up direction the fit takes as gravity, which moves the vertical hard iron several of its\n"
    "    stated sigmas, and neither the |B| rows (the accelerometer does not enter them) nor |a| (a tilt-like\n"
    "    disturbance leaves it at g) show it, so it might not be called unexplained and its sigmas are not\n"
    "    widened; swing slowly on a turntable, or pause at rest at each heading, where that matters")
"""What a swing cannot see, in the report's words, wrapped as the report prints it (docs/benchmarks.md, the swing's
field wander section)."""

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
              "({why}); heading and tilt do not depend on it"),
}


@dataclass(frozen=True)
class InstallationResult(CalibrationResult):
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
    diagnosis : InstallationDiagnosis
        The residual diagnosis; its ``block`` is the file's ``diagnosis`` (SPEC section 4).
    n_rows : int
        Rows fitted: they read gravity alone and every channel inside the bench calibration's range.
    n_rows_out_of_range : int
        Rows that read gravity alone but some channel beyond the bench's range.
    out_of_range_fitted : bool
        Whether those rows were fitted (too few inside the range turned: the bench response is then
        extrapolated) rather than left out.
    extrapolated : str or None
        The fitted rows that read a linear channel beyond the field it was calibrated over, in words
        (kept: a line beyond its range is the same line; :mod:`compass.response`).
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
    diagnosis: InstallationDiagnosis
    n_rows: int
    n_rows_out_of_range: int
    out_of_range_fitted: bool
    extrapolated: str | None
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
    def statistics(self) -> FitStatistics:
        """The diagnosis's final fit (:func:`calibrate.installation.model.parameter_names`), against the
        bench's noise (|B|, the field-gravity angle, the heading reference, the priors)."""
        fit = self.diagnosis.fit
        return FitStatistics(parameter_names(self.diagnosis.rows, fit.effects), fit.x, fit.covariance, fit.chi2,
                             fit.dof, fit.bic(), fit.success, fit.message)

    @property
    def warnings(self) -> tuple:
        """What the rotations did not determine, and structure left unexplained, in words."""
        return tuple(f"not determined by this recording: {w}" for w in self.undetermined) + self._cautions()

    def _cautions(self) -> tuple:
        """The warnings besides what was not determined: rows left out, structure left unexplained."""
        outside = ()
        if self.out_of_range_fitted:
            outside = (f"{self.n_rows_out_of_range} rows read a field beyond the bench calibration's range on some "
                       "channel (where its response was never measured) and too few inside it turned: all were fitted, "
                       "the bench response extrapolated there (calibrate the bench in a field as strong as this one)",)
        elif self.n_rows_out_of_range:
            outside = (f"{self.n_rows_out_of_range} rows read a field beyond the bench calibration's range on some "
                       "channel (where its response was never measured): left out of the fit",)
        return (outside + ((self.extrapolated,) if self.extrapolated else ())
                + ((UNEXPLAINED_WARNING,) if self.diagnosis.unexplained else ()))

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
                "n_rows": self.n_rows, "n_rows_out_of_range": self.n_rows_out_of_range,
                "out_of_range_fitted": self.out_of_range_fitted, "extrapolated": self.extrapolated,
                "residual_rms": self.residual_rms_ut,
                "deviation_card": None if self.card_before is None else {
                    "before": self.card_before.to_json(),
                    "after": None if self.card_after is None else self.card_after.to_json()},
            },
            "dip_deg": self.dip_deg,
            "dip_sigma_deg": self.dip_sigma_deg,
            "field_ut": self.base_document.get("field_ut"),
            "effects": list(self.diagnosis.effects),
            "diagnosis": self.diagnosis.block,
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
        if self.kind == "swing":
            lines.append(f"  {NOT_SEEN_BY_SWING}")
        tail = [f"  {e['name']}: the hard iron above holds at "
                + ", ".join(f"{k} {v:.6g}" for k, v in e["reference"].items()) + " (the runtime uses it there)"
                for e in self.diagnosis.effects]
        # what was not determined is listed above, not again as warnings
        return fit_report(self, lines, warnings=self._cautions(), diagnosis=self.diagnosis.format(unit), tail=tail)

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
    base : str, Path or compass.calibration.Calibration, optional
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

    def fit(self, rec) -> InstallationResult:
        """Calibrate from an :class:`compass.io.installation.InstallationRecording`.

        Raises
        ------
        CannotCalibrate
            No bench calibration, one that is not the recording's sensor, too few quiet rows, a turn
            too small to say anything, or a true heading reference without a site.
        """
        bench, site = _bench(self.base, rec), _site(self.site, self.date)
        base, base_document = bench.model, to_dict(bench)
        missing = [c for c in base.channels if c not in rec.channels]
        extra = [c for c in rec.channels if c not in base.channels]
        if missing or extra:
            raise CannotCalibrate(f"{rec.path}: its channels ({', '.join(rec.channels)}) are not the bench "
                                  f"calibration's ({', '.join(base.channels)})")
        order = [rec.channels.index(c) for c in base.channels]
        # the bench's mag_to_accel first (and a tumble's own accelerometer calibration): the fit's up direction is
        # the housing's, as the runtime's
        accel = base.corrected_accel(bench.imu.in_model_frame(rec.accel)[0])
        rec = replace(rec, channels=base.channels, raw=rec.raw[:, order], accel=accel)
        b, in_range = base.field(rec.raw, rec.temp_c)
        a_norm = np.linalg.norm(rec.accel, axis=1)
        quiet = (np.abs(a_norm / np.median(a_norm) - 1.0) < _QUIET) & np.all(np.isfinite(b), axis=1)
        if np.sum(quiet) < _MIN_ROWS:
            raise CannotCalibrate(f"{rec.path}: only {int(np.sum(quiet))} rows read gravity alone (|a| within "
                                      f"2 % of g); turn the product slowly and record at rest")
        p = base.solver
        sigma_b = float(np.sqrt(np.trace(p @ np.diag(base.component_noise**2) @ p.T) / 3.0))
        heading_ref, declination = rec.heading_ref_deg, None
        if heading_ref is not None and rec.heading_ref_true:
            if site is None:
                raise CannotCalibrate(f"{rec.path}: heading_ref_deg is a true heading (# heading_ref: true): give "
                                          f"--site so that the declination can be taken off")
            declination = site.field().declination_deg
            heading_ref = heading_ref - declination
        u = rec.accel / a_norm[:, None]
        used, outside, fitted_outside = _rows_to_fit(quiet, in_range, b, u)
        _check_axes(rec.path, rec.accel[used], b[used], base.channels, site)
        rows = Rows(b[used], u[used], sigma_b, sigma_b / float(np.median(np.linalg.norm(b[used], axis=1))),
                    self.accel_noise_g, None if heading_ref is None else heading_ref[used], {},
                    prior_hard_iron(base.field_ut))
        turn = _turn_deg(rows.b, rows.u)
        if turn < _MIN_TURN_DEG:
            raise CannotCalibrate(f"{rec.path}: the field turned through only {turn:.0f} deg about the vertical: "
                                  f"a swing needs a full turn of heading, a tumble every orientation")
        # a level swing holds the vertical hard and soft iron at zero: the site's |B| and dip would then
        # be met by bending the horizontal soft iron instead, so they are not used as priors there
        priors = {} if is_level(rows) else _priors(base, site)
        base_fit = fit_installation(rows, (), priors)
        if rows.heading_ref is not None:  # weigh the reference by its own noise, from what the fit leaves of it
            rows = replace(rows, heading_sigma_deg=max(base_fit.heading_rms_deg, 0.01))
            base_fit = fit_installation(rows, (), priors, base_fit.x, base_fit.fixed)
        temp_c = None if rec.temp_c is None else rec.temp_c[used]
        diagnosis = diagnose_installation(rows, priors, base_fit, diagnose=self.diagnose,
                                          t_s=None if rec.t_s is None else rec.t_s[used], temp_c=temp_c)
        # the noise's second-order bias out of the final fit: along a small swing's vertical weak direction
        # it is several sigma (calibrate.installation.model's docstring); unexplained structure above the
        # floor is noise in the regressors too, and is counted (model.debiased)
        diagnosis = replace(diagnosis, fit=debiased(diagnosis.fit, diagnosis.rows, priors,
                                                    unexplained=diagnosis.block["unexplained"]))
        outside = (int(np.sum(outside)), fitted_outside, _linear_beyond(base, rec.raw[used], temp_c))
        return _result(rec, diagnosis, used, outside, priors, base, base_document, site)


def _check_axes(path, accel: np.ndarray, field_h: np.ndarray, channels, site) -> None:
    """A left-handed magnetometer-accelerometer pair (:func:`compass.axes.check_axes`): refused when the site
    says which way the field points, else a warning naming the axis to negate."""
    names = tuple(channels) if len(channels) == 3 else ("the field's x", "the field's y", "the field's z")
    verdict = check_axes(accel, field_h, site_dip_deg=None if site is None else site.field().dip_deg, names=names,
                         note_upward=True)
    if verdict is None:
        return
    if site is not None:
        raise CannotCalibrate(f"{path}: {verdict.text}")
    note(f"{path}: {verdict.text}")


def _rows_to_fit(quiet: np.ndarray, in_range: np.ndarray, b: np.ndarray, u: np.ndarray):
    """The rows to fit: ``(used, outside, outside_fitted)``.

    The bench response is known over the field it saw there: the quiet rows beyond it on some
    channel (``outside``) are left out, unless too few rows inside it turn (a site's field stronger
    than the bench's): then every quiet row is fitted, the response extrapolated (``outside_fitted``).
    """
    used, outside = quiet & in_range, quiet & ~in_range
    fitted = bool(np.any(outside) and (np.sum(used) < _MIN_ROWS or _turn_deg(b[used], u[used]) < _MIN_TURN_DEG))
    return (quiet if fitted else used), outside, fitted


def _linear_beyond(base: SensorModel, raw: np.ndarray, temp_c) -> str | None:
    """Words for the rows that read a linear channel beyond the field it was calibrated over, None if
    none (they are fitted: a line beyond its range is the same line, :mod:`compass.response`)."""
    x, _ = base.components(raw, temp_c)
    beyond = [(name, r, r.beyond_range(x[:, c]) & np.isfinite(x[:, c]))
              for c, (name, r) in enumerate(zip(base.channels, base.responses)) if not r.nonlinear]
    rows = np.any([b for *_, b in beyond], axis=0) if beyond else np.zeros(len(raw), dtype=bool)
    if not rows.any():
        return None
    names = ", ".join(f"{name} (calibrated over {r.x_range[0]:.3g}..{r.x_range[1]:.3g})"
                      for name, r, b in beyond if b.any())
    return (f"{int(rows.sum())} fitted rows read a linear channel beyond the field the bench calibrated it over: "
            f"{names}; its response extrapolated linearly")


def _bench(base, rec):
    """The bench calibration: ``base`` (path or loaded file), else the recording's ``# base:`` metadata."""
    from pathlib import Path

    from compass.calibration import Calibration, CalibrationFileError, load

    if isinstance(base, Calibration):
        bench = base
    else:
        given = "--base"
        if base is None:
            if not rec.metadata.get("base"):
                raise CannotCalibrate(f"{rec.path}: an installation is calibrated on top of a bench calibration: "
                                      f"give --base BENCH.json (or '# base: BENCH.json' in the recording)")
            given = f"{rec.path}: its '# base: {rec.metadata['base'].strip()}' line:"
            base = Path(rec.path).parent / rec.metadata["base"].strip()
        try:
            bench = load(base)
        except CalibrationFileError as exc:
            raise CannotCalibrate(f"{given} {exc}") from None
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


def _result(rec, diagnosis: InstallationDiagnosis, used, outside: tuple, priors, base, base_document,
            site) -> InstallationResult:
    fit, rows = diagnosis.fit, diagnosis.rows
    x, cov = fit.x, fit.covariance
    h, d = x[:3], x[3:9]
    soft = np.eye(3) + np.einsum("k,kij->ij", d, soft_iron_basis())
    cov9 = cov[:9, :9]
    sig = np.sqrt(np.diag(cov))
    yaw = None if rows.heading_ref is None else float(x[N_CORE])
    yaw_sigma = None if yaw is None else float(sig[N_CORE])
    undetermined = _undetermined(fit, _why_scale_free(site, base, is_level(rows)) if "field" not in priors else None)
    alignment = None if yaw is None else Rotation.from_euler("z", yaw, degrees=True).as_matrix()
    model = installed_model(base, h, soft, cov9, alignment)
    card_before = card_after = None
    if rec.kind == "swing":
        card_before, card_after = _cards(base, model, rec, used, rows, alignment)
    return InstallationResult(
        rec.kind, h, sig[:3], soft, sig[3:9], cov9, float(x[9]), float(x[10]), float(sig[10]), yaw, yaw_sigma,
        undetermined, card_before, card_after, diagnosis, int(np.sum(used)), *outside, fit.residual_rms, model,
        base_document, None if site is None else site.to_json())


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


def _undetermined(fit: InstallationFit, scale_why: str | None) -> tuple:
    """Words for what the rows did not determine: the fixed parameters, and the soft iron's scale
    when no site's |B| ties it (``scale_why``: why not, None when one does)."""
    out = [_WORDS[name] for name, fixed in zip(PARAMETERS, fit.fixed[:9]) if fixed]
    return tuple(out + ([_WORDS["scale"].format(why=scale_why)] if scale_why else []))


def _why_scale_free(site, base: SensorModel, level: bool) -> str:
    """Why no site's |B| ties the soft iron's scale, in words that say what was given."""
    if site is None:
        return "give --site to tie |B| to the WMM's"
    if level:
        return ("the site's |B| is not used on a level swing: with the vertical iron held, it would be met by "
                "bending the horizontal soft iron; swing with some heel, or tumble, to tie it")
    return ("the site's |B| is in uT but the bench calibration knows no |B| in uT (its field unit is its own |B|): "
            "calibrate the bench with field_ut to tie it")


def _cards(base: SensorModel, model: SensorModel, rec, quiet, rows: Rows, alignment):
    """Deviation cards of a swing: the bench model alone and installed, against the reference heading."""
    from compass.attitude import solve_attitude
    from compass.calibration import ImuCorrection

    accel = rec.accel[quiet]
    installed = solve_attitude(model, rec.raw[quiet], accel=ImuCorrection(alignment=alignment).apply(accel),
                               temp_c=None if rec.temp_c is None else rec.temp_c[quiet]).heading_deg
    bench = solve_attitude(base, rec.raw[quiet], accel=accel,
                           temp_c=None if rec.temp_c is None else rec.temp_c[quiet]).heading_deg
    if rows.heading_ref is not None:
        return deviation_card(bench, rows.heading_ref), deviation_card(installed, rows.heading_ref)
    return deviation_card(bench, installed), None
