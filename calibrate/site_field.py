"""An external reference for what the bench cannot see: the World Magnetic Model at the site.

A fixed tilt of the turntable axis, or a local disturbance that is uniform over the cube,
changes the field the bench sees without leaving any trace in the residual (the dip absorbs
it).  Only a comparison with the expected field at the site and date shows it.

We use ``pygeomag`` (a pure-Python port of NOAA's World Magnetic Model with the WMM2025
coefficients, no dependencies): the model's own coefficients and synthesis are not code we should
write.  The WMM's published 1-sigma uncertainty for inclination (0.21 deg for WMM2025) and total
intensity (145 nT) is combined with the fit's sigma; crustal anomalies and buildings routinely
reach a degree, so a difference of a few sigma is a flag to look at, not a verdict.
"""

from __future__ import annotations

import datetime as dt

from compass.io.table import RecordingError
from compass.site import decimal_year, wmm_field

__all__ = ["WMM_DIP_SIGMA_DEG", "WMM_F_SIGMA_UT", "expected_field", "compare_with_site", "describe"]

WMM_DIP_SIGMA_DEG = 0.21
WMM_F_SIGMA_UT = 0.145


def _decimal_year(text: str, path: str) -> float:
    try:
        return decimal_year(dt.date.fromisoformat(text.strip()[:10]))
    except ValueError:
        raise RecordingError(path, f"metadata 'date' should be YYYY-MM-DD, got {text!r}") from None


def expected_field(lat_deg: float, lon_deg: float, decimal_year: float, altitude_km: float = 0.0) -> dict:
    """Dip (deg, > 0 down), total intensity (uT) and declination (deg) from the WMM (:func:`compass.site.wmm_field`)."""
    f = wmm_field(lat_deg, lon_deg, decimal_year, altitude_km)
    return {"dip_deg": f.dip_deg, "field_ut": f.field_ut, "declination_deg": f.declination_deg}


def compare_with_site(dip_deg: float, dip_sigma_deg: float | None, metadata: dict, path: str = "<recording>") -> dict | None:
    """Compare a fitted dip (and the recorded |B|) with the WMM at the site and date.

    Parameters
    ----------
    dip_deg, dip_sigma_deg : float
        The calibration's dip and its sigma.
    metadata : dict
        The recording's ``# key: value`` metadata; needs ``site_lat_deg``, ``site_lon_deg`` and
        ``date`` (``site_alt_m`` optional).

    Returns
    -------
    dict or None
        None when the metadata does not give site and date; otherwise the model's values, the
        differences and the differences in sigmas.
    """
    if not all(k in metadata for k in ("site_lat_deg", "site_lon_deg", "date")):
        return None
    values = {}
    for key in ("site_lat_deg", "site_lon_deg", "site_alt_m"):
        if key in metadata:
            try:
                values[key] = float(metadata[key])
            except ValueError:
                raise RecordingError(path, f"metadata '{key}' should be a number, got {metadata[key]!r}") from None
    if not -90 <= values["site_lat_deg"] <= 90:
        raise RecordingError(path, f"metadata 'site_lat_deg' must be in [-90, 90], got {values['site_lat_deg']}")
    year = _decimal_year(metadata["date"], path)
    model = expected_field(values["site_lat_deg"], values["site_lon_deg"], year, values.get("site_alt_m", 0.0) / 1000.0)
    sigma = (WMM_DIP_SIGMA_DEG**2 + (dip_sigma_deg or 0.0) ** 2) ** 0.5
    out = {
        "model": "WMM (pygeomag)",
        "decimal_year": year,
        "model_dip_deg": model["dip_deg"],
        "model_field_ut": model["field_ut"],
        "model_declination_deg": model["declination_deg"],
        "dip_difference_deg": dip_deg - model["dip_deg"],
        "dip_difference_sigma": (dip_deg - model["dip_deg"]) / sigma,
    }
    if "field_ut" in metadata:
        try:
            recorded = float(metadata["field_ut"])
        except ValueError:
            recorded = None
        if recorded is not None:
            out["recorded_field_ut"] = recorded
            out["field_difference_ut"] = recorded - model["field_ut"]
            out["field_difference_sigma"] = (recorded - model["field_ut"]) / WMM_F_SIGMA_UT
    return out


def describe(comparison: dict) -> str:
    """One or two lines for the report."""
    c = comparison
    text = (f"Site check against the {c['model']} for {c['decimal_year']:.2f}: dip {c['model_dip_deg']:.2f} deg, "
            f"|B| {c['model_field_ut']:.2f} uT; fitted dip differs by {c['dip_difference_deg']:+.2f} deg "
            f"({c['dip_difference_sigma']:+.1f} sigma)")
    if abs(c["dip_difference_sigma"]) > 3:
        text += ("\n  the bench's dip is off the model's by more than 3 sigma: a tilted turntable axis, "
                 "a magnetic object near the bench, or a crustal anomaly (the residual cannot show these)")
    if "field_difference_ut" in c:
        text += f"\n  the recording's field_ut differs from the model's |B| by {c['field_difference_ut']:+.2f} uT"
    return text
