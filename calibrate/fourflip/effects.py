"""Effects the base four-flip model lacks, as explicit extensions of :class:`BenchPhysics`.

Each effect owns a block of fit parameters (scaled to be of order one or smaller), knows how
they change the physics, whether a recording can show it at all, and how to report its fitted
values with units.  The base model is linear channels on an ideal bench.

Identifiability notes (what the bench cannot see):

- ``flip_error``: flip 0 defines the housing frame, so only flips 90, 180 and 270 have errors;
  a fixed tilt of the turntable axis turns the field the same way at every flip and is absorbed
  by the dip (and field azimuth): it never shows in the residual.  Only an external reference
  (IGRF/WMM dip at the site) reveals it.
- ``turntable_zero``: flip 0's zero is the field azimuth's, so only flips 90, 180 and 270 have one; a zero
  common to every flip is the field azimuth.
- ``platform_field``: its vertical component adds to the Earth's vertical field at every angle
  and flip (absorbed by the dip and the gains), and its component along the flip axis X adds
  ``a_x b_x`` in every flip (absorbed by the offsets); only the y component is fitted.  The other two
  are not read as zero: each takes a stated prior carried into the file's sigmas
  (:mod:`calibrate.fourflip._unseen`).
- ``encoder_error``: a constant encoder offset is the field azimuth; harmonics 1..3 are fitted.
- ``gain_drift`` and ``temperature``'s gain are confounded in the same way.
- ``offset_drift`` and ``temperature`` are confounded when the temperature only rises with time;
  the evidence then favours whichever fits better, and the report says both were candidates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from compass.sim.bench import BenchPhysics, BenchSamples

from ._phases import ZERO_OFF_DEG
from ..effects import EffectForm, TemperatureForm, TimePolynomial, WarmUpForm, time_powers, warm_up_tau_s

__all__ = ["FourFlipEffect", "EFFECTS", "VARIANTS", "effect_by_name"]

ENCODER_HARMONICS = 3
MAX_DRIFT_DEGREE = 3
MAX_GAIN_DRIFT_DEGREE = 2


class FourFlipEffect(EffectForm):
    """One model extension of the bench (:class:`calibrate.effects.Effect`): how its parameter block
    changes the physics, its parameter names and reporting units, and its formula for the file."""

    def param_names(self, channels) -> list[str]:
        raise NotImplementedError

    def apply(self, physics: BenchPhysics, p: np.ndarray, samples) -> BenchPhysics:
        raise NotImplementedError

    def jacobian(self, physics: BenchPhysics, p: np.ndarray, samples: BenchSamples, partials) -> np.ndarray:
        """d outputs / d p at ``physics`` (every effect applied), shape (n, c, n_params).

        ``partials`` is a :class:`calibrate.fourflip._jacobian.Partials` of ``physics`` at ``samples``.
        """
        raise NotImplementedError

    def report_scale(self, physics: BenchPhysics) -> np.ndarray | float:
        """Factor from fit parameters to the reported values (units in ``param_names``)."""
        return 1.0

    max_angle_deg = None
    """For an effect of angles (degrees): the largest a bench can have; a fit beyond it is not claimed
    (:func:`calibrate.fourflip.diagnosis.small_angles`)."""

    def too_few_channels(self, n_channels: int) -> str | None:
        """Why a recording of ``n_channels`` cannot show the effect apart from the directions, else None."""
        return None

    def reference(self, physics: BenchPhysics) -> dict:
        """Where the effect is zero, so where the file's responses hold (written with the effect)."""
        return {}

    @property
    def formula(self) -> str:
        """The effect's formula in the file's parameter names (the file's ``form``: it reads without this code)."""
        raise NotImplementedError


@dataclass(frozen=True)
class NonlinearResponse(FourFlipEffect):
    """Polynomial response per channel: ``x + sum_k c_k x^k`` over ``powers`` (2, 3 and/or 5).

    Odd powers are the usual saturation; an even power makes the response asymmetric (a
    sensor whose gain differs for fields along and against its axis).
    """

    powers: tuple = (3,)

    def n_params(self, c):
        return c * len(self.powers)

    def param_names(self, channels):
        return [f"{ch}.x{k}_rel_at_B" for ch in channels for k in self.powers]

    @property
    def formula(self):
        terms = " + ".join(f"x{k}_rel_at_B |B| (x/|B|)^{k}" for k in self.powers)
        return f"output = offset + gain (x + {terms}), x = B.a in field units"

    def apply(self, physics, p, samples):
        # parameters: relative output change at |B| of each power, scale-free
        b = physics.field_norm
        p = p.reshape(len(physics.gains), len(self.powers))
        coef = {k: p[:, i] / b ** (k - 1) for i, k in enumerate(self.powers)}
        return physics.with_(quadratic=coef.get(2), cubic=coef.get(3), quintic=coef.get(5))

    def jacobian(self, physics, p, samples, partials):
        b = physics.field_norm
        values = np.stack([partials.gain_t * partials.x**k / b ** (k - 1) for k in self.powers], axis=-1)
        return partials.per_channel(values)


