"""The acceptance specification: limits on a module's figures, read from TOML, and the verdict.

A spec is a TOML file (``compass batch --spec SPEC.toml``; the shipped default is
``compass/production/default_acceptance.toml``, its limits justified in ``docs/production.md``)::

    [site]                      # where the heading budget is predicted
    dip_deg = 65.0
    field_ut = 50.0
    bench_field_ut = 49.5       # optional: the bench's |B| (uT), for recordings that give neither
                                # '# field_ut:' nor the site keys (offset_ut needs it)

    [limits]                    # figure = { max = .. } and/or { min = .. }
    direction_sigma_deg = { max = 0.3 }
    snr_min = { min = 100.0 }

    [unexplained]
    fail = true                 # structure above the noise floor no effect explains rejects

    [warnings]
    fail_on = ["not_converged", "undetermined", "saturation", "channel"]

    [missing]
    fail = false                # a figure the calibration kind does not give is not judged (said so)

    [control]                   # the fleet report's EWMA chart
    figures = ["bench_dip_deg", "direction_sigma_deg"]
    baseline_sessions = 50
    lambda = 0.2
    width_sigmas = 4.0

A key the reader does not know, a value of the wrong type, a limit on an unknown figure, or no limit
at all (a spec that judges no figure accepts every module) is a :class:`SpecError` naming the file
and the key (exit status 2 on the command line).
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from .figures import FIGURES, WARNING_CLASSES

__all__ = ["DEFAULT_SPEC", "AcceptanceSpec", "SpecError", "Verdict", "load_spec", "parse_spec"]

DEFAULT_SPEC = Path(__file__).with_name("default_acceptance.toml")
"""The shipped default spec."""

_WARNING_CLASSES = tuple(WARNING_CLASSES) + ("other",)


class SpecError(ValueError):
    """A malformed acceptance spec: the message names the file and the key."""


@dataclass(frozen=True)
class Verdict:
    """A module's acceptance verdict.

    Attributes
    ----------
    status : {"accepted", "rejected", "refused"}
        ``refused``: the recording could not be calibrated at all.
    reasons : tuple of str
        Why it is not accepted (empty when accepted).
    notes : tuple of str
        Figures left unjudged and why (kept with the verdict).
    """

    status: str
    reasons: tuple[str, ...] = ()
    notes: tuple[str, ...] = ()

    @property
    def accepted(self) -> bool:
        return self.status == "accepted"


@dataclass(frozen=True)
class AcceptanceSpec:
    """Validated acceptance limits (build with :func:`load_spec` or :func:`parse_spec`).

    Attributes
    ----------
    limits : dict
        Figure name -> ``(low or None, high or None)``.
    site_dip_deg, site_field_ut : float
    bench_field_ut : float or None
        The bench's |B| in uT, for a recording that says neither ``# field_ut:`` nor its site.
    fail_unexplained, fail_missing : bool
    fail_on_warnings : tuple of str
        Warning classes that reject a module.
    control_figures : tuple of str
    baseline_sessions : int
    ewma_lambda, width_sigmas : float
    text : str
        The spec as written (kept in the store with every verdict).
    """

    limits: dict
    site_dip_deg: float = 65.0
    site_field_ut: float = 50.0
    bench_field_ut: float | None = None
    fail_unexplained: bool = True
    fail_missing: bool = False
    fail_on_warnings: tuple[str, ...] = ()
    control_figures: tuple[str, ...] = ("bench_dip_deg",)
    baseline_sessions: int = 50
    ewma_lambda: float = 0.2
    width_sigmas: float = 4.0
    text: str = field(default="", repr=False)

    @property
    def sha256(self) -> str:
        """Hash of the spec's text (a stored verdict names the spec it was judged by)."""
        return hashlib.sha256(self.text.encode()).hexdigest()

    def judge(self, figures: dict) -> Verdict:
        """The verdict on one module's figures (:func:`compass.production.figures.module_figures`)."""
        reasons, notes = [], []
        for name, (low, high) in self.limits.items():
            value = figures.get(name)
            unit = FIGURES[name].unit
            if value is None or not math.isfinite(value):
                why = figures.get("unjudged", {}).get(name, "not given by this calibration")
                (reasons if self.fail_missing else notes).append(f"{name}: not judged: {why}")
                continue
            if high is not None and value > high:
                reasons.append(f"{name} {value:.4g} {unit} above the limit {high:g}")
            if low is not None and value < low:
                reasons.append(f"{name} {value:.4g} {unit} below the limit {low:g}")
        if self.fail_unexplained and figures.get("unexplained") is True:
            reasons.append("unexplained: structure above the noise floor that no modelled effect explains")
        bad = [c for c in figures.get("warning_classes", ()) if c in self.fail_on_warnings]
        reasons += [f"warning of class '{c}'" for c in bad]
        return Verdict("rejected" if reasons else "accepted", tuple(reasons), tuple(notes))


def load_spec(path=None) -> AcceptanceSpec:
    """Read and validate a spec file (the default spec when ``path`` is None).

    Raises
    ------
    SpecError
        Unreadable, not TOML, or a key that is unknown or of the wrong type (named).
    """
    path = DEFAULT_SPEC if path is None else Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"{path}: cannot read the spec: {exc}") from None
    return parse_spec(text, source=str(path))


