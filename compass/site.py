"""The site's field: where the compass is used, never where it was calibrated (SPEC section 1).

A calibration carries the sensor; the Earth's field it meets (|B|, dip, declination) belongs to the
place and the date.  The runtime's reference field comes, in this order, from

1. a site given by the user (``--site LAT,LON[,ALT_M]`` and ``--date``): the World Magnetic Model
   (``pygeomag``, NOAA's coefficients and synthesis, imported only on this path) with its published
   error model (the declination's grows as the horizontal field weakens);
2. the calibration file's ``site`` block (written by an installation calibration given a site);
3. the recording itself (:func:`reference_from_recording`): the median |B| and dip over the rows
   where the accelerometer reads gravity alone, with outliers (a magnet passing) left out.

A :class:`ReferenceField` says which, with the uncertainty of its dip: that uncertainty enters the
two-vector weights (:func:`compass.attitude.solve_attitude`), so an uncertain dip never pulls the tilt.
"""

from __future__ import annotations

import math

import datetime as dt
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

__all__ = ["WMM_MODEL", "WMM_DATES", "Site", "SiteField", "ReferenceField", "wmm_field", "decimal_year",
           "known_reference", "reference_from_site",
           "reference_from_recording", "upside_down", "MIN_REFERENCE_ROWS"]

WMM_MODEL = "WMM2025"
WMM_DATES = (dt.date(2010, 1, 1), dt.date(2029, 12, 31))
"""The days the installed World Magnetic Models cover (WMM2010, 2015, 2020, 2025: five years each).
A site's date outside them is refused: the models' secular variation is a 5-year linear forecast,
so 1800 or 2040 would be an extrapolation with no published uncertainty."""
_QUIET_ACCEL = 0.02  # a row is quiet when | |a| / g - 1 | is below this (g: the median |a|)
_OUTLIER_SIGMAS = 5.0  # rows farther than this many robust sigmas from the median are left out
MIN_REFERENCE_ROWS = 10  # fewest quiet rows from which a reference is estimated
_MIN_SIGNED_DIP_DEG = 10.0  # below this |dip| a sign flip of the field is within tilt errors: not judged
_MIRROR_DIP_DEG = 10.0
"""Against the calibration's own dip (no site known), a stream's median dip within this of the mirrored one is
judged turned over, degrees: a negated accelerometer mirrors it exactly where the module was calibrated, within a
few degrees across a region; one merely of the other sign (a module near or across the magnetic equator, whose
headings are right) is not."""


def decimal_year(date: dt.date) -> float:
    """The WMM's time coordinate of a day: year plus the fraction of the year at its noon."""
    start = dt.date(date.year, 1, 1)
    length = (dt.date(date.year + 1, 1, 1) - start).days
    return date.year + ((date - start).days + 0.5) / length


