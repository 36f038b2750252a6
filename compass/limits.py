"""The range every number the toolkit accepts must lie in, and the one check that enforces it.

A number from the user (a command-line option, a ``# key: value`` line of a recording, a value
of a truth or calibration file) is accepted only when it is finite and inside a range declared
here, once, with the reason for its bounds.  :meth:`Range.check` is what library code calls on a
value (``ValueError`` naming the value, its place and the range); :meth:`Range.option` is the
``type=`` of every numeric ``argparse`` option (``compass.cli`` reports its refusal as one line,
exit 2).  A bound is far from anything physical on purpose: the point is that ``1e308``, ``nan``,
``1e-300`` or a negative count never reach a computation, not to second-guess a real value.

Examples
--------
>>> FIELD_UT.check(48.0, "field_ut")
48.0
>>> FIELD_UT.check(1e308, "field_ut")
Traceback (most recent call last):
...
ValueError: field_ut must be a number in [0.001, 100000] uT, got 1e+308
"""

from __future__ import annotations

import argparse
import math
import numbers
import re
from dataclasses import dataclass

import numpy as np

__all__ = ["Range", "FIELD_UT", "DIP_DEG", "TILT_DEG", "ANGLE_DEG", "NOISE_UT", "SAMPLES", "SEED", "RATE_HZ",
           "DURATION_S", "WAIT_S", "BAUD", "FRACTION", "CHANNELS", "SCALE", "IRON_UT", "ACCEL_NOISE_G", "MAX_TILT_DEG", "GRAVITY", "GYRO_SCALE_ERROR"]


@dataclass(frozen=True)
class Range:
    """A closed (or half-open) interval of finite numbers, optionally integers.

    Parameters
    ----------
    lo, hi : float
        The bounds, inclusive unless ``lo_open`` / ``hi_open``.
    unit : str
        The unit, for messages ("uT", "deg", "s"); empty for a pure number.
    integer : bool
        Only integers (a float with an integral value is accepted from a file, e.g. ``3.0``).
    lo_open, hi_open : bool
        Exclude the bound.
    """

    lo: float
    hi: float
    unit: str = ""
    integer: bool = False
    lo_open: bool = False
    hi_open: bool = False

    def __contains__(self, value) -> bool:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return False
        v = float(value) if not isinstance(value, numbers.Integral) else value
        if not isinstance(v, int) and (not math.isfinite(v) or (self.integer and not v.is_integer())):
            return False
        above = v > self.lo if self.lo_open else v >= self.lo
        below = v < self.hi if self.hi_open else v <= self.hi
        return above and below

    def describe(self) -> str:
        """``"a number in [0.001, 100000] uT"``, ``"an integer in [1, 64]"``."""
        lo, hi = (f"{v:d}" if self.integer else f"{v:g}" for v in (self.lo, self.hi))
        text = (f"{'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open else ']'}"
                + (f" {self.unit}" if self.unit else ""))
        return f"an integer in {text}" if self.integer else f"a number in {text}"

    def check(self, value, what: str):
        """``value`` if it is in the range, else ``ValueError("<what> must be <range>, got <value>")``.

        ``what`` names the value and its place (``"--field-ut"``, ``"rec.csv: # field_ut:"``,
        ``"truth.json: key 'noise_ut'"``).  A boolean or a string is refused too.
        """
        if value in self:
            return int(value) if self.integer else float(value)
        shown = f"{value:g}" if isinstance(value, float) else repr(value) if isinstance(value, str) else str(value)
        if isinstance(value, int) and not isinstance(value, bool) and len(shown) > 24:
            shown = f"{float(value):g}" if abs(value) < 1e308 else "an integer of %d digits" % len(shown)
        raise ValueError(f"{what} must be {self.describe()}, got {shown}")

    def parse(self, text: str, what: str):
        """The number written in ``text`` (ASCII digits, as in a file or on the command line), checked."""
        text = text.strip()
        try:
            if not _NUMBER.fullmatch(text) or (self.integer and not _INTEGER.fullmatch(text)):
                raise ValueError(text)  # "1_0" (Python's float reads 10), "0x10", "3.0" or "1e3" for a count
            value = int(text) if self.integer else float(text)
        except ValueError:
            raise ValueError(f"{what} must be {self.describe()}, got {text!r}") from None
        return self.check(value, what)

    def option(self, name: str):
        """An ``argparse`` ``type=`` that parses and checks the option ``name`` (``"--baud"``)."""

        def convert(text: str):
            try:
                return self.parse(text, name)
            except ValueError as exc:
                raise argparse.ArgumentTypeError(str(exc).removeprefix(f"{name} ")) from None

        convert.__name__ = self.describe()  # argparse names the type in some messages
        convert.range = self  # the tests find every numeric option's range through it
        return convert


