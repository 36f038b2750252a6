"""FourFlipResult: what a four-flip calibration found, with its statistics and report."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from compass.calibration import channel_entry, header
from compass.frames import direction_sigma_deg as _direction_sigma_deg
from compass.frames import seed_angles
from compass.response import Response

from ..contract import NO_JOINT_FIT, CalibrationResult, FitStatistics, fit_report

__all__ = ["ChannelCalibration", "FourFlipResult"]
_ANGLE_KEYS = ("theta_deg", "gamma_deg", "elevation_deg", "psi_deg")


@dataclass(frozen=True)
class ChannelCalibration:
    """One channel: sensing direction in H, seed angles, response curve.

    Attributes
    ----------
    name : str
    direction : ndarray, shape (3,)
        Unit sensing direction in the housing frame H.
    direction_covariance : ndarray, shape (3, 3), or None
        None when the method gives no uncertainty (``patent``, ``harmonic``).
    response : Response
    offset_sigma, gain_sigma : float or None
        Standard errors, output units and output units per field unit.
    joint_covariance : ndarray, shape (5, 5), or None
        Joint covariance of the direction (3), offset and gain (the units above): their errors are
        correlated within a channel (a warm-up during the first flip ties the offset to the direction).
        Its marginals are ``direction_covariance``, ``offset_sigma`` and ``gain_sigma`` (widened with them when
        the diagnosis said unexplained or found a wander under an explained fit, with the platform field's prior
        when it is in); written as the channel's
        ``joint_covariance`` when finite (a parameter the fit left undetermined makes its rows NaN).
    curve_covariance : ndarray, shape (8, 8), or None
        With a nonlinear response: ``joint_covariance`` and the curve's coefficients (quadratic, cubic, quintic,
        as ``response`` holds them) after it (:meth:`calibrate.fourflip._mlfit.MLFit.curve_covariance`); the
        heading sigma's terms (:func:`calibrate.diagnosis.robust.heading_sigma_deg`).  Written as the channel's
        ``curve_joint_covariance`` beside the 5 x 5 when finite (the runtime's heading sigma then carries the
        curve's errors too; a reader before that key keeps the 5 x 5).
    """

    name: str
    direction: np.ndarray
    direction_covariance: np.ndarray | None
    response: Response
    offset_sigma: float | None = None
    gain_sigma: float | None = None
    joint_covariance: np.ndarray | None = None
    curve_covariance: np.ndarray | None = None

    @property
    def direction_sigma_deg(self) -> float | None:
        if self.direction_covariance is None:
            return None
        return float(_direction_sigma_deg(self.direction_covariance))

    @property
    def angles_deg(self) -> dict[str, float]:
        return {k: float(v) for k, v in seed_angles(self.direction).items()}

    @property
    def angles_sigma_deg(self) -> dict[str, float] | None:
        """Propagated sigma of theta, gamma, elevation, psi (large where the angle is singular)."""
        if self.direction_covariance is None or not np.all(np.isfinite(self.direction_covariance)):
            return None
        step = 1e-7
        base = np.array([seed_angles(self.direction)[k] for k in _ANGLE_KEYS])
        jac = np.empty((4, 3))
        for j in range(3):
            d = self.direction.copy()
            d[j] += step
            moved = np.array([seed_angles(d)[k] for k in _ANGLE_KEYS])
            jac[:, j] = (np.mod(moved - base + 180.0, 360.0) - 180.0) / step
        var = np.einsum("ij,jk,ik->i", jac, self.direction_covariance, jac)
        return dict(zip(_ANGLE_KEYS, np.sqrt(np.maximum(var, 0.0)).tolist()))


@dataclass(frozen=True)
class FourFlipResult(CalibrationResult):
    """A four-flip calibration.

    Attributes
    ----------
    method : str
        ``patent``, ``harmonic`` or ``ml``.
    channels : tuple of ChannelCalibration
    dip_deg, dip_sigma_deg : float, float or None
    azimuth_deg : float
        Field azimuth from the turntable zero (nuisance parameter).
    field_ut : float or None
        |B| when known; gains are then per microtesla, otherwise per |B|.
    noise : ndarray, shape (c,)
        Noise floor per channel estimated from the data, output units.
    residuals : ndarray, shape (n, c)
        Measured minus predicted output.
    parameters : dict
        Name -> (value, sigma) of every fitted parameter (ml only).
    effects : tuple of dict
        ``{"name", "parameters"}`` of effects in the model (SPEC section 4).
    warnings : tuple of str
        Plain-words problems a person should read.
    diagnosis : dict or None
        The residual diagnosis block (SPEC section 4).
    statistics : FitStatistics
        The joint fit's (``ml``: every parameter of :mod:`calibrate.fourflip._mlfit`, the effects' included);
        :data:`~calibrate.contract.NO_JOINT_FIT` for the seed's rules.
    extra : dict
        Method-specific items written under new keys (e.g. the seed's raw minima).
    kept : ndarray of bool, shape (n_recorded,), or None
        Which recorded samples the fit used (None: all); ``residuals`` has one row per kept sample.
    base_residuals : ndarray, shape (n, c), or None
        The base model's residuals when the diagnosis added effects (for the report's plot).
    """

    method: str
    channels: tuple
    dip_deg: float
    dip_sigma_deg: float | None
    azimuth_deg: float
    field_ut: float | None
    noise: np.ndarray
    residuals: np.ndarray
    parameters: dict = field(default_factory=dict)
    effects: tuple = ()
    warnings: tuple = ()
    diagnosis: dict | None = None
    statistics: FitStatistics = NO_JOINT_FIT
    extra: dict = field(default_factory=dict)
    kept: np.ndarray | None = None
    base_residuals: np.ndarray | None = None

    calibration_kind = "fourflip"

    def used(self, rec):
        """The recording as the fit saw it (spikes dropped)."""
        return rec if self.kept is None else rec.subset(self.kept)

    @property
    def residual_rms(self) -> np.ndarray:
        """Per channel, output units."""
        return np.sqrt(np.mean(self.residuals**2, axis=0))

    @property
    def directions(self) -> np.ndarray:
        return np.array([c.direction for c in self.channels])

    @property
    def field_unit(self) -> str:
        return "uT" if self.field_ut else "|B|"

    def to_json(self) -> dict:
        """The calibration file of SPEC section 2, as a JSON-ready dictionary."""
        channels = {}
        for ch in self.channels:
            joint = ch.joint_covariance
            if ch.curve_covariance is not None and np.all(np.isfinite(ch.curve_covariance)):
                joint = ch.curve_covariance
            entry = channel_entry(ch.direction, ch.response.to_json(), covariance=ch.direction_covariance,
                                  response_sigma=None if ch.offset_sigma is None else (ch.offset_sigma, ch.gain_sigma),
                                  joint_covariance=joint if joint is not None and np.all(np.isfinite(joint)) else None)
            sig = ch.angles_sigma_deg
            if sig:
                entry["angles_sigma_deg"] = sig
            channels[ch.name] = entry
        out = header("fourflip") | {
            "channels": channels,
            "dip_deg": float(self.dip_deg),
            "dip_sigma_deg": self.dip_sigma_deg,
            "field_ut": self.field_ut,
            "effects": list(self.effects),
            "diagnosis": self.diagnosis,
            "method": self.method,
            "field_azimuth_deg": float(self.azimuth_deg),
            "noise_floor": [float(v) for v in self.noise],
            "residual_rms": [float(v) for v in self.residual_rms],
            "warnings": list(self.warnings),
        }
        out.update(self.extra)
        return out

    def plots(self, recording, folder) -> list:
        """``fit.png`` (outputs against the fit) and ``residuals.png`` (before and after the diagnosis).

        Parameters
        ----------
        recording : FourFlipRecording
            The recording this result was fitted to.
        folder : path
        """
        from pathlib import Path

        from ..plots import plot_fit, plot_residuals

        folder = Path(folder)
        used = self.used(recording)
        return [plot_fit(used, self, folder / "fit.png"),
                plot_residuals(used, self._residual_sets(), folder / "residuals.png", self.noise)]

    def _residual_sets(self) -> dict:
        """Residuals before (base model) and after the diagnosis, or the one fit there is."""
        if self.base_residuals is None:
            return {self.method: self.residuals}
        return {"before (base model)": self.base_residuals,
                "after (" + ", ".join(self.diagnosis["effects"]) + ")": self.residuals}

    def report(self) -> str:
        """A fit report for a person: values with +- sigma, warnings in words."""
        unit = self.field_unit
        lines = [f"Four-flip calibration, method {self.method}"]
        dip_sigma = f" +- {self.dip_sigma_deg:.3f}" if self.dip_sigma_deg is not None and np.isfinite(self.dip_sigma_deg) else ""
        lines.append(f"  dip {self.dip_deg:.3f}{dip_sigma} deg   field azimuth from turntable zero {self.azimuth_deg:.2f} deg")
        if "dip_turntable_axis_deg" in self.extra.get("accelerometer", {}):
            lines.append("      (against gravity: the turntable's tilt measured by the accelerometer, see below)")
        else:
            lines.append("      (against the turntable axis: a turntable off level by t deg moves it by up to t, which the "
                         "sigma leaves out; level it, or record ax,ay,az)")
        if "hemisphere" in self.extra:
            lines.append(_hemisphere_line(self.extra["hemisphere"]))
        lines.append(f"  field |B| {self.field_ut:g} uT (gains per uT)" if self.field_ut else
                     "  field |B| unknown (gains per |B|; give --field-ut or '# field_ut:' to get per uT)")
        for ch, rms, noise in zip(self.channels, self.residual_rms, self.noise):
            a = ch.direction
            lines.append(f"  channel {ch.name}: direction ({a[0]:+.5f}, {a[1]:+.5f}, {a[2]:+.5f})"
                         + (f" +- {ch.direction_sigma_deg:.4f} deg" if ch.direction_sigma_deg is not None else
                            "  (no uncertainty: the seed's rule gives none)"))
            sig = ch.angles_sigma_deg or {}
            parts = []
            for key in _ANGLE_KEYS:
                text = f"{key[:-4]} {ch.angles_deg[key]:+.3f}"
                s = sig.get(key)
                if s is not None:
                    text += f" +- {s:.3f}" if s < 5.0 else " (undefined here)"
                parts.append(text)
            lines.append("      " + ", ".join(parts) + " deg")
            r = ch.response
            off = f" +- {ch.offset_sigma:.3g}" if ch.offset_sigma is not None else ""
            gain = f" +- {ch.gain_sigma:.3g}" if ch.gain_sigma is not None else ""
            lines.append(f"      response {r.model}: offset {r.offset:.6g}{off}, gain {r.gain:.6g}{gain} per {unit}"
                         f"; residual rms {rms:.3g} (noise floor {noise:.3g})")
        if "channel_health" in self.extra:
            from ..health import describe

            lines.append(describe(self.extra["channel_health"]))
        diagnosis, tail = None, []
        if self.diagnosis:
            from ..diagnosis.report import format_diagnosis

            diagnosis = format_diagnosis(self.diagnosis)
        if "accelerometer" in self.extra:
            from .accelerometer import describe_accelerometer

            tail.append(describe_accelerometer(self.extra["accelerometer"]))
        if "site_check" in self.extra:
            from ..site_field import describe

            tail.append(describe(self.extra["site_check"]))
        return fit_report(self, lines, diagnosis=diagnosis, tail=tail)


def _hemisphere_line(hemisphere: dict) -> str:
    """Which hemisphere the calibration took, from where, and how to say otherwise."""
    north = hemisphere["assumed"] == "north"
    text = (f"  hemisphere: {'northern' if north else 'southern'} (the field taken pointing {'down' if north else 'up'}"
            f", dip {'>' if north else '<'} 0), from {hemisphere['from']}")
    if hemisphere.get("default"):
        text += ("\n      the data cannot tell (a, B) from (-a, -B): a bench in the southern hemisphere needs"
                 " '# site_lat_deg: <latitude>' in the recording (or --site LAT,LON), else the dip and every"
                 " direction come back negated and the runtime's heading 180 deg off")
    return text
