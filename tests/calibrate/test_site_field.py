"""The external reference: the fitted dip against the World Magnetic Model at the site."""

import pytest

from calibrate import calibrate_fourflip
from calibrate.site_field import WMM_DIP_SIGMA_DEG, compare_with_site, expected_field
from compass.io.table import RecordingError

SITE = {"site_lat_deg": "31.8", "site_lon_deg": "117.3", "date": "2026-11-22"}  # Hefei, the seed's site


def test_model_values_are_plausible_for_hefei():
    m = expected_field(31.8, 117.3, 2026.9)
    assert 45 < m["dip_deg"] < 53 and 47 < m["field_ut"] < 54


def test_bench_at_model_dip_agrees_and_tilted_bench_is_flagged(write_session):
    model_dip = expected_field(31.8, 117.3, 2026.89)["dip_deg"]
    rec, _ = write_session("a.csv", seed=300, dip_deg=model_dip)
    check = compare_with_site(*_dip(rec), {**rec.metadata, **SITE})
    assert abs(check["dip_difference_sigma"]) < 1.0
    # a turntable axis tilted by 1 deg toward north shifts the apparent dip by 1 deg:
    # invisible in the residual, about 5 sigma against the model
    rec, _ = write_session("b.csv", seed=301, dip_deg=model_dip + 1.0)
    check = compare_with_site(*_dip(rec), {**rec.metadata, **SITE})
    assert check["dip_difference_sigma"] == pytest.approx(1.0 / WMM_DIP_SIGMA_DEG, rel=0.1)


def _dip(rec):
    result = calibrate_fourflip(rec)
    return result.dip_deg, result.dip_sigma_deg


def test_no_site_no_check():
    assert compare_with_site(50.0, 0.01, {"field_ut": "50"}) is None


def test_bad_date_is_bad_input():
    with pytest.raises(RecordingError, match="date"):
        compare_with_site(50.0, 0.01, {**SITE, "date": "22/11/2026"}, "rec.csv")
