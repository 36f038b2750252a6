"""A reference field that follows the place: a new room's field is told from a magnet on the housing.

**Model.**  The gyro filter's attitude ``R = R_world<-housing`` carries the heading through a
rejection (the gyro's), so a field sample ``b_H`` can be seen in the world frame, ``b_W = R b_H``.
Two explanations of a field the gate keeps rejecting (|B| or dip beyond its tolerances):

- **a new place** (another room, a building's steel): the field is another world-fixed vector
  ``c``, with its own |B|, dip and azimuth (steel turns the horizontal field: the heading
  reference moves too).  Then ``b_W = c + n``: constant in the world frame while the housing turns;
  the heading it gives changes as the gyro's does (the two agree up to a constant, the azimuth of
  ``c``).
- **a magnet on the housing**: a constant field ``m`` in the housing frame on top of the reference
  ``e`` (the world vector of the reference |B|, dip and azimuth).  Then ``b_H - R^T e = m + n``:
  constant in the housing frame, and ``b_W = e + R m`` turns with the housing.

Over a window of ``place_window_s`` (W) the scatter (mean square about the mean, per component,
field units^2) of ``b_W`` tests the first and the scatter of ``d_H = b_H - R^T e`` the second, each
against the variance its hypothesis leaves:

.. math::

    \\sigma^2_{place} = \\sigma_n^2 + |c|^2 \\big(\\sigma_{dir}^2 + P_{tilt}\\big) + |c_h|^2 Q_W, \\qquad
    \\sigma^2_{magnet} = \\sigma_n^2 + |c|^2 \\sigma_{dir}^2 + |e|^2 P_{tilt} + |e_h|^2 P_{heading},

the sensor noise, the field's own direction error (the gate's measured dip wander, floored by
``mag_heading_sigma_deg``: calibration residue and inhomogeneity), and the attitude's error (a
heading error moves only the horizontal parts ``c_h``, ``e_h``; each error's whole displacement is
charged to every component, a bound on the safe side).  A
constant attitude error turns every ``b_W`` alike and leaves the world-frame scatter alone: only
what the heading drifts within the window counts there, ``Q_W`` (the gyro's white noise over W, its
scale error over the angle turned, its bias uncertainty times W); but it turns the reference ``e``
seen from the turning housing, so the whole attitude variance counts against the magnet.  The errors
are correlated over ``field_error_time_s``, so the window holds ``k = 3 max(1, W /
field_error_time_s)`` independent components; the place hypothesis is kept when its mean square is
below ``sigma_place^2 chi2_{0.999}(k) / k`` and the magnet hypothesis rejected when its mean
square is above ``sigma_magnet^2 chi2_{0.999}(k) / k``.  The reference moves to ``c`` (its |B|,
dip and azimuth) only when both hold and ``c`` differs from the reference as the gate judges a
sample (``field_tolerance``, ``dip_tolerance_deg``).  Its azimuth moves the heading reference only
when the turn from the last North is beyond the heading's and the field's own error (chi-square,
99.9 %): a smaller one is the heading's error of that moment, which the new field then corrects.

The other way round, the place hypothesis rejected and the magnet one kept with the housing frame's
scatter under a quarter of the world frame's (:data:`_MAGNET_SHARE`: a field that changes in time while
the housing hardly turns leaves both alike), is a magnet (or iron) on the housing told as such: the
gate's timeout (``gate_timeout_s``) then does not adopt its field
(``GateState.magnet_on_housing``), which would be wrong by the magnet's field at every attitude, and a
sample must agree with the gyro's heading too, until a window shows the reference's own |B| and dip steady
in the world frame (:data:`REFERENCE`: the magnet gone) or a new place.

A housing that does not turn cannot tell the two apart (a body-fixed and a world-fixed offset look
the same): the magnet hypothesis is then not rejected and the reference does not move; turning only
about the vertical cannot tell a change of the vertical field either.  The gate's timeout
(``gate_timeout_s``) still adopts a field rejected without a break and not told to be a magnet.

The window is ``_BLOCKS`` blocks of ``W / _BLOCKS`` seconds (sums of the samples, O(1) per
sample); the test runs at each block's end on the last ``_BLOCKS`` blocks, so a field from before
the move leaves the window within ``W`` of the move (an exponential window would keep it for many
time constants).  Without a gyro the heading coasts through a rejection and cannot see the world
frame: the two-vector filter has no place rule.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from scipy.special import chdtri  # chi2.ppf(q, k) == chdtri(k, 1 - q), without importing scipy.stats (a second of start-up)

from ._records import FilterConfig

__all__ = ["PlaceState", "PlaceDetector", "FieldChange", "PLACE", "MAGNET", "REFERENCE", "PLACE_EVENT", "MAGNET_EVENT"]

PLACE_EVENT = "the field moved"
"""How the filter's event note of a move to a new place begins."""
MAGNET_EVENT = "the field turns with the housing"
"""How the filter's event note of a magnet told on the housing begins."""

