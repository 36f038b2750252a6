"""compass.production: the acceptance spec, the figures, the control chart, the store."""

import math
import sqlite3

import numpy as np
import pytest

from compass.model import SensorModel
from compass.production.control import ewma_chart
from compass.production.figures import FIGURES, classify_warning, heading_error_deg, module_figures
from compass.production.spec import SpecError, load_spec, parse_spec
from compass.production.store import (SCHEMA_VERSION, SessionTimeError, Store, StoreError, module_outcome,
                                     module_outcomes, session_time_text)
from compass.response import LinearResponse


# ---------------------------------------------------------------------------------------------- spec


def test_the_default_spec_loads_and_limits_only_known_figures():
    spec = load_spec()
    assert spec.limits and set(spec.limits) <= set(FIGURES)
    assert spec.fail_unexplained and "channel" in spec.fail_on_warnings


@pytest.mark.parametrize("text, key", [
    ("[limits]\ndirection_sigma = { max = 1.0 }\n", "'limits.direction_sigma': unknown figure"),
    ("[limits]\nsnr_min = { min = 'high' }\n", "'limits.snr_min.min': expected a number"),
    ("[limits]\nsnr_min = { minimum = 3 }\n", "'limits.snr_min.minimum': unknown key"),
    ("[limits]\ngain_spread = { min = 2, max = 1 }\n", "'limits.gain_spread': min 2 is above max 1"),
    ("[site]\ndip_deg = 100\n", "'site.dip_deg': expected >= -90 and <= 90"),
    ("[warnings]\nfail_on = ['chanel']\n", "'warnings.fail_on': unknown name 'chanel'"),
    ("[unexplained]\nfail = 'yes'\n", "'unexplained.fail': expected true or false"),
    ("[control]\nbaseline_sessions = 2.5\n", "'control.baseline_sessions': expected a whole number"),
    ("[limit]\n", "'limit': unknown key"),
    ("[limits\n", "not valid TOML"),
    ("", "no [limits]: the spec judges no figure"),  # an empty or truncated file
    ("[site]\ndip_deg = 60.0\n", "no [limits]: the spec judges no figure"),
    ("[limits]\n[unexplained]\nfail = true\n", "no [limits]: the spec judges no figure"),
])
def test_a_malformed_spec_is_refused_naming_the_key(text, key):
    with pytest.raises(SpecError, match=f"^acceptance.toml: .*{key}".replace("[", r"\[").replace("(", r"\(")
                       .replace("{", r"\{").replace("}", r"\}")):
        parse_spec(text, source="acceptance.toml")


def _figures(**changes):
    f = {name: 1.0 for name in FIGURES}
    f.update(unexplained=False, warning_classes=[])
    f.update(changes)
    return f


def test_judge_names_every_figure_past_its_limit_and_notes_the_missing():
    spec = parse_spec("[limits]\ngain_spread = { max = 0.3 }\nsnr_min = { min = 100 }\n"
                      "direction_sigma_deg = { max = 0.3 }\n[warnings]\nfail_on = ['channel']\n")
    ok = spec.judge(_figures(gain_spread=0.1, snr_min=300.0, direction_sigma_deg=0.05))
    assert ok.status == "accepted" and ok.reasons == ()
    bad = spec.judge(_figures(gain_spread=0.5, snr_min=20.0, direction_sigma_deg=None, unexplained=True,
                              warning_classes=["channel", "other"]))
    assert bad.status == "rejected"
    assert any(r.startswith("gain_spread 0.5 fraction above the limit 0.3") for r in bad.reasons)
    assert any(r.startswith("snr_min 20 ratio below the limit 100") for r in bad.reasons)
    assert any(r.startswith("unexplained") for r in bad.reasons)
    assert "warning of class 'channel'" in bad.reasons and "warning of class 'other'" not in bad.reasons
    assert bad.notes == ("direction_sigma_deg: not judged: not given by this calibration",)
    strict = parse_spec("[limits]\ndirection_sigma_deg = { max = 0.3 }\n[missing]\nfail = true\n")
    assert strict.judge(_figures(direction_sigma_deg=None)).status == "rejected"


