"""Is each channel a working sensor?  The checks every kind runs on its fit, before a file is written.

A least-squares fit calibrates whatever it is given.  Three defects of a module come back from it
with plausible numbers and no word, although a calibration bench's first job is to say a module is bad:

- **a dead channel** (a constant output plus noise): its fitted response is within a few sigma of
  zero and its direction sigma is tens of degrees.  Refused (:class:`~calibrate.contract.CannotCalibrate`):
  no heading can be read from it.
- **a drowned channel** (a broken front end, 20 times its neighbours' noise): the fit is right, only
  noisier, and the pooled residual test calls it explained.  Its signal-to-noise ratio (the response
  to the whole field over the noise of one sample) is stated for every channel, and a channel far
  below the others' is warned about.
- **a gross mounting error** (a channel 20 deg off its housing axis): the fit is right, and the angles
  show it to whoever reads them.  Each channel's angle from the nearest housing axis is stated and
  warned about above a tolerance (an option, for designs with oblique channels).

Each kind describes its channels as :class:`ChannelHealth` records and calls :func:`check_channels`;
the file keeps every figure under ``"channel_health"`` (:func:`to_json`), and the runtime refuses a
file whose channel's gain is within :data:`DEAD_SIGMAS` of its sigma (:func:`compass.calibration.load`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from compass.calibration import DEAD_RESPONSE_SIGMAS

from .contract import CannotCalibrate

__all__ = ["AXIS_TOLERANCE_DEG", "ChannelHealth", "check_channels", "describe", "to_json"]

DEAD_SIGMAS = DEAD_RESPONSE_SIGMAS
"""A response smaller than this many of its own standard errors is not distinguishable from zero: at
5 sigma a working channel is called dead with a chance of 3e-7 (one-sided Gaussian).  The runtime's
file check uses the same number (:data:`compass.calibration.DEAD_RESPONSE_SIGMAS`)."""

DEAD_DIRECTION_SIGMA_DEG = 10.0
"""A direction known no better than this is no sensing direction.  A direction's sigma is about the
response's relative sigma in radians, so this is the same test as :data:`DEAD_SIGMAS` (1/5 rad = 11 deg)
for the kinds that give a direction sigma but no response sigma."""

DROWNED_RATIO = 4.0
"""A channel whose signal-to-noise ratio is below the other channels' median by this factor (12 dB)
is warned about.  Channels of one module differ in gain and noise by tens of percent; a factor of 4 is
a broken front end, a wrong gain setting or a different part fitted."""

AXIS_TOLERANCE_DEG = 10.0
"""Default angle from the nearest housing axis above which a channel is warned about.  Channels
placed by hand on a board or a cube are off their axes by 1-3 deg RMS (the four-flip simulator draws
3 deg RMS: a channel beyond 10 deg happens once in 10^4 modules there); 10 deg is a gross error."""

_AXES = ("+X", "+Y", "+Z")


@dataclass(frozen=True)
class ChannelHealth:
    """What tells a working channel from a broken one.

    Attributes
    ----------
    name : str
        The channel's column.
    response : float
        The channel's output for the whole field along its sensing direction, minus its zero-field
        output (gain times |B|), output units.
    response_sigma : float
        Standard error of ``response``, output units.
    noise : float
        White noise of one sample, output units.
    direction : ndarray, shape (3,), or None
        Unit sensing direction in the housing frame H (None: the kind fixes no housing frame).
    direction_sigma_deg : float or None
        The direction's standard error, deg.
    """

    name: str
    response: float
    response_sigma: float
    noise: float
    direction: np.ndarray | None = None
    direction_sigma_deg: float | None = None

    @property
    def snr(self) -> float:
        """Signal-to-noise ratio: :attr:`response` over :attr:`noise` (one sample)."""
        return float(abs(self.response) / self.noise) if self.noise > 0 else float("inf")

    @property
    def snr_db(self) -> float:
        return float(20.0 * np.log10(self.snr)) if self.snr > 0 else float("-inf")

    @property
    def response_sigmas(self) -> float:
        """How many standard errors the response is from zero."""
        return float(abs(self.response) / self.response_sigma) if self.response_sigma > 0 else float("inf")

    @property
    def nearest_axis(self) -> tuple[str, float] | None:
        """The housing axis nearest the sensing direction (``"+X"`` .. ``"-Z"``) and the angle to it, deg."""
        if self.direction is None:
            return None
        a = np.asarray(self.direction, float) / np.linalg.norm(self.direction)
        i = int(np.argmax(np.abs(a)))
        sign = "+" if a[i] >= 0 else "-"
        return sign + _AXES[i][1], float(np.degrees(np.arccos(min(abs(a[i]), 1.0))))

    @property
    def dead(self) -> bool:
        """The response is not distinguishable from zero."""
        return (self.response_sigmas < DEAD_SIGMAS
                or (self.direction_sigma_deg is not None and not self.direction_sigma_deg <= DEAD_DIRECTION_SIGMA_DEG))


def check_channels(path, channels, *, axis_tolerance_deg: float | None = AXIS_TOLERANCE_DEG,
                   direction_accuracy_deg: float | None = None) -> tuple[str, ...]:
    """Refuse a dead channel; warn about a drowned one and one far from its housing axis.

    Parameters
    ----------
    path : str
        The recording, for the messages.
    channels : sequence of ChannelHealth
    axis_tolerance_deg : float or None
        Warn when a channel is farther than this from the nearest housing axis (None: never).
    direction_accuracy_deg : float, optional
        The direction accuracy the user needs: a channel whose direction sigma is larger is warned
        about, with the signal-to-noise ratio that would reach it.

    Returns
    -------
    tuple of str
        Warnings, in words.

    Raises
    ------
    CannotCalibrate
        A channel's response is not distinguishable from zero (naming it and its figures).
    """
    channels = list(channels)
    for ch in channels:
        if ch.dead:
            others = [o.snr for o in channels if o is not ch]
            beside = f" (the other channels' {_ratio(float(np.median(others)))})" if others else ""
            sigma = (f", direction +- {ch.direction_sigma_deg:.3g} deg" if ch.direction_sigma_deg is not None else "")
            figures = (f"its response {ch.response:.3g} +- {ch.response_sigma:.2g} output units is "
                       f"{ch.response_sigmas:.1f} sigma from zero{sigma}, signal-to-noise {_ratio(ch.snr)}{beside}")
            if ch.response_sigmas >= DEAD_SIGMAS:  # it responds: the fit cannot place its direction
                raise CannotCalibrate(f"{path}: channel '{ch.name}' responds to the field but its direction is not "
                                      f"determined: {figures}: the recording's angles are not what the model can "
                                      "follow (a flip's turntable counting the other way or read from another "
                                      "reference, flips mislabelled) or the sensor is far from linear: check the "
                                      "recording's platform_deg and flip_deg before the sensor")
            raise CannotCalibrate(f"{path}: channel '{ch.name}' does not respond to the field: {figures}: a dead or "
                                  "disconnected sensor")
    warnings = []
    for ch in channels:
        others = [o.snr for o in channels if o is not ch]
        if others and ch.snr * DROWNED_RATIO < float(np.median(others)):
            warnings.append(f"channel {ch.name}: signal-to-noise {_ratio(ch.snr)}, against "
                            f"{_ratio(float(np.median(others)))} for the other channels: its noise "
                            f"({ch.noise:.3g} output units) is that of a broken front end, a wrong gain setting or "
                            "another part; its direction is calibrated, with that much larger a sigma")
        if direction_accuracy_deg is not None and ch.direction_sigma_deg is not None \
                and ch.direction_sigma_deg > direction_accuracy_deg:
            needed = ch.snr * ch.direction_sigma_deg / direction_accuracy_deg
            warnings.append(f"channel {ch.name}: direction +- {ch.direction_sigma_deg:.3g} deg at signal-to-noise "
                            f"{_ratio(ch.snr)}; {direction_accuracy_deg:g} deg needs {_ratio(needed)} (or "
                            f"{(ch.direction_sigma_deg / direction_accuracy_deg) ** 2:.0f} times the samples)")
        axis = ch.nearest_axis
        if axis is not None and axis_tolerance_deg is not None and axis[1] > axis_tolerance_deg:
            warnings.append(f"channel {ch.name}: {axis[1]:.1f} deg from the nearest housing axis ({axis[0]}), more "
                            f"than {axis_tolerance_deg:g} deg: a gross mounting error, unless the design is oblique "
                            "(then raise --axis-tolerance-deg); the calibration holds its true direction")
    return tuple(warnings)


def _ratio(snr: float) -> str:
    return f"{snr:.3g} ({20 * np.log10(snr):.1f} dB)" if snr > 0 and np.isfinite(snr) else f"{snr:g}"


def to_json(channels) -> dict:
    """The file's ``"channel_health"`` block: per channel its signal-to-noise ratio and axis angle."""
    out = {}
    for ch in channels:
        entry = {"snr": ch.snr, "snr_db": ch.snr_db, "response": float(ch.response),
                 "response_sigma": float(ch.response_sigma), "noise": float(ch.noise)}
        axis = ch.nearest_axis
        if axis is not None:
            entry |= {"nearest_axis": axis[0], "axis_angle_deg": axis[1]}
        out[ch.name] = entry
    return out


def describe(block: dict) -> str:
    """Report lines from a file's ``"channel_health"`` block (:func:`to_json`): each channel's
    signal-to-noise ratio and its angle from the nearest housing axis."""
    lines = ["  channels: signal-to-noise (whole-field response over one sample's noise), nearest housing axis"]
    for name, entry in block.items():
        where = (f", {entry['axis_angle_deg']:.2f} deg from {entry['nearest_axis']}"
                 if "axis_angle_deg" in entry else "")
        lines.append(f"    {name}: {_ratio(entry['snr'])}{where}")
    return "\n".join(lines)