PLACE, MAGNET, REFERENCE = "place", "magnet", "reference"
""":attr:`FieldChange.kind`'s values."""

_BLOCKS = 4  # blocks per window
_CONFIDENCE = 0.999  # each hypothesis' test, one-sided
_MAGNET_SHARE = 0.25
"""A magnet is told only when the housing frame's scatter is at most this share of the world frame's (rms half).
The magnet's bound is loose (the whole attitude variance: on the safe side for rejecting it), so a field that
changes in time while the housing hardly turns (a walk), which both frames see alike, passes it while failing the
place's tight one; the housing's turns are what make the world frame's scatter and not the housing frame's.
``tools/bench_place.py``'s walks: 1.01 on the walks, 2.2-24 on the magnets (rms ratios)."""


@dataclass(slots=True)
class PlaceState:
    """The place detector's sums (part of the gyro filter's state).

    Attributes
    ----------
    block : list of float
        The current block's sums: duration (s), samples, ``sum b_W`` (3), ``sum |b_W|^2``,
        ``sum d_H`` (3), ``sum |d_H|^2`` (field units), ``sum |omega|^2 dt`` (rad^2/s).
    done : list of list of float
        The last complete blocks' sums, oldest first (at most ``_BLOCKS``).
    """

    block: list = field(default_factory=lambda: [0.0] * 11)
    done: list = field(default_factory=list)

    def clear(self) -> None:
        """Forget the window (the reference changed: ``d_H`` is measured against another one)."""
        self.block = [0.0] * 11
        self.done = []


@dataclass(frozen=True)
class FieldChange:
    """What a window told of a field unlike the reference: a new place, or a magnet on the housing.

    Attributes
    ----------
    kind : str
        :data:`PLACE`: a new place (steady in the world frame, not in the housing's about the reference);
        :data:`MAGNET`: a magnet or iron on the housing (steady in the housing frame, not in the world's);
        :data:`REFERENCE`: the reference's own |B| and dip, steady in the world frame (a magnet gone).
    field_norm : float
        |B| of the window's mean field in the world frame, field units.
    dip_deg : float
        Its dip, degrees.
    azimuth_rad : float
        Its azimuth in the filter's world frame, rad (toward West, from the filter's North).
    place_rms, magnet_rms : float
        The window's per-component rms scatter in the world frame (the place hypothesis) and in the
        housing frame about the reference (the magnet hypothesis), field units.
    place_bound_rms, magnet_bound_rms : float
        The bounds they are judged against, field units: a place is within the first and beyond the second, a
        magnet the other way round.
    """

    kind: str
    field_norm: float
    dip_deg: float
    azimuth_rad: float
    place_rms: float
    magnet_rms: float
    place_bound_rms: float
    magnet_bound_rms: float