@pytest.mark.parametrize("text, cls", [
    ("the fit did not converge: max iterations", "not_converged"),
    ("singular covariance: the data cannot separate v1 and v2", "undetermined"),
    ("incomplete coverage: 40 % of the sphere", "coverage"),
    ("hard iron is 3.1 times the field: the magnetometer may be near saturation", "saturation"),
    ("structure remains in the residual above the noise floor: ...", "unexplained"),
    ("channel 'v2': signal-to-noise 14 is far below the others' 320", "channel"),
    ("channel v3: 20.4 deg from the nearest housing axis (+Z), more than 5 deg: a gross mounting error", "channel"),
    ("channel v2: signal-to-noise 16 (24 dB), against 320 for the other channels: a wrong gain setting",
     "channel"),
    ("something nobody classified", "other"),
])
def test_warnings_fall_into_classes(text, cls):
    assert classify_warning(text) == cls


# ---------------------------------------------------------------------------------------------- figures


def _model(directions, *, sigma_rad=0.0, gains=(2.0, 2.0, 2.0), offsets=(0.0, 0.0, 0.0), noise=(0.01,) * 3,
           field_ut=50.0):
    a = np.asarray(directions, float)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    cov = np.stack([sigma_rad**2 * (np.eye(3) - np.outer(v, v)) for v in a])
    return SensorModel(("x", "y", "z"), a, tuple(LinearResponse(o, g) for o, g in zip(offsets, gains)),
                       field_norm=50.0, field_ut=field_ut, dip_deg=60.0, noise=np.asarray(noise, float),
                       direction_covariance=cov)


def test_heading_budget_of_an_orthogonal_module_follows_the_closed_form():
    # three orthogonal channels, each direction uncertain by s (rad) isotropically across it, gains and
    # offsets exact: heading variance s^2 (b_x^4 + b_y^4 + b_z^2 H^2) / H^4, whose mean over headings is
    # s^2 (3/4 + tan^2 dip)
    s = np.radians(0.1)
    for dip in (0.0, 30.0, 65.0):
        got = heading_error_deg(_model(np.eye(3), sigma_rad=s), dip, 50.0)
        expected = np.degrees(s * np.sqrt(0.75 + np.tan(np.radians(dip)) ** 2))
        assert got == pytest.approx(expected, rel=1e-9)


def test_heading_budget_doubles_with_the_sigmas():
    a = np.eye(3) + 0.02 * np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]])
    once = heading_error_deg(_model(a, sigma_rad=1e-3), 60.0, 50.0)
    assert heading_error_deg(_model(a, sigma_rad=2e-3), 60.0, 50.0) == pytest.approx(2 * once, rel=1e-9)


def test_geometry_figures_of_a_channel_tilted_twenty_degrees():
    tilt = np.radians(20.0)
    a = np.array([[1.0, 0, 0], [0, np.cos(tilt), np.sin(tilt)], [0, 0, 1.0]])
    f = module_figures(_model(a, sigma_rad=1e-3, gains=(2.0, 1.0, 2.0), offsets=(10.0, 0.0, -4.0),
                              noise=(0.01, 0.2, 0.01)), {"noise_floor": 0.01, "residual_rms_after": 0.02,
                                                         "unexplained": False},
                       ["did not converge"], site_dip_deg=60.0, site_field_ut=50.0)
    assert f["axis_misalignment_deg"] == pytest.approx(20.0)
    assert f["non_orthogonality_deg"] == pytest.approx(20.0)
    assert f["gain_spread"] == pytest.approx(0.5)
    assert f["offset_ut"] == pytest.approx(5.0)  # 10 output units at 2 per uT
    assert f["snr_min"] == pytest.approx(1.0 * 50.0 / 0.2)
    assert f["snr_ratio_min"] == pytest.approx(250.0 / 10000.0)
    assert f["residual_over_floor"] == pytest.approx(2.0)
    assert f["direction_sigma_deg"] == pytest.approx(np.degrees(1e-3) * math.sqrt(2))
    assert f["warning_classes"] == ["not_converged"] and f["unexplained"] is False


