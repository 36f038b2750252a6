"""The magnetic-disturbance gate shared by the gyro and the two-vector filter (testable alone).

VQF's and Fusion's magnetic rejection: the field is used only while its magnitude and its dip
against the filter's own up direction match a reference within tolerances, and (once the heading
is settled) its heading innovation is small.  The reference starts from the configured |B| and dip
and follows the accepted field slowly (``field_reference_tau_s``), so a field that changes across a
room is followed while a fast change (a magnet) is rejected.  A rejection longer than
``gate_timeout_s`` means the environment changed: the current |B| and dip become the reference
(VQF's ``magNewTime``).  While a field is told to turn with the housing (a magnet on it:
``GateState.magnet_on_housing``, :mod:`compass.filter._place`) a sample must pass the innovation test too
and no time makes the field the place's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ._records import FilterCoefficients, FilterConfig

__all__ = ["GateState", "MagneticGate"]


@dataclass(slots=True)
class GateState:
    """The gate's state (part of the filter's state).

    Attributes
    ----------
    ref_norm : float
        Reference |B|, field units.
    ref_dip_deg : float
        Reference dip, degrees.
    rejected_since_s : float or None
        Start of the current rejection, s.
    dip_excess_var : float
        Mean square of the accepted field's dip deviation beyond the sensor noise, rad^2.
    ref_azimuth_rad : float
        Azimuth of the reference field's horizontal part in the world frame, toward West, rad: 0
        where the filter's North is the field's (the start), another where the reference moved to a
        place whose field steel turned (:mod:`compass.filter._place`).
    north_from_gyro : bool
        The heading's North has come down from the start's field through the gyro and verified
        moves; False once a timeout re-learnt it from a field nothing verified (a magnet on the
        housing held long enough): a later move cannot then measure a turn of North against it.
    magnet_on_housing : bool
        The rejected field was seen steady in the housing frame while the housing turned, not in the world's
        (:mod:`compass.filter._place`): a magnet or iron on the housing.  A sample is refused (``"magnet"``) unless
        it passes the heading innovation test too, settled or not (a sample its field lets through by chance turns
        the heading: a tracked hard iron's corrected field passes), and the timeout does not adopt it; a window of
        the reference's own field steady in the world frame, or a new place, ends it.
    """

    ref_norm: float
    ref_dip_deg: float
    rejected_since_s: float | None
    dip_excess_var: float
    ref_azimuth_rad: float = 0.0
    north_from_gyro: bool = True
    magnet_on_housing: bool = False

    def world_field(self) -> tuple[float, float, float]:
        """The reference field in the world frame (NWU), field units."""
        dip, az = math.radians(self.ref_dip_deg), self.ref_azimuth_rad
        h = self.ref_norm * math.cos(dip)
        return h * math.cos(az), h * math.sin(az), -self.ref_norm * math.sin(dip)

    @classmethod
    def initial(cls, config: FilterConfig, coefficients: FilterCoefficients) -> "GateState":
        return cls(config.field_norm, config.dip_deg, None, coefficients.env_floor_var * coefficients.cos_dip2)


class MagneticGate:
    """Decide whether one field sample may correct the heading, and follow the reference.

    Parameters
    ----------
    config : FilterConfig
    coefficients : FilterCoefficients

    Examples
    --------
    >>> cfg = FilterConfig(field_norm=50.0, dip_deg=60.0, mag_noise=0.1)
    >>> gate = MagneticGate(cfg, FilterCoefficients.from_config(cfg))
    >>> state = GateState.initial(cfg, gate.coefficients)
    >>> gate.check(state, 0.0, 0.01, 50.0, 60.0, 0.0, True), gate.check(state, 0.01, 0.01, 70.0, 60.0, 0.0, True)
    ('ok', 'norm')
    """

    ADOPTED = "adopted"
    """:meth:`check`'s answer when a long rejection made the current field the new reference."""
    MAGNET = "magnet"
    """:meth:`check`'s answer while a magnet is told on the housing (``GateState.magnet_on_housing``)."""

    def __init__(self, config: FilterConfig, coefficients: FilterCoefficients):
        self.config = config
        self.coefficients = coefficients

    def check(self, state: GateState, t_s: float, dt: float, b_norm: float, dip_deg: float,
              innovation_rad: float, settled: bool) -> str:
        """Gate one field sample and update ``state``.

        Parameters
        ----------
        state : GateState
            Updated in place.
        t_s, dt : float
            Sample time and interval, s (``dt = 0`` freezes the reference).
        b_norm : float
            Measured |B|, field units (0: no field).
        dip_deg : float
            Measured dip against the filter's up direction, degrees.
        innovation_rad : float
            Heading innovation, rad.
        settled : bool
            The heading is known well enough for the innovation test.

        Returns
        -------
        str
            ``"ok"``, ``"absent"``, ``"norm"``, ``"dip"``, ``"innovation"``, :attr:`MAGNET` or :attr:`ADOPTED`.
        """
        cfg = self.config
        if b_norm == 0.0:
            return "absent"
        if not cfg.gate:
            return "ok"
        magnet = state.magnet_on_housing
        if abs(b_norm / state.ref_norm - 1.0) > cfg.field_tolerance:
            reason = "norm"
        elif abs(dip_deg - state.ref_dip_deg) > cfg.dip_tolerance_deg:
            reason = "dip"
        elif (settled or magnet) and abs(math.degrees(innovation_rad)) > cfg.heading_tolerance_deg:
            reason = "innovation"
        else:
            state.rejected_since_s = None
            if dt > 0.0:  # the reference follows the accepted field slowly (VQF's magRefTau)
                alpha = -math.expm1(-dt / cfg.field_reference_tau_s)
                # the dip's wander beyond the white sensor noise (the filter's own tilt error stays in: it is
                # correlated like the environment's, and moves the heading as much, tan(dip) ~ 1 / cos(dip))
                excess = math.radians(dip_deg - state.ref_dip_deg) ** 2 - self.coefficients.dip_noise_var
                state.dip_excess_var += alpha * (excess - state.dip_excess_var)
                state.ref_norm += alpha * (b_norm - state.ref_norm)
                state.ref_dip_deg += alpha * (dip_deg - state.ref_dip_deg)
            return "ok"
        if magnet:  # no timeout: its field is never the place's
            state.rejected_since_s = None
            return self.MAGNET
        if state.rejected_since_s is None:
            state.rejected_since_s = t_s
        elif t_s - state.rejected_since_s > cfg.gate_timeout_s:
            state.ref_norm, state.ref_dip_deg, state.ref_azimuth_rad = b_norm, dip_deg, 0.0
            state.north_from_gyro = False
            state.rejected_since_s = None
            return self.ADOPTED
        return reason

    def field_heading_var(self, state: GateState) -> float:
        """Heading error variance of the accepted field itself, rad^2: the larger of the configured floor
        and the one measured from the wander of its dip."""
        c = self.coefficients
        if not self.config.field_error_from_dip:
            return c.env_floor_var
        return max(c.env_floor_var, state.dip_excess_var / c.cos_dip2)