class PlaceDetector:
    """Tell a new place's field from a magnet on the housing (module docstring).

    Parameters
    ----------
    config : FilterConfig
        ``place_window_s``, ``field_error_time_s``, ``mag_noise`` and the gate's tolerances.

    Examples
    --------
    >>> cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1)
    >>> PlaceDetector(cfg).bound_factor > 1.0
    True
    """

    def __init__(self, config: FilterConfig):
        self.config = config
        self.block_s = config.place_window_s / _BLOCKS
        dof = 3.0 * max(1.0, config.place_window_s / config.field_error_time_s)
        self.bound_factor = float(chdtri(dof, 1.0 - _CONFIDENCE) / dof)
        """The bound on a mean square over ``sigma^2``: the chi-square quantile over its degrees of freedom."""

    def add(self, state: PlaceState, dt: float, m: tuple, b: tuple, e: tuple, rate2: float) -> bool:
        """Add one field sample; True when a block closed (the window can be judged, :meth:`judge`).

        Parameters
        ----------
        state : PlaceState
            Updated in place.
        dt : float
            Time since the last sample, s.
        m : tuple of 9 floats
            ``R_world<-housing``, row-major (the gyro-propagated attitude before this sample's field).
        b : tuple
            The field in H ``(x, y, z, ...)``, field units.
        e : tuple of 3 floats
            The reference field in the world frame, field units.
        rate2 : float
            The squared (bias-corrected) turn rate, (rad/s)^2.
        """
        bx, by, bz = b[0], b[1], b[2]
        ex, ey, ez = e
        wx = m[0] * bx + m[1] * by + m[2] * bz
        wy = m[3] * bx + m[4] * by + m[5] * bz
        wz = m[6] * bx + m[7] * by + m[8] * bz
        dx = bx - (m[0] * ex + m[3] * ey + m[6] * ez)
        dy = by - (m[1] * ex + m[4] * ey + m[7] * ez)
        dz = bz - (m[2] * ex + m[5] * ey + m[8] * ez)
        s = state.block
        s[0] += dt
        s[1] += 1.0
        s[2] += wx
        s[3] += wy
        s[4] += wz
        s[5] += wx * wx + wy * wy + wz * wz
        s[6] += dx
        s[7] += dy
        s[8] += dz
        s[9] += dx * dx + dy * dy + dz * dz
        s[10] += rate2 * dt
        if s[0] < self.block_s:
            return False
        state.done.append(s)
        if len(state.done) > _BLOCKS:
            del state.done[0]
        state.block = [0.0] * 11
        return len(state.done) == _BLOCKS

    def judge(self, state: PlaceState, ref_norm: float, ref_dip_deg: float, direction_var: float,
              tilt_var: float, heading_var: float, drift: tuple) -> FieldChange | None:
        """What the window shows of its field: a new place, a magnet on the housing, the reference's own field
        steady in the world frame, or None (not told apart).

        Parameters
        ----------
        state : PlaceState
        ref_norm, ref_dip_deg : float
            The gate's reference |B| (field units) and dip (degrees).
        direction_var : float
            The field's own direction error, rad^2 per axis.
        tilt_var, heading_var : float
            The attitude's error variance about a horizontal axis and about the vertical, rad^2.
        drift : tuple of 3 floats
            What the heading's error gains over the window: the gyro's white rate variance density
            ((rad/s)^2/Hz), its scale-error variance times its correlation time (s), the bias
            variance about the vertical ((rad/s)^2).
        """
        n = sum(blk[1] for blk in state.done)
        if n < 2.0:
            return None
        sums = [sum(blk[k] for blk in state.done) / n for k in range(2, 10)]
        cx, cy, cz, c2, mx, my, mz, d2 = sums
        window_s = sum(blk[0] for blk in state.done)
        turn2 = sum(blk[10] for blk in state.done)
        c_norm = math.sqrt(cx * cx + cy * cy + cz * cz)
        if c_norm == 0.0:
            return None
        dip = math.degrees(math.asin(max(-1.0, min(1.0, -cz / c_norm))))
        cfg = self.config
        place = max(0.0, c2 - c_norm * c_norm) / 3.0
        magnet = max(0.0, d2 - (mx * mx + my * my + mz * mz)) / 3.0
        gyro_var, scale_var, bias_var = drift
        heading_drift = gyro_var * window_s + scale_var * turn2 + bias_var * window_s * window_s
        own = cfg.mag_noise**2 + c_norm * c_norm * direction_var
        # a turn about the vertical moves only the horizontal part of a field, cos(dip) of it
        c_h2, e_h2 = (cx * cx + cy * cy), ref_norm * ref_norm * math.cos(math.radians(ref_dip_deg)) ** 2
        place_bound = self.bound_factor * (own + c_norm * c_norm * tilt_var + c_h2 * heading_drift)
        magnet_bound = self.bound_factor * (own + ref_norm * ref_norm * tilt_var + e_h2 * heading_var)
        same = abs(c_norm / ref_norm - 1.0) <= cfg.field_tolerance and abs(dip - ref_dip_deg) <= cfg.dip_tolerance_deg
        if place <= place_bound and (same or magnet > magnet_bound):
            kind = REFERENCE if same else PLACE
        elif not same and place > place_bound and magnet <= min(magnet_bound, _MAGNET_SHARE * place):
            kind = MAGNET
        else:
            return None  # both kept (a housing that hardly turned), both rejected, or a change in time
        return FieldChange(kind, c_norm, dip, math.atan2(cy, cx), math.sqrt(place), math.sqrt(magnet),
                           math.sqrt(place_bound), math.sqrt(magnet_bound))