def test_offset_without_field_ut_is_put_in_uT_by_the_bench_field_else_left_unjudged_in_words():
    # gains per bench |B| (field_norm 1): an offset of 10 output units at gain 2 is 5 |B|
    model = SensorModel(("x", "y", "z"), np.eye(3), tuple(LinearResponse(o, 2.0) for o in (10.0, 0.0, -4.0)),
                        field_norm=1.0, field_ut=None, dip_deg=60.0, noise=np.full(3, 0.01))
    known = module_figures(model, None, [], site_dip_deg=60.0, site_field_ut=50.0, bench_field_ut=48.0)
    assert known["offset_ut"] == pytest.approx(5.0 * 48.0) and known["unjudged"] == {}
    unknown = module_figures(model, None, [], site_dip_deg=60.0, site_field_ut=50.0)
    assert unknown["offset_ut"] is None
    assert "bench's |B| in uT is unknown" in unknown["unjudged"]["offset_ut"] and "5 bench |B|" in unknown[
        "unjudged"]["offset_ut"]
    note = parse_spec("[limits]\noffset_ut = { max = 180 }\n").judge(_figures(offset_ut=None, **{
        "unjudged": unknown["unjudged"]})).notes
    assert note == (f"offset_ut: not judged: {unknown['unjudged']['offset_ut']}",)


# ---------------------------------------------------------------------------------------------- control chart


def test_ewma_limits_tend_to_the_asymptotic_width():
    rng = np.random.default_rng(1)
    chart = ewma_chart(rng.normal(10.0, 1.0, 400), baseline=300, lam=0.2, width_sigmas=3.0)
    assert chart.sigma == pytest.approx(1.0, rel=0.15)  # median moving range / 0.954 of 300 normal values
    assert chart.high[-1] - chart.centre == pytest.approx(3.0 * chart.sigma * math.sqrt(0.2 / 1.8), rel=1e-6)


def test_ewma_flags_a_step_of_three_sigmas_within_a_few_sessions_and_ignores_one_outlier():
    rng = np.random.default_rng(2)
    x = rng.normal(0.0, 1.0, 60)
    x[45:] += 3.0
    chart = ewma_chart(x, baseline=20)
    assert chart.first_alarm is not None and 45 <= chart.first_alarm <= 49
    y = rng.normal(0.0, 0.01, 60)  # tiny noise: one dead channel's figure 1e4 sigmas off
    y[30] = 100.0
    assert ewma_chart(y, baseline=20, clip_sigmas=4.0, width_sigmas=3.0).out[30] == False  # noqa: E712


def test_ewma_needs_more_sessions_than_its_baseline():
    with pytest.raises(ValueError, match="more than its 20 baseline sessions, got 20"):
        ewma_chart(np.zeros(20), baseline=20)


# ---------------------------------------------------------------------------------------------- store


def _add(store, module, time, sha, status="accepted", calibration="{}", path=None):
    return store.add(module_id=module, session_time=time, recording_path=path or f"/r/{module}.csv",
                     recording_sha256=sha,
                     toolkit_version="1.0", kind="fourflip", status=status, reasons=[] if status == "accepted"
                     else ["gain_spread 0.5 above the limit 0.3"], notes=[], figures={"gain_spread": 0.1},
                     calibration=calibration, spec_text="[limits]\n", spec_sha256="s1")