_SECTIONS = {"site", "limits", "unexplained", "warnings", "missing", "control"}


def parse_spec(text: str, *, source: str = "<spec>") -> AcceptanceSpec:
    """Validate a spec's TOML text (see the module docstring).

    Raises
    ------
    SpecError
    """
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(f"{source}: not valid TOML: {exc}") from None
    _known(doc, _SECTIONS, source, "")
    site = _table(doc, "site", source)
    _known(site, {"dip_deg", "field_ut", "bench_field_ut"}, source, "site.")
    limits = {}
    for name, entry in _table(doc, "limits", source).items():
        key = f"limits.{name}"
        if name not in FIGURES:
            raise SpecError(f"{source}: '{key}': unknown figure; known: {', '.join(FIGURES)}")
        if not isinstance(entry, dict) or not entry:
            raise SpecError(f"{source}: '{key}': expected a table like {{ max = 1.0 }} or {{ min = 1.0 }}")
        _known(entry, {"min", "max"}, source, key + ".")
        low, high = (_number(entry, k, source, key + ".") if k in entry else None for k in ("min", "max"))
        if low is not None and high is not None and low > high:
            raise SpecError(f"{source}: '{key}': min {low:g} is above max {high:g}")
        limits[name] = (low, high)
    unexplained = _table(doc, "unexplained", source)
    _known(unexplained, {"fail"}, source, "unexplained.")
    missing = _table(doc, "missing", source)
    _known(missing, {"fail"}, source, "missing.")
    warns = _table(doc, "warnings", source)
    _known(warns, {"fail_on"}, source, "warnings.")
    fail_on = _names(warns, "fail_on", _WARNING_CLASSES, source, "warnings.")
    control = _table(doc, "control", source)
    _known(control, {"figures", "baseline_sessions", "lambda", "width_sigmas"}, source, "control.")
    figures = _names(control, "figures", tuple(FIGURES), source, "control.")
    spec = AcceptanceSpec(
        limits=limits,
        site_dip_deg=_number(site, "dip_deg", source, "site.", default=65.0, low=-90.0, high=90.0),
        site_field_ut=_number(site, "field_ut", source, "site.", default=50.0, positive=True),
        bench_field_ut=_number(site, "bench_field_ut", source, "site.", positive=True),
        fail_unexplained=_bool(unexplained, "fail", source, "unexplained.", default=True),
        fail_missing=_bool(missing, "fail", source, "missing.", default=False),
        fail_on_warnings=fail_on,
        control_figures=figures if "figures" in control else ("bench_dip_deg",),
        baseline_sessions=int(_number(control, "baseline_sessions", source, "control.", default=50, low=3,
                                      integer=True)),
        ewma_lambda=_number(control, "lambda", source, "control.", default=0.2, positive=True, high=1.0),
        width_sigmas=_number(control, "width_sigmas", source, "control.", default=4.0, positive=True),
        text=text,
    )
    if not spec.limits:
        raise SpecError(f"{source}: no [limits]: the spec judges no figure, so every module would be accepted "
                        f"(an empty or truncated file?); give limits like [limits] gain_spread = {{ max = 0.3 }} "
                        f"(the default spec: {DEFAULT_SPEC})")
    return spec


def _known(table: dict, allowed: set, source: str, prefix: str) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise SpecError(f"{source}: '{prefix}{unknown[0]}': unknown key; known here: {', '.join(sorted(allowed))}")


def _table(doc: dict, name: str, source: str) -> dict:
    value = doc.get(name, {})
    if not isinstance(value, dict):
        raise SpecError(f"{source}: '{name}': expected a table ([{name}])")
    return value


def _number(table, key, source, prefix, *, default=None, positive=False, low=None, high=None, integer=False):
    if key not in table:
        return default
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError(f"{source}: '{prefix}{key}': expected a number, got {value!r}")
    if integer and value != int(value):
        raise SpecError(f"{source}: '{prefix}{key}': expected a whole number, got {value!r}")
    if (positive and not value > 0) or (low is not None and value < low) or (high is not None and value > high):
        bounds = " and ".join(b for b in ("positive" if positive else "", f">= {low:g}" if low is not None else "",
                                          f"<= {high:g}" if high is not None else "") if b)
        raise SpecError(f"{source}: '{prefix}{key}': expected {bounds}, got {value!r}")
    return float(value)


def _bool(table, key, source, prefix, *, default):
    value = table.get(key, default)
    if not isinstance(value, bool):
        raise SpecError(f"{source}: '{prefix}{key}': expected true or false, got {value!r}")
    return value


def _names(table, key, allowed, source, prefix) -> tuple[str, ...]:
    value = table.get(key, [])
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise SpecError(f"{source}: '{prefix}{key}': expected a list of names, got {value!r}")
    for v in value:
        if v not in allowed:
            raise SpecError(f"{source}: '{prefix}{key}': unknown name {v!r}; known: {', '.join(allowed)}")
    return tuple(value)