class EncoderError(FourFlipEffect):
    def n_params(self, c):
        return 2 * ENCODER_HARMONICS

    def param_names(self, channels):
        return [f"encoder.{kind}{k}_deg" for k in range(1, ENCODER_HARMONICS + 1) for kind in ("cos", "sin")]

    @property
    def formula(self):
        return ("true turntable angle = platform_deg + sum_k (cos<k>_deg cos(k platform_deg) + sin<k>_deg "
                f"sin(k platform_deg)), k = 1..{ENCODER_HARMONICS}, degrees")

    def apply(self, physics, p, samples):
        return physics.with_(encoder_fourier=np.degrees(p.reshape(ENCODER_HARMONICS, 2)))

    def jacobian(self, physics, p, samples, partials):
        k = np.arange(1, ENCODER_HARMONICS + 1)
        arg = np.radians(samples.platform_deg)[:, None] * k[None, :]
        turn = np.stack([np.cos(arg), np.sin(arg)], axis=-1).reshape(arg.shape[0], -1)  # d phi' / d p, rad / rad
        return partials.per_turn[:, :, None] * turn[:, None, :]

    def report_scale(self, physics):
        return np.degrees(1.0)


class _FlipAngle(FourFlipEffect):
    """An angle of each of flips 90, 180 and 270, degrees (flip 0's defines the frame): its parameters, their
    reporting, their Jacobian through the output's partial by the angle (:meth:`_partial`), and the most a bench
    can have (:data:`calibrate.fourflip._phases.ZERO_OFF_DEG`)."""

    suffix = ""
    """The parameters' names: ``flip<k>.<suffix>``."""
    max_angle_deg = ZERO_OFF_DEG

    def n_params(self, c):
        return 3

    def param_names(self, channels):
        return [f"flip{k}.{self.suffix}" for k in (90, 180, 270)]

    def _partial(self, partials) -> np.ndarray:
        """d output / d angle (rad), shape (n, c)."""
        raise NotImplementedError

    def jacobian(self, physics, p, samples, partials):
        which = (samples.flip_index[:, None] == np.arange(1, 4)[None, :]).astype(float)  # (n, 3)
        return self._partial(partials)[:, :, None] * which[:, None, :]

    def report_scale(self, physics):
        return np.degrees(1.0)


class FlipError(_FlipAngle):
    """The real flip angles of flips 90, 180, 270 differ from the recorded ones.

    The cube turns about its X edge, which stays on the turntable's X axis, so a face that is
    not square errs in the flip angle only.  (General pose errors are not identifiable: a
    rotation of the whole housing frame about Z, compensated by the field azimuth and matching
    yaws of the flips, leaves every output unchanged.)
    """

    suffix = "error_deg"

    @property
    def formula(self):
        return "real flip = recorded flip_deg + flip<k>.error_deg, right-hand about the cube's X edge, degrees"

    def apply(self, physics, p, samples):
        rotvec = np.zeros((4, 3))
        rotvec[1:, 0] = np.degrees(p)
        return physics.with_(flip_rotvec_deg=rotvec)

    def _partial(self, partials):
        return partials.per_flip


class TurntableZero(_FlipAngle):
    """Each flip's turntable zero differs from flip 0's: the true angle is ``platform_deg + D_k`` in flip k.

    The cube set down turned about the vertical after a flip (no fence, or a fence it does not touch), or the
    table's reading re-zeroed between flips.  Flip 0's zero is the field azimuth's, so only flips 90, 180 and 270
    have one; it is not a flip angle error (``flip_error``, about the cube's X edge) nor a harmonic of the angle
    (``encoder_error``): a constant per flip, told apart by each flip's own first harmonic
    (:mod:`calibrate.fourflip._phases`).
    """

    suffix = "turntable_zero_deg"

    @property
    def formula(self):
        return ("true turntable angle = platform_deg + flip<k>.turntable_zero_deg in flip k (flip 0's is 0: it defines "
                "the field's azimuth), degrees")

    def apply(self, physics, p, samples):
        return physics.with_(turntable_zero_deg=np.degrees(np.concatenate([[0.0], p])))

    def _partial(self, partials):
        return partials.per_turn

    def too_few_channels(self, n_channels):
        if n_channels < 3:
            return (f"with {n_channels} channel{'s' * (n_channels > 1)} a flip's zero trades against a direction: "
                    "three or more tell them apart (calibrate.fourflip._phases)")
        return None


