"""Temperature compensation at runtime, from the ``temperature`` effect of a calibration file.

When the residual diagnosis (SPEC section 4) finds a channel's output changing with the sensor
temperature ``T``, the calibration file describes the channel at a reference temperature
``T_ref`` (the effect's ``reference.temp_c``) and the effect gives how the output departs from it:

.. math::

    v(T) = V_0 + \\delta V\\,(T - T_{ref}) + \\big(1 + g\\,(T - T_{ref})\\big)\\,(v_{ref} - V_0),

``v_ref`` the output the channel would give at ``T_ref`` (what the file's response describes),
``V_0`` its zero-field output, ``dV`` the offset's change (output units per degC) and ``g`` the
relative change of the gain per degC.  At runtime the reading is taken back to ``T_ref``,

.. math::

    v_{ref} = V_0 + \\frac{v - V_0 - \\delta V\\,(T - T_{ref})}{1 + g\\,(T - T_{ref})},

and then inverted through the response as usual.  The fits spell the parameters per channel
``ch`` in their own units; all mean the same two numbers:

=====================================  ==========================================  ==============
fit                                    offset change                               gain change
=====================================  ==========================================  ==============
four-flip                              ``ch.offset_fieldunit_per_degc`` (x gain)   ``ch.gain_rel_per_degc``
3-D platform, reference fields         ``ch.offset_per_degc``                      ``ch.gain_rel_per_degc``
tumble                                 ``ch.hard_iron_per_degc``                   ``ch.scale_rel_per_degc``
=====================================  ==========================================  ==============

The effect is linear in temperature and was fitted over the calibration's temperature span: far
outside it the compensation extrapolates.  A channel whose gain factor ``1 + g (T - T_ref)`` falls
below one half is reported out of range.  An ``offset_drift`` effect is not applied at runtime: it is a function of the time within the
calibration session, which a later recording does not know; the file's offsets are the ones at the
effect's ``reference`` (a time of the session, or after the warm-up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["TemperatureCompensation"]

_OFFSET_KEYS = (("offset_fieldunit_per_degc", True), ("offset_per_degc", False), ("hard_iron_per_degc", False))
_GAIN_KEYS = ("gain_rel_per_degc", "scale_rel_per_degc")


@dataclass(frozen=True)
class TemperatureCompensation:
    """How each channel's output departs from the calibrated one with temperature.

    Attributes
    ----------
    reference_c : float or None
        Temperature the file's responses hold at, degC; None when the file names none (written
        before the effects carried their reference): the effect is then known but not usable.
    offset_per_degc : ndarray, shape (c,)
        Change of each channel's zero-field output, output units per degC.
    gain_rel_per_degc : ndarray, shape (c,)
        Relative change of each channel's gain, per degC.
    """

    reference_c: float | None
    offset_per_degc: np.ndarray
    gain_rel_per_degc: np.ndarray

    @classmethod
    def from_effects(cls, effects, channels, gains) -> "TemperatureCompensation | None":
        """The compensation a file's ``effects`` list describes, or None without a ``temperature`` effect.

        Parameters
        ----------
        effects : list of dict or None
            The file's ``effects`` (``{"name", "parameters", "reference"}``).
        channels : sequence of str
            Channel names, in the model's order.
        gains : ndarray, shape (c,)
            Each channel's gain, output units per field unit (for the four-flip's spelling).

        Raises
        ------
        ValueError
            More than one ``temperature`` effect, a parameter that names no channel of the model or
            no known coefficient, or one that is not a number.
        """
        found = [e for e in effects or () if isinstance(e, dict) and e.get("name") == "temperature"]
        if not found:
            return None
        if len(found) > 1:
            raise ValueError(f"{len(found)} temperature effects: expected one")
        effect = found[0]
        reference = (effect.get("reference") or {}).get("temp_c")
        usable = isinstance(reference, (int, float)) and np.isfinite(reference)
        params = dict(effect.get("parameters") or {})
        offset = np.zeros(len(channels))
        gain = np.zeros(len(channels))
        for c, name in enumerate(channels):
            for key, in_field_units in _OFFSET_KEYS:
                if f"{name}.{key}" in params:
                    offset[c] = _value(params.pop(f"{name}.{key}"), key) * (gains[c] if in_field_units else 1.0)
            for key in _GAIN_KEYS:
                if f"{name}.{key}" in params:
                    gain[c] = _value(params.pop(f"{name}.{key}"), key)
        if params:
            raise ValueError(f"temperature effect: {', '.join(sorted(params))} name no channel of the model "
                             f"({', '.join(channels)}) or no known coefficient")
        return cls(float(reference) if usable else None, offset, gain)

    def to_reference(self, raw: np.ndarray, temp_c, zero_outputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Outputs taken back to the reference temperature (module docstring).

        Parameters
        ----------
        raw : ndarray, shape (..., c)
            Channel outputs, output units.
        temp_c : float or array_like, shape (...)
            Sensor temperature of each reading, degC.
        zero_outputs : ndarray, shape (c,)
            Each channel's zero-field output at the reference temperature (``V_0``).

        Returns
        -------
        outputs : ndarray, shape (..., c)
        valid : ndarray of bool, shape (..., c)
            False where the gain factor ``1 + g (T - T_ref)`` is below one half (far outside the
            calibrated temperatures).

        Raises
        ------
        ValueError
            The effect names no reference temperature.
        """
        if self.reference_c is None:
            raise ValueError("the calibration's temperature effect names no reference temperature "
                             "('reference': {'temp_c': ..}): recalibrate to compensate temperature")
        dt = (np.asarray(temp_c, dtype=float) - self.reference_c)[..., None]
        factor = 1.0 + dt * self.gain_rel_per_degc
        valid = factor > 0.5
        return zero_outputs + (raw - zero_outputs - dt * self.offset_per_degc) / np.where(valid, factor, 1.0), valid

    def to_json(self, channels) -> dict:
        """The effect entry in the runtime's own spelling (output units)."""
        params = {}
        for c, name in enumerate(channels):
            params[f"{name}.offset_per_degc"] = {"value": float(self.offset_per_degc[c])}
            params[f"{name}.gain_rel_per_degc"] = {"value": float(self.gain_rel_per_degc[c])}
        return {"name": "temperature", "parameters": params, "reference": {"temp_c": self.reference_c}}


def _value(entry, key: str) -> float:
    value = entry.get("value") if isinstance(entry, dict) else entry
    if not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ValueError(f"temperature effect: '{key}' must be a finite number, got {value!r}")
    return float(value)