@dataclass(frozen=True)
class Site:
    """A place and a day: geodetic latitude and longitude (degrees), height (metres), date.

    Build it with :meth:`parse` (command line text) or :meth:`from_json` (a file's ``site`` block).
    """

    lat_deg: float
    lon_deg: float
    alt_m: float
    date: dt.date

    def __post_init__(self):
        for name, value, limit in (("latitude", self.lat_deg, 90.0), ("longitude", self.lon_deg, 360.0)):
            if not (np.isfinite(value) and abs(value) <= limit):
                raise ValueError(f"site {name} must be within +-{limit:g} degrees, got {value}")
        if not (np.isfinite(self.alt_m) and -1000.0 <= self.alt_m <= 850e3):
            raise ValueError(f"site altitude must be in [-1000, 850000] m (the WMM's range), got {self.alt_m}")
        first, last = WMM_DATES
        if not first <= self.date <= last:
            raise ValueError(f"site date {self.date.isoformat()} is outside the World Magnetic Model's "
                             f"{first.isoformat()} to {last.isoformat()}: the field then is not known to it (each "
                             f"model forecasts 5 years; its uncertainty does not hold outside them)")

    @classmethod
    def parse(cls, text: str, date: str | dt.date | None = None) -> "Site":
        """``LAT,LON[,ALT_M]`` (degrees, degrees, metres) and a ``YYYY-MM-DD`` date (default today, UTC).

        Raises
        ------
        ValueError
            Not two or three numbers, out of range, or a date not in ISO form.
        """
        parts = [p.strip() for p in str(text).split(",")]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            values = []
        if len(values) not in (2, 3):
            raise ValueError(f"--site expects LAT,LON[,ALT_M] in degrees and metres, got {text!r}")
        return cls(values[0], values[1], values[2] if len(values) == 3 else 0.0, _date(date))

    @classmethod
    def from_json(cls, block: dict) -> "Site":
        """From a calibration file's ``site`` block (``lat_deg``, ``lon_deg``, ``alt_m``, ``date``)."""
        if not isinstance(block, dict):
            raise ValueError(f"'site' must be an object with lat_deg, lon_deg, alt_m and date, got {block!r}")
        try:
            return cls(float(block["lat_deg"]), float(block["lon_deg"]), float(block.get("alt_m") or 0.0),
                       _date(block["date"]))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"'site' block: expected lat_deg, lon_deg and date ({exc})") from None

    @property
    def decimal_year(self) -> float:
        return decimal_year(self.date)

    def field(self) -> "SiteField":
        """The WMM's field here and now (:func:`wmm_field`)."""
        return wmm_field(self.lat_deg, self.lon_deg, self.decimal_year, self.alt_m / 1000.0)

    def to_json(self) -> dict:
        """The ``site`` block of SPEC section 2, with the model's field at this site and date."""
        f = self.field()
        return {"lat_deg": self.lat_deg, "lon_deg": self.lon_deg, "alt_m": self.alt_m, "date": self.date.isoformat(),
                "field_ut": f.field_ut, "dip_deg": f.dip_deg, "declination_deg": f.declination_deg,
                "dip_sigma_deg": f.dip_sigma_deg, "declination_sigma_deg": f.declination_sigma_deg,
                "model": f.model}

    def __str__(self) -> str:
        return f"{self.lat_deg:g},{self.lon_deg:g},{self.alt_m:g} m on {self.date.isoformat()}"


def _date(value) -> dt.date:
    if value is None:
        return dt.datetime.now(dt.timezone.utc).date()
    if isinstance(value, dt.date):
        return value
    try:
        return dt.date.fromisoformat(str(value).strip()[:10])
    except ValueError:
        raise ValueError(f"date should be YYYY-MM-DD, got {value!r}") from None


@dataclass(frozen=True)
class SiteField:
    """The World Magnetic Model's field at a site: values and its published 1-sigma uncertainties.

    Attributes
    ----------
    field_ut, field_sigma_ut : float
        Total intensity |B| and its uncertainty, microtesla.
    dip_deg, dip_sigma_deg : float
        Inclination (> 0: field points down) and its uncertainty, degrees.
    declination_deg, declination_sigma_deg : float
        Declination (east-positive: ``heading_true = heading + declination``) and its uncertainty,
        degrees; the WMM's error model ``sqrt(0.26^2 + (5417 nT / H)^2)`` grows near the poles.
    model : str
    """

    field_ut: float
    field_sigma_ut: float
    dip_deg: float
    dip_sigma_deg: float
    declination_deg: float
    declination_sigma_deg: float
    model: str = WMM_MODEL


def wmm_field(lat_deg: float, lon_deg: float, year: float, alt_km: float = 0.0) -> SiteField:
    """The WMM's field at a geodetic position and decimal year, with the WMM's error model.

    Parameters
    ----------
    lat_deg, lon_deg : float
        Geodetic latitude and longitude, degrees.
    year : float
        Decimal year (:func:`decimal_year`); outside the model's 2025.0-2030.0 it extrapolates.
    alt_km : float
        Height above the WGS-84 ellipsoid, km.

    Examples
    --------
    One of NOAA's WMM2025 test values (2025.0, 0 km, 80 N, 0 E: declination 1.28 deg):

    >>> round(wmm_field(80.0, 0.0, 2025.0).declination_deg, 2)
    1.28
    """
    geomag = _geomag(int(min(max(year, 2010.0), 2029.0)))
    result = geomag.calculate(glat=lat_deg, glon=lon_deg, alt=alt_km, time=year, allow_date_outside_lifespan=True)
    try:
        sigma = result.calculate_uncertainty()
        dip_sigma, f_sigma, d_sigma = sigma.i, sigma.f, sigma.d
    except ValueError:  # outside the error model's years: the last published model's figures
        dip_sigma, f_sigma = 0.20, 138.0
        d_sigma = float(np.hypot(0.26, 5417.0 / max(result.h, 1.0)))
    return SiteField(float(result.f) / 1000.0, float(f_sigma) / 1000.0, float(result.i), float(dip_sigma),
                     float(result.d), float(d_sigma), geomag.model.replace("-", ""))