_NUMBER = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:nan|inf|infinity)", re.I)
_INTEGER = re.compile(r"[+-]?[0-9]+")


FIELD_UT = Range(1e-3, 1e5, "uT")
"""A field strength: 1 nT (the resolution of the best fluxgates) to 0.1 T (beyond any
magnetometer's range: the widest, Hall sensors such as the MLX90393, read +-50 mT); the Earth's
field is 22-67 uT."""
DIP_DEG = Range(-90.0, 90.0, "deg")
"""A dip (inclination): the field's angle below the horizontal."""
TILT_DEG = Range(0.0, 90.0, "deg")
"""A largest pitch or roll."""
ANGLE_DEG = Range(-360.0, 360.0, "deg")
"""A heading, yaw or misalignment angle (one turn either way)."""
NOISE_UT = Range(0.0, 1e3, "uT")
"""A white-noise level: at most 1 mT, twenty times the Earth's field (no signal left)."""
IRON_UT = Range(0.0, 1e4, "uT")
"""A hard-iron offset's size: at most 10 mT (a magnet on the sensor saturates it long before)."""
SCALE = Range(0.0, 1e3)
"""A multiplier of simulated effect sizes."""
SAMPLES = Range(1, 10_000_000, integer=True)
"""Rows to simulate: ten million rows are about 1 GB of CSV."""
CHANNELS = Range(1, 64, integer=True)
"""Single-axis channels or sensors of one module."""
SEED = Range(0, 2**63 - 1, integer=True)
"""A random seed (numpy's generators take non-negative integers)."""
RATE_HZ = Range(1e-3, 1e5, "Hz")
"""A sample rate: one sample in 1000 s (a slow logger) to 100 kHz (ten times the fastest
magnetometer's output rate)."""
DURATION_S = Range(0.0, 1e9, "s", lo_open=True)
"""A duration: positive, at most 31 years (Python's timers stop at 9.2e9 s)."""
WAIT_S = Range(0.0, 1e9, "s")
"""A wait or a time offset: zero or positive, at most 31 years."""
BAUD = Range(50, 20_000_000, integer=True)
"""A serial baud rate: 50 (the slowest standard rate) to 20 Mbaud (beyond the fastest USB-serial
bridges' 12 Mbaud)."""
FRACTION = Range(0.0, 1.0)
"""A probability or a fraction of a whole."""
MAX_TILT_DEG = Range(0.0, 90.0, "deg", hi_open=True)
"""``--level``'s largest tilt assumed (90 deg leaves no heading)."""
GRAVITY = Range(0.0, 1e6, lo_open=True)
"""What 1 g reads in an accelerometer's unit (1 in g, 9.81 in m/s^2, 1000 in mg, counts): positive,
at most a million (a 20-bit count)."""
ONE_G_RATIO = Range(0.7, 1.4)
"""A stream's corrected median |a| over what 1 g read in a calibration's recording (a bench's offsets and scales, a
tumble's accelerometer correction): within, the same unit; units differ by 4x or more (ranges' counts, m/s^2
against g, mg), motion, noise and a board's own errors by less."""


def reads_one_g(accel, one_g: float) -> bool:
    """Whether accelerometer rows (n, 3), corrected, read 1 g as a calibration's recording did (``one_g``): their
    finite rows' median |a| over it within :data:`ONE_G_RATIO`; False without a finite row."""
    norms = np.linalg.norm(np.atleast_2d(np.asarray(accel, dtype=float)), axis=1)
    norms = norms[np.isfinite(norms)]
    return norms.size > 0 and float(np.median(norms)) / one_g in ONE_G_RATIO


GYRO_SCALE_ERROR = Range(0.0, 0.2, lo_open=True)
"""``--gyro-scale-error``: a fraction of the rate, above 0 and up to 20 % (beyond, the gyro's unit or an axis is
wrong, not its scale: ``compass.calibration.MAX_GYRO_MATRIX_ERROR``)."""
ACCEL_NOISE_G = Range(0.0, 1.0, "g", lo_open=True)
"""An accelerometer's noise level: positive, at most 1 g (no gravity direction left)."""