class PlatformField(FourFlipEffect):
    """Field fixed to the turntable; only its y component (turntable frame) shows.

    Seen by a channel in flip k it adds ``(Rx(kappa) a) . b_p``: the x part is ``a_x b_x`` in every
    flip (an offset) and the z part adds to the Earth's vertical field (the dip and gains); their prior
    is :func:`calibrate.fourflip._unseen.platform_prior`.
    """

    def n_params(self, c):
        return 1

    def param_names(self, channels):
        return ["platform_field.y_fieldunit"]

    @property
    def formula(self):
        return ("a field (0, platform_field.y_fieldunit, 0) fixed to the turntable frame (it turns with it), "
                "field units; its x and z parts are absorbed by the offsets and the dip")

    def apply(self, physics, p, samples):
        return physics.with_(platform_field=np.array([0.0, p[0], 0.0]) * physics.field_norm)

    def jacobian(self, physics, p, samples, partials):
        d_b_h = partials.turntable_to_housing(np.array([0.0, physics.field_norm, 0.0]))
        return partials.through_field(d_b_h[:, :, None])

    def report_scale(self, physics):
        return physics.field_norm


@dataclass(frozen=True)
class OffsetDrift(TimePolynomial, FourFlipEffect):
    """Offsets drifting with time: a polynomial of the given degree in t_s per channel."""

    def param_names(self, channels):
        return [f"{ch}.drift_t{k}_fieldunit" for ch in channels for k in range(1, self.degree + 1)]

    def apply(self, physics, p, samples):
        t0 = 0.5 * (samples.t_s.min() + samples.t_s.max())
        half = 0.5 * np.ptp(samples.t_s)
        drift = p.reshape(-1, self.degree) * physics.gains[:, None]
        return physics.with_(drift=drift, drift_t0=t0, drift_scale_s=half)

    def jacobian(self, physics, p, samples, partials):
        powers = time_powers((samples.t_s - physics.drift_t0) / physics.drift_scale_s, self.degree)
        return partials.per_channel(powers[:, None, :] * physics.gains[None, :, None])

    @property
    def formula(self):
        return ("offset(t) = offset + gain sum_k drift_t<k>_fieldunit ((t_s - reference.t_s) / reference.half_span_s)^k, "
                f"k = 1..{self.degree}")

    def reference(self, physics):
        return {"t_s": float(physics.drift_t0), "half_span_s": float(physics.drift_scale_s)}  # the session's midpoint


@dataclass(frozen=True)
class WarmUp(WarmUpForm, FourFlipEffect):
    """Offsets settling after switch-on: a per-channel amplitude times ``exp(-t / tau)``, one
    time constant for all channels (one thermal path), ``t`` from the first sample."""

    tau_fractions: tuple = (0.1, 0.25, 0.5, 1.0)

    def param_names(self, channels):
        return [f"{ch}.warmup_fieldunit" for ch in channels] + ["warmup.log_tau_over_session"]

    def apply(self, physics, p, samples):
        session = max(np.ptp(samples.t_s), 1e-9)
        tau = warm_up_tau_s(session, p[-1], high=6.0)
        return physics.with_(warmup=p[:-1] * physics.gains, warmup_tau_s=tau, drift_t0=samples.t_s.min())

    def jacobian(self, physics, p, samples, partials):
        age = samples.t_s - physics.drift_t0
        settling = np.exp(-age / physics.warmup_tau_s)
        amplitudes = partials.per_channel(settling[:, None, None] * physics.gains[None, :, None])
        # tau = session exp(log ratio), clipped: d tau / d log ratio = tau inside the clip, 0 outside
        inside = -6.0 < p[-1] < 6.0
        d_tau = (settling * age / physics.warmup_tau_s)[:, None] * physics.warmup[None, :] * inside
        return np.concatenate([amplitudes, d_tau[:, :, None]], axis=-1)

    @property
    def formula(self):
        return ("offset(t) = offset + gain warmup_fieldunit exp(-(t_s - reference.t_s_first) / reference.tau_s), "
                "tau_s = session exp(warmup.log_tau_over_session); offset is the settled one")

    def reference(self, physics):
        # the offsets the channels settle to
        return {"after_warm_up": True, "t_s_first": float(physics.drift_t0), "tau_s": float(physics.warmup_tau_s)}


