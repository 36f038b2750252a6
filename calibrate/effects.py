"""The effect protocol every kind's residual diagnosis speaks, and the time and temperature bases it shares.

An *effect* is one extension of a kind's base model that the evidence loop
(:func:`calibrate.diagnosis.evidence.select_effects`) may add (SPEC section 4).  Every kind writes its
effects against its own model -- the four-flip changes the bench physics
(:mod:`calibrate.fourflip.effects`), the fits against known inputs add to the predicted outputs
(:mod:`calibrate.diagnosis.offsets`), the tumble corrects the readings (:mod:`calibrate.tumble.diagnosis`),
the installation moves the hard iron (:mod:`calibrate.installation.diagnosis`) -- but all of them are
:class:`Effect`: a SPEC section 4 ``name``, a ``form`` among that name's forms, a ``description`` in
words, a ``label``, a parameter count ``n_params(n_channels)``, whether a recording can show it
(``applicable(columns)``) and where its score test linearises it (``score_points(n_channels)``).

The forms in time and temperature are the same everywhere and written once here:

- :class:`TimeForm` and :class:`TemperatureForm`: applicable only when ``t_s`` (``temp_c``) changes;
- :class:`TimePolynomial`: ``degree`` coefficients per channel, the powers ``tau^k``, k = 1..degree
  (:func:`time_powers`), ``tau = (t - t_ref) / T``;
- :class:`WarmUpForm`: a change per channel and one ``log(tau / session)``: ``1 - exp(-(t - t_ref) / tau)``
  (:func:`settled`), the log-ratio clipped so a fit cannot run to a step or a line (:func:`warm_up_tau_s`);
- :class:`OddCubic`: one coefficient per channel;
- :class:`Basis`: a recording's reference time and temperature and their spans, ``tau`` and ``d``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["Effect", "Columns", "EffectForm", "TimeForm", "TemperatureForm", "TimePolynomial", "WarmUpForm",
           "OddCubic", "Basis", "Recorded", "WARMUP_TAU_FRACTIONS", "settled", "time_powers", "warm_up_tau_s",
           "why_no_temperature", "why_no_time"]

WARMUP_TAU_FRACTIONS = (0.03, 0.07, 0.15, 0.3, 0.6)
"""Time constants (fractions of the session) at which a warm-up's score test is evaluated."""


class Columns(Protocol):
    """What :meth:`Effect.applicable` reads of a recording (the four-flip's ``BenchSamples`` is one).

    Attributes
    ----------
    t_s : ndarray, shape (n,), or None
        Time of each sample, s.
    temp_c : ndarray, shape (n,), or None
        Sensor temperature of each sample, degC.
    """

    t_s: np.ndarray | None
    temp_c: np.ndarray | None


@dataclass(frozen=True)
class Recorded:
    """The columns of a recording an effect may need, when the kind has no record of its own.

    Attributes
    ----------
    t_s, temp_c : ndarray, shape (n,), or None
        Time (s) and temperature (degC) of each sample.
    missing : tuple of str
        Half-axes the field never came near (a tumble's coverage, e.g. ``("+Z",)``).
    """

    t_s: np.ndarray | None = None
    temp_c: np.ndarray | None = None
    missing: tuple = ()


@runtime_checkable
class Effect(Protocol):
    """One extension of a kind's base model: what the evidence loop and the reports read of it."""

    name: str
    """The SPEC section 4 vocabulary name (``offset_drift``, ``temperature``, ...)."""
    description: str
    """What it describes in words (a step's evidence starts with it)."""

    @property
    def form(self) -> str:
        """Which of the name's forms (``"linear"``, ``"warm-up"``; ``""`` for a name with one form)."""

    @property
    def label(self) -> str:
        """``name (form)``, or the name alone."""

    def n_params(self, n_channels: int) -> int:
        """Parameters of the effect on a model of ``n_channels`` channels (axes)."""

    def applicable(self, columns: Columns) -> str | None:
        """None when a recording with these columns can show the effect, else the reason it cannot."""

    def score_points(self, n_channels: int) -> list[np.ndarray]:
        """Parameter blocks of zero size at which the score test linearises the effect."""


@dataclass(frozen=True)
class EffectForm:
    """The shared part of every kind's effects (:class:`Effect`): name, form, description.

    Subclasses give :meth:`n_params` (and, as their model needs, the correction itself).
    """

    name: str
    form: str
    description: str

    @property
    def label(self) -> str:
        return f"{self.name} ({self.form})" if self.form else self.name

    def n_params(self, n_channels: int) -> int:
        raise NotImplementedError(f"{type(self).__name__} does not give its parameter count")

    def applicable(self, columns: Columns) -> str | None:
        return None

    def score_points(self, n_channels: int) -> list[np.ndarray]:
        """One zero block for effects linear in their parameters (a shape parameter overrides it)."""
        return [np.zeros(self.n_params(n_channels))]