def test_store_keeps_sessions_once_and_hands_out_the_latest_only_when_accepted(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        assert _add(store, "M1", "2026-01-01T08:00", "h1", calibration='{"a": 1}')
        assert store.exportable("M1").calibration == '{"a": 1}'
        assert _add(store, "M1", "2026-01-02T08:00", "h2", status="rejected", calibration='{"a": 2}')
        assert not _add(store, "M1", "2026-01-01T08:00", "h1")  # same recording, version, spec
        assert store.count() == 2
        assert store.known("1.0", "s1") == {"h1", "h2"} and store.known("1.1", "s1") == set()
        with pytest.raises(StoreError, match=r"module 'M1': its latest session, 2026-01-02T08:00 \(/r/M1.csv\), was "
                                             r"rejected: gain_spread .*an earlier session, 2026-01-01T08:00, was "
                                             r"accepted: export --module M1 --session 2026-01-01T08:00 hands it out"):
            store.exportable("M1")
        assert module_outcome(store.sessions(module_id="M1")).status == "rejected"
        assert store.exportable("M1", "2026-01-01T08:00:00Z").calibration == '{"a": 1}'  # asked for explicitly
        with pytest.raises(StoreError, match="its session, 2026-01-02T08:00 .*was rejected"):
            store.exportable("M1", "2026-01-02T08:00")
        with pytest.raises(StoreError, match="no session at 2026-01-03; its sessions: 2026-01-01T08:00, 2026-01-02"):
            store.exportable("M1", "2026-01-03")
        _add(store, "M2", "2026-01-03T08:00", "h3", status="rejected")
        with pytest.raises(StoreError, match="module 'M2': its latest session, .*rejected: gain_spread .*; no session of it was accepted"):
            store.exportable("M2")
        with pytest.raises(StoreError, match="no session of module 'M3'"):
            store.exportable("M3")
    with sqlite3.connect(tmp_path / "s.sqlite") as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == SCHEMA_VERSION


def test_two_recordings_of_one_module_at_one_session_time_are_a_tie_latest_accepted_refuses(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        _add(store, "M5", "2026-03-02T07:24", "h5", calibration='{"own": 1}')
        store.add(module_id="M5", session_time="2026-03-02T07:24", recording_path="/r/M5_rerun.csv",
                  recording_sha256="h10", toolkit_version="1.0", kind="fourflip", status="accepted", reasons=[],
                  notes=[], figures={}, calibration='{"other": 1}', spec_text="[limits]\n", spec_sha256="s1")
        _add(store, "M5", "2026-03-02T07:24", "h5")  # the same recording again is not a rival
        store.add(module_id="M5", session_time="2026-03-02T07:24", recording_path="/r/M5.csv",
                  recording_sha256="h5", toolkit_version="1.1", kind="fourflip", status="accepted", reasons=[],
                  notes=[], figures={}, calibration='{"own": 1}', spec_text="[limits]\n", spec_sha256="s1")
        count = store.count()
        with pytest.raises(StoreError, match="module 'M5': 2 different recordings claim its session "
                                             "2026-03-02T07:24: /r/M5.csv .*/r/M5_rerun.csv .*none is later"):
            store.exportable("M5")
        assert store.count() == count  # a refusal writes nothing
        outcome = module_outcome(store.sessions(module_id="M5"))
        assert outcome.status == "duplicate" and len(outcome.rivals) == 1  # h5 stored twice is one rival
        assert {outcome.row.recording_sha256, outcome.rivals[0].recording_sha256} == {"h5", "h10"}
        _add(store, "M5", "2026-03-05T09:00", "h5b", calibration='{"again": 1}')  # a later session decides
        assert store.exportable("M5").calibration == '{"again": 1}'
        _add(store, "M6", "2026-03-02T08:00", "h6", calibration='{"six": 1}')
        _add(store, "M6", "2026-03-02T08:00", "h6x", status="rejected", path="/r/M6b.csv")  # any verdict ties
        with pytest.raises(StoreError, match="/r/M6.csv \\(sha256 h6, accepted\\), /r/M6b.csv \\(sha256 h6x, rejected"):
            store.exportable("M6")
        # the same file edited (or recorded again over it), and a day alone (compass bench's # date:): no tie
        _add(store, "M7", "2026-03-02T08:00", "h7", calibration='{"seven": 1}')
        _add(store, "M7", "2026-03-02T08:00", "h7b", calibration='{"seven": 2}')
        _add(store, "M8", "2026-03-02", "h8", calibration='{"eight": 1}', path="/r/M8a.csv")
        _add(store, "M8", "2026-03-02", "h8b", calibration='{"eight": 2}', path="/r/M8b.csv")
        assert store.exportable("M7").calibration in ('{"seven": 1}', '{"seven": 2}')
        assert store.exportable("M8").calibration == '{"eight": 2}'  # the later file name, as before
        outcomes = {o.module_id: o.status for o in module_outcomes(store.sessions())}
    assert outcomes == {"M5": "accepted", "M6": "duplicate", "M7": "accepted", "M8": "accepted"}


@pytest.mark.parametrize("written, stored", [
    ("2026-03-02T09:30:00+02:00", "2026-03-02T07:30:00+00:00"),
    ("2026-03-02T07:24:00Z", "2026-03-02T07:24:00+00:00"),
    ("2026-03-02T07:24:00", "2026-03-02T07:24:00+00:00"),  # no offset: taken as UTC
    (" 2026-03-02 ", "2026-03-02"),  # a day stays a day
])
def test_a_session_time_is_stored_as_its_utc_instant_or_its_day(written, stored):
    assert session_time_text(written) == stored


@pytest.mark.parametrize("written", ["2026-3-9", "03/02/2026", "Monday", "2026-03-02T25:00"])
def test_a_session_time_in_no_iso_form_is_refused_quoting_it(written):
    with pytest.raises(SessionTimeError, match=f"'{written}' is not an ISO 8601 time"):
        session_time_text(written)


def test_sessions_order_and_tie_on_instants_also_in_a_store_that_kept_the_text_as_written(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:  # rows as an older batch stored them: the recording's text
        _add(store, "MA", "2026-03-02T09:30:00+02:00", "a1", calibration='{"first": 1}', path="/r/A1.csv")
        _add(store, "MA", "2026-03-02T08:00:00+00:00", "a2", calibration='{"second": 1}', path="/r/A2.csv")
        _add(store, "MC", "2026-03-02T07:24:00Z", "c1", path="/r/C1.csv")
        _add(store, "MC", "2026-03-02T07:24:00+00:00", "c2", path="/r/C2.csv")
        assert store.exportable("MA").calibration == '{"second": 1}'  # 08:00 UTC after 07:30 UTC
        with pytest.raises(StoreError, match="2 different recordings claim its session"):
            store.exportable("MC")  # one instant written two ways
        _add(store, "MB", "2026-3-9", "b1", calibration='{"unreadable": 1}', path="/r/B1.csv")
        _add(store, "MB", "2026-03-10", "b2", calibration='{"readable": 1}', path="/r/B2.csv")
        # a time an older store kept that is no ISO time still lists, first: never the latest over a readable one
        assert [r.recording_path for r in store.sessions(module_id="MB")] == ["/r/B1.csv", "/r/B2.csv"]
        assert store.exportable("MB").calibration == '{"readable": 1}'
        assert store.exportable("MB", "2026-03-10").calibration == '{"readable": 1}'  # a day picked past the unreadable
        _add(store, "MD", "9:30 2/3/26", "d1", path="/r/D1.csv")
        _add(store, "MD", "9:30 2/3/26", "d2", path="/r/D2.csv")
        assert len(store.sessions(module_id="MD")) == 2 and not store.rivals(store.sessions(module_id="MD"))


def test_a_batchs_rows_see_the_stores_rivals_of_their_sessions_and_nothing_else(tmp_path):
    """Store.rivals: another recording (hash and path) at a row's module id and session time of day; not the same
    recording under another spec, the same file edited, a day alone, nor the module's sessions at other times."""
    with Store(tmp_path / "s.sqlite") as store:
        _add(store, "M1", "2026-03-02T07:24", "h1", path="/r/M1.csv")  # the rival
        _add(store, "M1", "2026-03-01T07:00", "h0", path="/r/M1_early.csv")  # an earlier session
        _add(store, "M1", "2026-03-02T07:24", "h2", path="/r/M1_rerun.csv", status="rejected")  # the batch's
        _add(store, "M2", "2026-03-02T08:00", "h3", path="/r/M2.csv")  # the same file, edited
        _add(store, "M2", "2026-03-02T08:00", "h4", path="/r/M2.csv")
        _add(store, "M3", "2026-03-02", "h5", path="/r/M3a.csv")  # a day alone
        _add(store, "M3", "2026-03-02", "h6", path="/r/M3b.csv")
        rows = store.sessions(hashes={"h2", "h4", "h6"})
        rivals = store.rivals(rows)
        assert [r.recording_sha256 for r in rivals] == ["h1"]
        outcomes = {o.module_id: o.status for o in module_outcomes(rows, rivals)}
    assert outcomes == {"M1": "duplicate", "M2": "accepted", "M3": "accepted"}


def test_a_store_from_a_newer_schema_is_refused_and_left_alone(tmp_path):
    path = tmp_path / "new.sqlite"
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE future (x)")
        db.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    before = path.read_bytes()
    with pytest.raises(StoreError, match=f"written by a newer compass \\(store schema {SCHEMA_VERSION + 1}; "
                                         f"this compass knows up to {SCHEMA_VERSION}\\): upgrade compass"):
        Store(path)
    assert path.read_bytes() == before


def test_a_file_that_is_not_a_store_is_refused(tmp_path):
    path = tmp_path / "notes.sqlite"
    path.write_text("not a database at all, just words " * 40)
    with pytest.raises(StoreError, match="not a calibration store"):
        Store(path)
    with pytest.raises(StoreError, match="no such store"):
        Store(tmp_path / "missing.sqlite", create=False)