@lru_cache(maxsize=4)
def _geomag(base_year: int):
    """The WMM of that epoch (coefficients loaded once)."""
    from pygeomag import GeoMag

    return GeoMag(base_year=base_year)


@dataclass(frozen=True)
class ReferenceField:
    """The field the runtime expects: direction (dip) and |B|, their uncertainty, where they came from.

    Attributes
    ----------
    dip_deg, dip_sigma_deg : float
        Reference dip and its 1-sigma, degrees.
    field_norm, field_sigma : float
        Reference |B| in the sensor model's field units and its 1-sigma, same units.
    source : str
        ``"site"`` (given by the user), ``"calibration site"`` (the file's ``site`` block),
        ``"calibration"`` (the dip the calibration measured against its own accelerometer: judges a stream's
        field turned over, never seeds the filter) or ``"recording"`` (estimated from the quiet rows).
    description : str
        One line for the output's metadata.
    declination_deg, declination_sigma_deg : float or None
        With a site: declination (east-positive) and its 1-sigma, degrees.
    """

    dip_deg: float
    dip_sigma_deg: float
    field_norm: float
    field_sigma: float
    source: str
    description: str
    declination_deg: float | None = None
    declination_sigma_deg: float | None = None

    def complete(self, estimate: "ReferenceField") -> "ReferenceField":
        """This reference with its |B| taken from ``estimate`` when unknown (NaN); else itself."""
        if np.isfinite(self.field_norm):
            return self
        return replace(self, field_norm=estimate.field_norm, field_sigma=estimate.field_sigma,
                       description=f"{self.description}; |B| {estimate.field_norm:.4g} from the {estimate.source}")


def known_reference(dip_deg: float, field_norm: float, *, dip_sigma_deg: float = 0.0,
                    field_sigma: float = 0.0) -> ReferenceField:
    """A reference field the caller knows (a local survey, a simulation's truth), source ``"given"``."""
    if not (np.isfinite(dip_deg) and abs(dip_deg) < 90.0 and field_norm > 0):
        raise ValueError(f"expected a dip in (-90, 90) degrees and a positive |B|, got {dip_deg} and {field_norm}")
    return ReferenceField(float(dip_deg), float(dip_sigma_deg), float(field_norm), float(field_sigma), "given",
                          f"given: |B| {field_norm:.4g} +- {field_sigma:.2g}, dip {dip_deg:.3f} +- {dip_sigma_deg:.3f} deg")


def reference_from_site(site: Site, *, field_ut: float | None, source: str = "site") -> ReferenceField:
    """The reference at a site (WMM).

    Parameters
    ----------
    site : Site
    field_ut : float or None
        The sensor model's field unit in microtesla (1 when the calibration knew |B|), None when its
        gains are per unit of the bench's |B|: the reference's |B| is then unknown (NaN) and comes
        from the data (:meth:`ReferenceField.complete`).
    source : str
        ``"site"`` or ``"calibration site"``.
    """
    f = site.field()
    magnitude, magnitude_sigma = ((np.nan, np.nan) if field_ut is None else
                                  (f.field_ut / field_ut, f.field_sigma_ut / field_ut))
    text = (f"{source} {site}: {f.model} |B| {f.field_ut:.2f} uT, dip {f.dip_deg:.2f} +- {f.dip_sigma_deg:.2f} deg, "
            f"declination {f.declination_deg:+.2f} +- {f.declination_sigma_deg:.2f} deg"
            + ("" if field_ut is not None else " (the calibration's unit is the bench's |B|, not the uT)"))
    return ReferenceField(f.dip_deg, f.dip_sigma_deg, float(magnitude), float(magnitude_sigma), source, text,
                          f.declination_deg, f.declination_sigma_deg)