class TimeForm(EffectForm):
    """An effect in time: applicable when ``t_s`` changes."""

    def applicable(self, columns):
        return why_no_time(columns.t_s)


class TemperatureForm(EffectForm):
    """An effect in temperature: applicable when ``temp_c`` changes by 0.5 degC or more."""

    def applicable(self, columns):
        return why_no_temperature(columns.temp_c)


@dataclass(frozen=True)
class TimePolynomial(TimeForm):
    """A polynomial in time without constant term per channel: ``degree`` coefficients each."""

    degree: int = 1

    def n_params(self, n_channels):
        return self.degree * n_channels


@dataclass(frozen=True)
class WarmUpForm(TimeForm):
    """A settling after switch-on: a change per channel and one ``log(tau / session)`` (the last parameter).

    ``tau_fractions`` are the time constants, as fractions of the session, at which the score test
    linearises it (at zero size the data say nothing of the time constant).
    """

    tau_fractions: tuple = WARMUP_TAU_FRACTIONS

    def n_params(self, n_channels):
        return n_channels + 1

    def score_points(self, n_channels):
        return [np.concatenate([np.zeros(n_channels), [np.log(f)]]) for f in self.tau_fractions]


class OddCubic(EffectForm):
    """An odd cubic response per channel: one coefficient each."""

    def n_params(self, n_channels):
        return n_channels


@dataclass(frozen=True)
class Basis:
    """A recording's reference condition, where every time and temperature effect is zero.

    Attributes
    ----------
    t_ref_s : float
        Reference time, s (the first sample).
    session_s : float
        The session's span of ``t_s``, s (``tau = (t - t_ref) / session``).
    temp_ref_c : float
        Reference temperature, degC (the mean of ``temp_c``).
    temp_span_c : float
        The span of ``temp_c``, degC (``d = (T - T_ref) / span``).
    """

    t_ref_s: float
    session_s: float
    temp_ref_c: float
    temp_span_c: float

    @classmethod
    def of(cls, t_s: np.ndarray | None, temp_c: np.ndarray | None) -> "Basis":
        """The basis of a recording (neutral values for a missing column)."""
        return cls(t_ref_s=0.0 if t_s is None else float(t_s[0]),
                   session_s=1.0 if t_s is None else max(float(np.ptp(t_s)), 1e-9),
                   temp_ref_c=0.0 if temp_c is None else float(np.mean(temp_c)),
                   temp_span_c=1.0 if temp_c is None else max(float(np.ptp(temp_c)), 1e-9))

    def tau(self, t_s: np.ndarray) -> np.ndarray:
        """Time from the reference over the session, dimensionless."""
        return (t_s - self.t_ref_s) / self.session_s

    def d(self, temp_c: np.ndarray) -> np.ndarray:
        """Temperature from the reference over its span, dimensionless."""
        return (temp_c - self.temp_ref_c) / self.temp_span_c


def time_powers(tau: np.ndarray, degree: int) -> np.ndarray:
    """``tau^k``, k = 1..degree, shape (n, degree): the columns of a :class:`TimePolynomial`."""
    return tau[:, None] ** np.arange(1, degree + 1)


def why_no_time(t_s) -> str | None:
    """Why a recording cannot show an effect in time (no ``t_s``, or one that never changes), else None."""
    if t_s is None:
        return "the recording has no t_s column"
    if not np.ptp(t_s) > 0:
        return "t_s never changes"
    return None


def why_no_temperature(temp_c) -> str | None:
    """Why a recording cannot show a temperature effect (no ``temp_c``, or under 0.5 degC of change), else None."""
    if temp_c is None:
        return "the recording has no temp_c column"
    if np.ptp(temp_c) < 0.5:
        return "temp_c varies by less than 0.5 degC"
    return None


def warm_up_tau_s(session_s: float, log_ratio: float, low: float = -6.0, high: float = 3.0) -> float:
    """A warm-up's time constant, s: ``session_s exp(log_ratio)`` with the log-ratio clipped to [low, high]."""
    return session_s * np.exp(np.clip(log_ratio, low, high))


def settled(t_s: np.ndarray, t_ref_s: float, tau_s: float) -> np.ndarray:
    """The fraction of a warm-up's change reached at ``t_s``: ``1 - exp(-(t - t_ref) / tau)``."""
    return -np.expm1(-(t_s - t_ref_s) / tau_s)

