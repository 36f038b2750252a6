"""Response curves of single-axis channels and their inverses.

A channel's output ``v`` is a monotone increasing function of the field component along its
sensing direction, ``x = B . a``, in field units (uT when the calibration knows |B|, otherwise
units of |B|).  Every response keeps the range of ``x`` it was calibrated over.  The inverse flags
a reading that rests on a nonlinear curve extrapolated beyond it (a fitted cubic or table is
continued with its end slopes: not to be trusted).  A linear response beyond its range is the same
straight line: the only error it can add is a nonlinearity too small for the calibration to see
inside the range, grown as ``(x / x_max)^3`` for an odd cubic; that is not flagged
(:meth:`Response.beyond_range` still tells).  Four-flip benches make this common: flips about X
never turn a channel's X component vertical, so a channel along X is calibrated over only
``|B| cos(dip)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Response", "LinearResponse", "CubicResponse", "TableResponse", "response_from_json"]

_INVERSE_GRID = 2049  # knots of the monotone table used to invert nonlinear curves


@dataclass(frozen=True)
class Response:
    """Base class: ``v = offset + gain * g(x)`` with ``g`` monotone, ``g(0) = 0``, ``g'(0) = 1``.

    Attributes
    ----------
    offset : float
        Zero-field output (output units).
    gain : float
        Output per field unit at zero field, > 0.
    x_range : tuple of float
        Field components (field units) the curve was calibrated over.
    """

    offset: float
    gain: float
    x_range: tuple[float, float] = (-np.inf, np.inf)

    model = "linear"
    nonlinear = False  # beyond its range, a nonlinear curve is extrapolated; a line stays itself

    def shape(self, x: np.ndarray) -> np.ndarray:
        """The normalised curve g(x); identity for a linear channel."""
        return x

    def output(self, x) -> np.ndarray:
        """Output for field components ``x`` (field units), any shape."""
        return self.offset + self.gain * self.shape(np.asarray(x, dtype=float))

    def field_component(self, v) -> tuple[np.ndarray, np.ndarray]:
        """Invert the response.

        Returns
        -------
        x : ndarray
            Field component along the sensing direction (field units), same shape as ``v``.
        in_range : ndarray of bool
            False where a nonlinear response's ``x`` lies outside the calibrated range (the curve
            is then extrapolated with its end slopes and the value must not be trusted); always
            True for a linear response (see the module's notes and :meth:`beyond_range`).
        """
        v = np.asarray(v, dtype=float)
        x = self._invert((v - self.offset) / self.gain)
        return x, ~self.beyond_range(x) if self.nonlinear else np.ones(x.shape, dtype=bool)

    def beyond_range(self, x) -> np.ndarray:
        """True where ``x`` (field units) lies outside the calibrated range by more than 2 % of its span."""
        x = np.asarray(x, dtype=float)
        lo, hi = self.x_range
        span = hi - lo if np.isfinite(hi - lo) else 0.0
        margin = 0.02 * span
        return ~((x >= lo - margin) & (x <= hi + margin))

    def _invert(self, y: np.ndarray) -> np.ndarray:
        return y

    def to_json(self) -> dict:
        out = {"model": self.model, "offset": float(self.offset), "gain": float(self.gain)}
        if np.all(np.isfinite(self.x_range)):
            out["range"] = [float(self.x_range[0]), float(self.x_range[1])]
        out.update(self._extra_json())
        return out

    def _extra_json(self) -> dict:
        return {}


@dataclass(frozen=True)
class LinearResponse(Response):
    """``v = offset + gain * x``."""

    model = "linear"


@dataclass(frozen=True)
class _MonotoneResponse(Response):
    """A nonlinear curve inverted through a dense monotone table over the calibrated range."""

    nonlinear = True

    def _invert(self, y: np.ndarray) -> np.ndarray:
        lo, hi = self.x_range
        grid = np.linspace(lo, hi, _INVERSE_GRID)
        g = self.shape(grid)
        if np.any(np.diff(g) <= 0):
            raise ValueError(
                f"{self.model} response is not monotone over its calibrated range [{lo:.4g}, {hi:.4g}]"
            )
        inside = np.interp(y, g, grid)
        # beyond the table: continue with the end slopes (flagged by field_component)
        slope_lo = (grid[1] - grid[0]) / (g[1] - g[0])
        slope_hi = (grid[-1] - grid[-2]) / (g[-1] - g[-2])
        return np.where(y < g[0], lo + (y - g[0]) * slope_lo,
                        np.where(y > g[-1], hi + (y - g[-1]) * slope_hi, inside))


@dataclass(frozen=True)
class CubicResponse(_MonotoneResponse):
    """Polynomial: ``v = offset + gain * (x + quadratic * x**2 + cubic * x**3 + quintic * x**5)``.

    ``quadratic`` in 1/field-unit, ``cubic`` in 1/field-unit^2, ``quintic`` in 1/field-unit^4
    (zero when absent: a pure odd cubic is the common case, hence the model's name).
    """

    cubic: float = 0.0
    quintic: float = 0.0
    quadratic: float = 0.0
    model = "cubic"

    def shape(self, x):
        return x + self.quadratic * x**2 + self.cubic * x**3 + self.quintic * x**5

    def _extra_json(self):
        out = {"cubic": float(self.cubic)}
        for key in ("quadratic", "quintic"):
            if getattr(self, key):
                out[key] = float(getattr(self, key))
        return out


@dataclass(frozen=True)
class TableResponse(_MonotoneResponse):
    """Tabulated curve (seed 000's f(beta)): output at field components ``x_table``.

    ``offset`` and ``gain`` are a straight-line fit to the table; the curve itself is the
    monotone cubic (PCHIP) through the table's points, made monotone by sorting on output.
    """

    x_table: tuple[float, ...] = field(default=())
    v_table: tuple[float, ...] = field(default=())
    model = "table"

    def shape(self, x):
        from scipy.interpolate import PchipInterpolator  # 0.4 s to import: only table responses pay it

        curve = PchipInterpolator(np.asarray(self.x_table), np.asarray(self.v_table), extrapolate=True)
        return (curve(x) - self.offset) / self.gain

    def _extra_json(self):
        return {"x": [float(v) for v in self.x_table], "v": [float(v) for v in self.v_table]}


def response_from_json(d: dict, where: str = "response") -> Response:
    """Build a response curve from its calibration-file dictionary.

    Raises
    ------
    ValueError
        Unknown model or missing/invalid keys; the message names ``where``.
    """
    try:
        model = d["model"]
        offset, gain = float(d["offset"]), float(d["gain"])
        x_range = tuple(float(v) for v in d.get("range", (-np.inf, np.inf)))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: expected model, offset, gain ({exc})") from None
    if not gain > 0:
        raise ValueError(f"{where}: gain must be positive, got {gain}")
    if model == "linear":
        return LinearResponse(offset, gain, x_range)
    if model == "cubic":
        return CubicResponse(offset, gain, x_range, cubic=float(d.get("cubic", 0.0)),
                             quintic=float(d.get("quintic", 0.0)), quadratic=float(d.get("quadratic", 0.0)))
    if model == "table":
        x, v = np.asarray(d["x"], float), np.asarray(d["v"], float)
        return TableResponse(offset, gain, x_range, x_table=tuple(x), v_table=tuple(v))
    raise ValueError(f"{where}: unknown response model {model!r} (known: linear, cubic, table)")