def reference_from_recording(field_h, up_h, accel_norm=None) -> ReferenceField:
    """|B| and dip of the field from a recording's own rows.

    Medians over the rows where the accelerometer reads gravity alone (``| |a| / median |a| - 1 |``
    below 2 %), then again over the rows within five robust sigmas (1.4826 MAD) of those medians, so
    that a magnet passing or a field changing for part of the recording does not move the reference.
    The sigma of each median is ``1.2533 s / sqrt(n)`` (``s`` the robust spread of the kept rows).

    Parameters
    ----------
    field_h : array_like, shape (n, 3)
        Field in H, field units.
    up_h : array_like, shape (n, 3)
        Unit up direction in H per row (from the accelerometer, known tilt, or assumed level).
    accel_norm : array_like, shape (n,), optional
        |a| per row (any unit); without it every row counts as quiet.

    Raises
    ------
    ValueError
        Fewer than 10 quiet rows.
    """
    b = np.asarray(field_h, dtype=float)
    u = np.asarray(up_h, dtype=float)
    b_norm = np.linalg.norm(b, axis=1)
    ok = np.isfinite(b_norm) & (b_norm > 0) & np.all(np.isfinite(u), axis=1)
    if accel_norm is not None:
        a = np.asarray(accel_norm, dtype=float)
        ok &= np.abs(a / np.median(a[ok]) - 1.0) < _QUIET_ACCEL if np.any(ok) else ok
    if np.sum(ok) < MIN_REFERENCE_ROWS:
        usable = int(np.sum(np.isfinite(b_norm) & (b_norm > 0)))
        what = (f"only {int(np.sum(ok))} rows read gravity alone (|a| within {100 * _QUIET_ACCEL:g} % of g)"
                if usable >= MIN_REFERENCE_ROWS else f"the recording has {usable} usable rows")
        raise ValueError(f"{what} and the site's field needs at least {MIN_REFERENCE_ROWS} quiet rows to be estimated from "
                         "the recording; give --site LAT,LON --date D")
    dip = np.degrees(np.arcsin(np.clip(-np.einsum("ij,ij->i", b, u) / b_norm, -1.0, 1.0)))
    keep = ok.copy()
    for values in (b_norm, dip):
        centre = np.median(values[ok])
        spread = 1.4826 * np.median(np.abs(values[ok] - centre))
        if spread > 0:
            keep &= np.abs(values - centre) <= _OUTLIER_SIGMAS * spread
    n = int(np.sum(keep))
    if n < MIN_REFERENCE_ROWS:
        raise ValueError(f"only {n} rows agree on the field: the site's field cannot be estimated from the "
                         f"recording; give --site LAT,LON --date D")
    stats = []
    for values in (b_norm[keep], dip[keep]):
        centre = float(np.median(values))
        stats.append((centre, 1.2533 * 1.4826 * float(np.median(np.abs(values - centre))) / np.sqrt(n)))
    (magnitude, magnitude_sigma), (dip_deg, dip_sigma) = stats
    text = (f"recording: median over {n} of {len(b)} rows (quiet, no outliers): |B| {magnitude:.4g} "
            f"+- {magnitude_sigma:.2g}, dip {dip_deg:.3f} +- {dip_sigma:.3f} deg (no site given: no true north)")
    return ReferenceField(dip_deg, dip_sigma, magnitude, magnitude_sigma, "recording", text)


class QuietSeed:
    """The reference field of a live stream, from its first quiet seconds (no site given).

    Collects the field and accelerometer of the first samples; once they span ``seconds`` and at
    least ten of them read gravity alone, :func:`reference_from_recording` gives the reference.  A
    stream that never holds still for ``max_seconds`` is estimated from every row it has (the
    outlier rejection still applies).

    Parameters
    ----------
    seconds, max_seconds : float
        Span of samples to collect before estimating, and the longest wait, seconds.
    """

    def __init__(self, seconds: float = 1.0, max_seconds: float = 10.0):
        self.seconds, self.max_seconds = seconds, max_seconds
        self._t: list[float] = []
        self._rows: list[np.ndarray] = []
        self._next_try_s = seconds  # span at which to try again (every 0.1 s of data, not every sample)

    def add(self, t_s: float, accel, field_h) -> ReferenceField | None:
        """Add one sample (``accel`` None, zero or not finite: skipped); the reference once it is known, else None."""
        if accel is None or not np.all(np.isfinite(field_h)):
            return None
        a = np.asarray(accel, dtype=float)
        norm = math.hypot(*a)  # inf for an absurd reading (no overflow warning): skipped with zero and NaN
        if not 0 < norm < math.inf:
            return None
        self._t.append(t_s)
        self._rows.append(np.concatenate([a / norm, [norm], np.asarray(field_h, dtype=float)]))
        span = self._t[-1] - self._t[0]
        if span < self._next_try_s:
            return None
        self._next_try_s = span + 0.1
        return self._estimate(any_row=span >= self.max_seconds)

    def finish(self) -> ReferenceField | None:
        """The stream ended before a quiet second: the reference from what there is, quiet rows first, else
        every row; None with fewer than ten rows."""
        return self._estimate(any_row=True) if self._rows else None

    def _estimate(self, any_row: bool) -> ReferenceField | None:
        rows = np.array(self._rows)
        try:
            return reference_from_recording(rows[:, 4:], rows[:, :3], rows[:, 3])
        except ValueError:
            if not any_row:
                return None
        try:
            return reference_from_recording(rows[:, 4:], rows[:, :3])
        except ValueError:
            return None