@dataclass(frozen=True)
class GainDrift(TimePolynomial, FourFlipEffect):
    """Gains drifting with time (a temperature change nobody recorded): ``K (1 + sum_k g_k tau^k)`` per
    channel, ``tau`` the time from the session's midpoint over half its span, k = 1..degree."""

    def param_names(self, channels):
        return [f"{ch}.gain_drift_t{k}_rel" for ch in channels for k in range(1, self.degree + 1)]

    def apply(self, physics, p, samples):
        t0 = 0.5 * (samples.t_s.min() + samples.t_s.max())
        return physics.with_(gain_drift=p.reshape(-1, self.degree), gain_drift_t0=t0,
                             gain_drift_scale_s=0.5 * np.ptp(samples.t_s))

    def jacobian(self, physics, p, samples, partials):
        powers = time_powers((samples.t_s - physics.gain_drift_t0) / physics.gain_drift_scale_s, self.degree)
        static = physics.gains * partials.temperature_factor * partials.bent  # (n, c)
        return partials.per_channel(powers[:, None, :] * static[:, :, None])

    @property
    def formula(self):
        return ("gain(t) = gain (1 + sum_k gain_drift_t<k>_rel ((t_s - reference.t_s) / reference.half_span_s)^k), "
                f"k = 1..{self.degree}")

    def reference(self, physics):
        return {"t_s": float(physics.gain_drift_t0), "half_span_s": float(physics.gain_drift_scale_s)}


class Temperature(TemperatureForm, FourFlipEffect):
    def n_params(self, c):
        return 2 * c

    def param_names(self, channels):
        return [f"{ch}.{kind}" for ch in channels for kind in ("offset_fieldunit_per_degc", "gain_rel_per_degc")]

    def apply(self, physics, p, samples):
        p = p.reshape(-1, 2)
        return physics.with_(
            temp_offset=p[:, 0] * physics.gains,
            temp_gain=p[:, 1] / 100.0,
            temp_ref_c=float(np.mean(samples.temp_c)),
        )

    def jacobian(self, physics, p, samples, partials):
        dt = (samples.temp_c - physics.temp_ref_c)[:, None]
        offset = dt * physics.gains[None, :]
        gain = dt * physics.gains * partials.gain_drift_factor * partials.bent / 100.0
        return partials.per_channel(np.stack([offset, gain], axis=-1))

    def report_scale(self, physics):
        return np.tile([1.0, 0.01], len(physics.gains))

    @property
    def formula(self):
        return ("offset(T) = offset + gain offset_fieldunit_per_degc (T - reference.temp_c); "
                "gain(T) = gain (1 + gain_rel_per_degc (T - reference.temp_c)), T = temp_c")

    def reference(self, physics):
        return {"temp_c": float(physics.temp_ref_c)}


_NONLINEAR = "curves flattened, sharpened or made asymmetric toward their extremes (harmonics growing with B.a): a curved response"
_DRIFT = "a slow trend in time in each channel's offset"
VARIANTS: dict[str, tuple[FourFlipEffect, ...]] = {
    "nonlinear_response": (NonlinearResponse("nonlinear_response", "powers 3", _NONLINEAR + " (odd cubic)", powers=(3,)),
                           NonlinearResponse("nonlinear_response", "powers 2, 3", _NONLINEAR + " (quadratic and cubic)",
                                             powers=(2, 3)),
                           NonlinearResponse("nonlinear_response", "powers 3, 5",
                                             _NONLINEAR + " (odd cubic and quintic)", powers=(3, 5))),
    "encoder_error": (EncoderError(
        "encoder_error", "",
        f"harmonics of the turntable angle shared by every channel and flip (encoder error, harmonics 1..{ENCODER_HARMONICS})"),),
    "offset_drift": tuple(OffsetDrift("offset_drift", f"degree {d}", _DRIFT + f" (polynomial of degree {d} in t_s)",
                                      degree=d)
                          for d in range(1, MAX_DRIFT_DEGREE + 1))
                    + (WarmUp("offset_drift", "warm-up exponential",
                              _DRIFT + " (warm-up: exponential settling, one time constant)"),),
    "platform_field": (PlatformField(
        "platform_field", "",
        "per-flip offsets that follow each channel's direction in the turntable frame (a field turning with the turntable)"),),
    "flip_error": (FlipError("flip_error", "",
                             "flip-to-flip inconsistency that turning the 90/180/270 flips by small angles removes"),),
    "turntable_zero": (TurntableZero(
        "turntable_zero", "", "the field's azimuth differs between flips by a constant each (the cube set down turned "
        "about the vertical after a flip, or the table's zero moved)"),),
    "temperature": (Temperature("temperature", "", "offset and gain changes that follow temp_c"),),
    "gain_drift": tuple(GainDrift("gain_drift", f"degree {d}", "a slow trend in time in each channel's gain (the swing "
                                  f"of its curve growing or shrinking; polynomial of degree {d} in t_s)", degree=d)
                        for d in range(1, MAX_GAIN_DRIFT_DEGREE + 1)),
}
"""Each effect's forms, simplest first; the diagnosis lets the evidence (BIC) choose among them."""
EFFECTS: dict[str, FourFlipEffect] = {name: max(forms, key=lambda e: e.n_params(3)) for name, forms in VARIANTS.items()}
"""Each effect's most general form (the most parameters)."""


def effect_by_name(name: str) -> FourFlipEffect:
    try:
        return EFFECTS[name]
    except KeyError:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}") from None
