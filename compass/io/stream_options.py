"""The options that say what a module's stream is (``--format``, ``--columns``, ``--*-unit``, ``--accel-sign``).

Kept apart from the decoders (:mod:`compass.io.streams`) so that building the command-line parser
imports none of them.
"""

from __future__ import annotations

from dataclasses import dataclass

from . import units

__all__ = ["FORMATS", "EXAMPLE_COLUMNS", "StreamOptions", "add_stream_arguments"]

FORMATS = ("auto", "compass", "motioncal", "csv")
EXAMPLE_COLUMNS = "t_s,ax,ay,az,gx,gy,gz,mx,my,mz"


@dataclass(frozen=True)
class StreamOptions:
    """What the user says about a stream (``--format``, ``--columns``, ``--*-unit``, ``--accel-sign``).

    Attributes
    ----------
    format : {"auto", "compass", "motioncal", "csv"}
    columns : tuple of str or None
        The cells of a CSV stream (:func:`compass.io.fixed_lines.parse_columns`); implies ``csv``.
    mag_unit : {"uT", "nT", "G", "mG"} or None
    accel_unit : {"g", "m/s2"} or None
    gyro_unit : {"rad/s", "deg/s"} or None
    accel_sign : {1, -1}
        -1: the accelerometer reads gravity (-1 g on Z when level at rest), negated to read specific force (SPEC),
        whatever the format.

    Raises
    ------
    ValueError
        Options that contradict each other, with what to do.
    """

    format: str = "auto"
    columns: tuple | None = None
    mag_unit: str | None = None
    accel_unit: str | None = None
    gyro_unit: str | None = None
    accel_sign: int = 1

    def __post_init__(self):
        if self.format not in FORMATS:
            raise ValueError(f"--format must be one of {', '.join(FORMATS)}, got {self.format!r}")
        if self.columns is not None and self.format not in ("auto", "csv"):
            raise ValueError(f"--columns names the cells of a headerless stream (--format csv), not of "
                             f"{self.format} lines: leave it out")
        if self.format == "csv" and not self.columns:
            raise ValueError(f"--format csv needs --columns naming every cell in order, e.g. --columns {EXAMPLE_COLUMNS}")
        named = [f"--{k}-unit" for k in ("mag", "accel", "gyro") if getattr(self, f"{k}_unit") is not None]
        if self.format == "motioncal" and named:
            raise ValueError(f"MotionCal lines have fixed units (Raw: counts of 0.1 uT, 1/8192 g and 1/16 deg/s; "
                             f"Uni: uT, m/s^2 and rad/s): leave out {', '.join(named)}")
        if self.accel_sign not in (1, -1):
            raise ValueError(f"--accel-sign must be 1 or -1, got {self.accel_sign!r}")
        for kind, table in (("mag", units.MAG_UNITS), ("accel", units.ACCEL_UNITS), ("gyro", units.GYRO_UNITS)):
            unit = getattr(self, f"{kind}_unit")
            if unit is not None and unit not in table:
                raise ValueError(f"--{kind}-unit must be one of {', '.join(table)}, got {unit!r}")

    @property
    def requested(self) -> str:
        """The format asked for: ``csv`` when only ``--columns`` says it."""
        return "csv" if self.columns and self.format == "auto" else self.format

    @classmethod
    def from_args(cls, args) -> "StreamOptions":
        """From the options :func:`add_stream_arguments` registered (ValueError for a contradiction)."""
        return cls(format=getattr(args, "format", "auto") or "auto", columns=getattr(args, "columns", None),
                   mag_unit=getattr(args, "mag_unit", None), accel_unit=getattr(args, "accel_unit", None),
                   gyro_unit=getattr(args, "gyro_unit", None), accel_sign=getattr(args, "accel_sign", 1))

    def factors(self, fmt: str) -> tuple[float, float, float]:
        """Multipliers of the decoded field, accelerometer and gyro (to uT, g, rad/s where a unit is named; the
        accelerometer's times ``accel_sign``)."""
        if fmt == "motioncal":
            return 1.0, float(self.accel_sign), 1.0  # scaled by the format itself
        return (1.0 if self.mag_unit is None else units.MAG_UNITS[self.mag_unit],
                self.accel_sign * (1.0 if self.accel_unit is None else units.ACCEL_UNITS[self.accel_unit]),
                1.0 if self.gyro_unit is None else units.GYRO_UNITS[self.gyro_unit])

    def accel_known(self, fmt: str) -> bool:
        """Whether the accelerometer's unit is known (named, or fixed by the format): then it reads g."""
        return fmt == "motioncal" or self.accel_unit is not None


def add_stream_arguments(parser) -> None:
    """Register ``--format``, ``--columns``, ``--mag-unit``, ``--accel-unit``, ``--gyro-unit``, ``--accel-sign``
    (:class:`StreamOptions`)."""
    import argparse

    def columns(text):
        from .fixed_lines import parse_columns  # at parse time: the parser is built without the decoders

        try:
            return parse_columns(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    g = parser.add_argument_group("the stream's format and units")
    g.add_argument("--format", choices=FORMATS, default="auto",
                   help="what the module sends: compass (our line protocol), motioncal (the Raw:/Uni: lines of the "
                        "PJRC and Adafruit calibration sketches), csv (bare numbers, with --columns); default auto: "
                        "found from the first lines and said")
    g.add_argument("--columns", type=columns, metavar="NAME,...",
                   help=f"the cells of a headerless stream in order, e.g. {EXAMPLE_COLUMNS} (-mz: the cell is minus "
                        f"mz; t_ms, t_us: times in ms, us; other names: cells skipped); implies --format csv")
    g.add_argument("--mag-unit", choices=tuple(units.MAG_UNITS), default=None,
                   help="unit of the stream's field (converted to uT; default: the calibration's own unit)")
    g.add_argument("--accel-unit", choices=tuple(units.ACCEL_UNITS), default=None,
                   help="unit of the stream's ax,ay,az (converted to g and checked against 1 g; default: any unit)")
    g.add_argument("--gyro-unit", choices=tuple(units.GYRO_UNITS), default=None,
                   help="unit of the stream's gx,gy,gz (default rad/s, the line protocol's); a deg/s gyro taken as "
                        "rad/s turns the attitude 57 times too fast")
    g.add_argument("--accel-sign", type=int, choices=(1, -1), default=1,
                   help="-1: the accelerometer reads gravity (-1 g on Z when level at rest), negated to read specific "
                        "force, +1 g on Z (SPEC); any format")