def upside_down(dip_deg: np.ndarray, reference: ReferenceField, *, bench_sign_ambiguous: bool = True) -> str | None:
    """Why the calibrated field points the other way from a given reference, or None.

    The bench data cannot tell ``(a, B)`` from ``(-a, -B)``: a calibration made in one hemisphere
    while the other was assumed has every sensing direction negated, so the field it measures is
    ``-B``, whose dip is the site's with the sign turned.  Every row then differs from the reference
    by about twice the dip (all disturbed) and the heading is 180 deg off.  So does a stream whose
    accelerometer reads gravity instead of specific force (``-a``): its dip is the calibration's with
    the sign turned.  Judged on the median over the rows (a magnet for part of the recording does not
    move it), only for a reference the user gave (a site) or the calibration measured (its own dip
    against its accelerometer: then only within :data:`_MIRROR_DIP_DEG` of the mirrored dip), never the
    recording's own, with ``|dip| >= 10 deg``, where no tilt error reaches the mirrored dip.  Meaningful only for dips measured against a full up vector (a three-axis
    accelerometer): an assumed level housing or a two-axis tilt sensor upside down mirror the dip
    themselves.

    Parameters
    ----------
    dip_deg : ndarray, shape (n,)
        The measured field's angle below the horizontal per row, degrees.
    reference : ReferenceField
    bench_sign_ambiguous : bool
        The calibration came from a four-flip bench without an accelerometer, whose data cannot
        tell the hemisphere: the message then names that cause and its cure.
    """
    if reference.source == "recording" or abs(reference.dip_deg) < _MIN_SIGNED_DIP_DEG:
        return None
    dips = np.asarray(dip_deg, float)
    dips = dips[np.isfinite(dips)]
    if dips.size == 0:
        return None
    median = float(np.median(dips))
    if abs(median + reference.dip_deg) >= abs(median - reference.dip_deg):
        return None
    if reference.source == "calibration" and (abs(median + reference.dip_deg) > _MIRROR_DIP_DEG
                                              or abs(median) < _MIN_SIGNED_DIP_DEG):
        return None
    way = ("up", "down") if reference.dip_deg > 0 else ("down", "up")
    cause = ("A bench in the other hemisphere calibrated without its latitude? (the bench data cannot tell "
             "(a, B) from (-a, -B)): recalibrate with '# site_lat_deg:' in the recording or --site LAT,LON"
             if bench_sign_ambiguous else
             "Check the signs of the recording's magnetometer and accelerometer columns against the calibration's "
             "(a negated axis, e.g. az=-AccZ in --columns) and the site")
    if reference.source == "calibration site":  # the bench's site, taken where no --site said the module's
        cause += ("; or the module is not at its calibration's site (the reference taken without --site): give "
                  "--site LAT,LON where it is")
    if reference.source == "calibration":  # the calibration's own dip, measured against its accelerometer
        cause = ("An accelerometer that reads gravity, not specific force (all three axes reversed: az about -1 g "
                 "when level at rest, where SPEC's reads +1 g)? Read it negated with --accel-sign -1. Else check the "
                 "signs of the stream's magnetometer and accelerometer columns against the calibration's (two axes "
                 "reversed, a chip mounted turned: negate those, e.g. ay=-AccY,az=-AccZ in --columns; the axes check "
                 "names them); or the module is across the magnetic equator from where it was calibrated: give --site "
                 "LAT,LON where it is")
    against = (f"its calibration measured it pointing {way[1]} (dip {reference.dip_deg:+.1f} deg): the stream reads "
               f"the field upside down against its calibration" if reference.source == "calibration" else
               f"the {reference.source} reference has it pointing {way[1]} (dip {reference.dip_deg:+.1f} deg): the "
               f"calibration's field is upside down")
    return (f"the calibrated readings have the field pointing {way[0]} (median dip {median:+.1f} deg) where "
            f"{against}, and every heading would be 180 deg off. {cause}")
