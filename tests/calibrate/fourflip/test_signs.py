"""Channel signs, the hemisphere and calibrated ranges of four-flip calibrations (review 4).

The model: a linear channel reads ``v = V0 + K B.a`` with ``K > 0`` (SPEC section 1: the direction
is oriented so the output increases with ``B.a``).  Seed 000's minima are the same for ``a`` and
``-a``; the data tell them apart through the shared field azimuth (harmonic phases) and the
vertical field (flip means), except for the global ``(a, B) -> (-a, -B)``, which is the hemisphere.
"""

import numpy as np
import pytest

from calibrate import calibrate_fourflip

# channels like a real module's: Y tilted toward -X, Z tilted backwards (negative X components)
NEGATIVE_X = [[1.0, 0.035, -0.026], [-0.021, 1.0, 0.052], [-0.044, 0.014, 1.0]]


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _signed_angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(_unit(a) * _unit(b), axis=-1), -1.0, 1.0)))


@pytest.mark.parametrize("method,limit_deg", [("harmonic", 0.5), ("patent", 30.0)])
def test_seed_rules_orient_channels_with_negative_x(write_session, method, limit_deg):
    # before: theta, gamma in [-90, 90] forced x >= 0, so Y and Z came back reversed (error ~180 deg)
    # with positive gains, and the runtime's heading was 180 deg off. Limits: harmonic as for
    # positive-X channels (noise 0.15 uT gives ~0.05 deg); patent's lowest-sample minima on a flat curve
    # are off by up to ~sqrt(2 noise / amplitude) rad per minimum, tens of degrees for Y, far below 90.
    rec, truth = write_session(seed=31, directions=NEGATIVE_X, dip_deg=62.0)
    result = calibrate_fourflip(rec, method=method)
    err = _signed_angle_deg(result.directions, truth["directions"])
    assert np.all(err < limit_deg), err
    assert all(ch.response.gain > 0 for ch in result.channels)
    assert result.dip_deg > 0


def test_orient_uses_the_well_conditioned_evidence(write_session):
    """A channel along X has no vertical component in any flip (its flip means carry no sign); its sign
    comes from the shared field azimuth, i.e. the other channels' harmonics."""
    from calibrate.fourflip import _harmonic as hm

    rec, truth = write_session(seed=32, directions=[[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
    h = hm.fit_harmonics(rec.platform_deg, rec.flip_index, rec.outputs)
    v = hm.vector_harmonic(h, 50.0, 1.0)
    wrong = np.abs(np.asarray(truth["directions"]))  # every channel with the opposite sign where negative
    oriented = hm.orient(wrong, v)
    np.testing.assert_allclose(oriented, truth["directions"], atol=0.01)
    assert v.vertical_sigmas > 100  # two channels with vertical components, dip 40-70 deg


# ------------------------------------------------------------------------------------- the hemisphere

SOUTH_SITE, SOUTH_DATE = "-35.3,149.1", "2026-03-01"  # Canberra: WMM dip about -66 deg


@pytest.fixture(scope="module")
def southern_bench(tmp_path_factory):
    """A bench session at the southern site (its WMM dip and |B|), and its truth."""
    from compass.sim.fourflip import simulate_fourflip, write_fourflip
    from compass.site import Site

    wmm = Site.parse(SOUTH_SITE, SOUTH_DATE).field()
    session = simulate_fourflip(seed=33, dip_deg=wmm.dip_deg, field_ut=wmm.field_ut)
    path, _ = write_fourflip(session, tmp_path_factory.mktemp("south") / "south.csv")
    return path, session.truth


def test_southern_bench_without_latitude_says_which_hemisphere_was_taken(southern_bench, tmp_path, capsys):
    from compass.cli import main

    path, truth = southern_bench
    assert truth["dip_deg"] < -60
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(path), "--out", str(out), "--no-diagnose"]) == 0
    report = capsys.readouterr().out
    # the data alone give the mirror image (a, B) -> (-a, -B): the report must say what was assumed and how to change it
    assert "hemisphere: northern" in report and "site_lat_deg" in report and "--site" in report
    import json

    doc = json.loads(out.read_text())
    assert doc["dip_deg"] > 0 and doc["hemisphere"]["assumed"] == "north" and doc["hemisphere"]["default"]


def test_site_sets_the_bench_hemisphere(southern_bench, tmp_path, capsys):
    import json

    from compass.cli import main

    path, truth = southern_bench
    out = tmp_path / "cal.json"
    assert main(["calibrate", str(path), "--out", str(out), "--no-diagnose", "--site", SOUTH_SITE,
                 "--date", SOUTH_DATE]) == 0
    assert "hemisphere: southern" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    assert doc["hemisphere"]["assumed"] == "south" and doc["dip_deg"] == pytest.approx(truth["dip_deg"], abs=0.1)
    for name, a in zip(truth["channels"], truth["directions"]):
        ch = doc["channels"][name]
        assert _signed_angle_deg(ch["direction"], a) < 4 * ch["direction_sigma_deg"]
    # the site check against the WMM ran on the same site (the simulated dip is the WMM's)
    assert abs(doc["site_check"]["dip_difference_sigma"]) < 3


def test_attitude_refuses_a_calibration_whose_field_is_upside_down(southern_bench, tmp_path, capsys):
    """Calibrated as northern, used at the southern site: the measured field is -B (dip turned over);
    before, every row was marked disturbed with the heading 180 deg off and exit 0."""
    import json

    from compass.cli import main
    from compass.sim.runtime import simulate_runtime, write_runtime

    path, truth = southern_bench
    wrong, right = tmp_path / "wrong.json", tmp_path / "right.json"
    assert main(["calibrate", str(path), "--out", str(wrong), "--no-diagnose", "--quiet"]) == 0
    assert main(["calibrate", str(path), "--out", str(right), "--no-diagnose", "--quiet", "--site", SOUTH_SITE]) == 0
    rec, _ = write_runtime(simulate_runtime(truth, 200, seed=34, max_tilt_deg=40.0), tmp_path / "rec.csv")
    capsys.readouterr()
    site = ["--site", SOUTH_SITE, "--date", SOUTH_DATE]
    assert main(["attitude", str(wrong), str(rec), "--out", str(tmp_path / "a.csv"), *site]) == 2
    err = capsys.readouterr().err
    assert "upside down" in err and "site_lat_deg" in err and "wrong.json" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    # the same through the file's site block
    block = tmp_path / "wrong_site.json"
    from compass.site import Site

    block.write_text(json.dumps(json.loads(wrong.read_text()) | {"site": Site.parse(SOUTH_SITE, SOUTH_DATE).to_json()}))
    assert main(["attitude", str(block), str(rec), "--out", str(tmp_path / "b.csv")]) == 2
    assert "upside down" in capsys.readouterr().err
    # the right calibration at the same site: solved, nothing disturbed
    assert main(["attitude", str(right), str(rec), "--out", str(tmp_path / "c.csv"), *site]) == 0
    from compass.io.table import read_table

    assert read_table(tmp_path / "c.csv").column("disturbed").mean() <= 0.01


def test_upside_down_is_judged_only_against_a_given_reference():
    from compass.site import known_reference, upside_down

    dips = np.full(50, -60.0)
    assert upside_down(dips, known_reference(60.0, 50.0)) is not None
    assert upside_down(-dips, known_reference(60.0, 50.0)) is None
    assert upside_down(np.full(50, -4.0), known_reference(4.0, 50.0)) is None  # near the magnetic equator
    from dataclasses import replace

    assert upside_down(dips, replace(known_reference(60.0, 50.0), source="recording")) is None


# ------------------------------------------------------------------------------------- calibrated ranges


def _expected_range(direction, dip_deg, field):
    """min and max of B.a over the four flips and a full turn: in flip k the channel's vertical
    component is v_k = (Rx(k 90 deg) a)_z, so B.a = -|B| sin(dip) v_k +- |B| cos(dip) sqrt(1 - v_k^2)."""
    a = _unit(direction)
    v = np.array([a[2], a[1], -a[2], -a[1]])
    d = np.radians(dip_deg)
    centre, swing = -field * np.sin(d) * v, field * np.cos(d) * np.sqrt(1 - v**2)
    return np.min(centre - swing), np.max(centre + swing)


@pytest.mark.parametrize("method", ["ml", "harmonic"])
def test_calibrated_range_is_the_field_each_channel_saw(write_session, method):
    # before: [-|B|, |B|] for every channel, although flips about X never turn the X channel vertical
    rec, truth = write_session(seed=35, directions=NEGATIVE_X, dip_deg=62.0)
    result = calibrate_fourflip(rec, method=method)
    field = truth["field_ut"]
    for ch, a in zip(result.channels, truth["directions"]):
        lo, hi = _expected_range(a, truth["dip_deg"], field)
        # the fitted direction and dip are good to << 0.1 deg (harmonic's dip to ~1 deg: 2 % of |B|)
        tol = 0.002 * field if method == "ml" else 0.03 * field
        assert ch.response.x_range == pytest.approx((lo, hi), abs=tol)
    x_lo, x_hi = result.channels[0].response.x_range
    # the X channel: |B| (cos(62 deg) + sin(62 deg) 0.035) = 0.50 |B|, its 2 deg tilt toward Y adding 0.03
    assert x_hi < 0.52 * field and x_lo > -0.52 * field


def test_runtime_flags_extrapolated_curves_and_counts_extrapolated_lines(write_session, tmp_path, capsys):
    """Tilted far, the X channel reads beyond the +-|B| cos(dip) it was calibrated over: a linear
    response is the same line there (counted, not flagged); a nonlinear one is flagged."""
    import json

    from compass.cli import main
    from compass.io.table import read_table
    from compass.sim.runtime import simulate_runtime, write_runtime

    rec, truth = write_session(seed=36, directions=NEGATIVE_X, dip_deg=62.0)
    result = calibrate_fourflip(rec, method="ml")
    doc = result.to_json()
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(doc))
    session = simulate_runtime(truth, 300, seed=37, max_tilt_deg=70.0)
    path, _ = write_runtime(session, tmp_path / "att.csv")
    x_true = session.field_h @ np.asarray(truth["directions"]).T
    lo, hi = result.channels[0].response.x_range
    margin = 0.02 * (hi - lo) + 0.05 * truth["field_ut"]  # the recording's noise: far below 5 % of |B|
    surely_beyond = int(np.sum((x_true[:, 0] > hi + margin) | (x_true[:, 0] < lo - margin)))
    assert surely_beyond > 30  # the case exists in this recording
    assert main(["attitude", str(cal), str(path), "--out", str(tmp_path / "a.csv")]) == 0
    out = read_table(tmp_path / "a.csv")
    assert out.column("in_range").all()
    counted = int(out.metadata["extrapolated"].split()[0])
    assert counted >= surely_beyond and "linear" in out.metadata["extrapolated"]
    # the same channel with a cubic response: its curve is extrapolated there, and those rows are flagged
    doc["channels"][truth["channels"][0]]["response"] |= {"model": "cubic", "cubic": -1e-6}
    cal.write_text(json.dumps(doc))
    assert main(["attitude", str(cal), str(path), "--out", str(tmp_path / "b.csv")]) == 0
    assert np.sum(read_table(tmp_path / "b.csv").column("in_range") == 0) >= surely_beyond


# ------------------------------------------------------------------------------------- one and two channels


@pytest.mark.parametrize("directions", [[[0.6, 0.5, 0.62]], [[1.0, 0.035, -0.026], [-0.021, 1.0, 0.052]]],
                         ids=["one", "two"])
def test_one_and_two_channel_benches_calibrate_and_the_runtime_refuses_them(write_session, tmp_path, capsys,
                                                                             directions):
    """SPEC: a recording with one channel is a single-axis calibration (before: exit 2, 'a field vector
    needs at least 3 channels'). The minimum of three belongs to the runtime."""
    import json

    from compass.cli import main

    rec, truth = write_session(seed=38, directions=directions, dip_deg=62.0)
    cal = tmp_path / "cal.json"
    assert main(["calibrate", rec.path, "--out", str(cal), "--no-diagnose"]) == 0
    assert "single-axis" in capsys.readouterr().out
    doc = json.loads(cal.read_text())
    assert list(doc["channels"]) == list(truth["channels"])
    for name, a in zip(truth["channels"], truth["directions"]):
        ch = doc["channels"][name]
        assert ch["response"]["gain"] > 0
        assert _signed_angle_deg(ch["direction"], a) < 4 * ch["direction_sigma_deg"]
    att = tmp_path / "att.csv"
    att.write_text("t_s," + ",".join(truth["channels"]) + ",ax,ay,az\n0.0," + ",".join(["1.0"] * len(directions))
                   + ",0,0,1\n")
    for args in (["attitude", str(cal), str(att), "--out", str(tmp_path / "o.csv")],
                 ["export", str(cal), "--format", "fusion"],
                 ["live", "--port", str(tmp_path / "no-such-port"), "--cal", str(cal), "--duration", "1"]):
        assert main(args) == 2
        err = capsys.readouterr().err
        assert "at least 3 channels" in err and "cal.json" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.parametrize("directions, dip_deg, warned", [
    ([[1.0, 0.0, 0.0]], 62.0, True),                 # only X: never vertical, the flip means see nothing
    (np.eye(3).tolist(), 0.0, True),                 # the magnetic equator: no vertical field to see
    (np.eye(3).tolist(), 0.5, False),                # 0.5 deg is seen: about 110 sigma here
    (np.eye(3).tolist(), 62.0, False)])
def test_warns_when_the_hemisphere_cannot_fix_the_directions_sign(write_session, directions, dip_deg, warned):
    rec, _ = write_session(seed=39, directions=directions, dip_deg=dip_deg)
    result = calibrate_fourflip(rec, method="ml")
    said = any("hardly show the vertical field" in w for w in result.warnings)
    assert said == warned, (result.extra["hemisphere"], result.warnings)


def test_three_coplanar_channels_calibrate_with_a_warning_and_the_runtime_refuses_them(write_session, tmp_path,
                                                                                      capsys):
    """Three channels in one plane are three single-axis calibrations: written, said in the report (before:
    exit 0 and no word, then `compass export` refused the file)."""
    from compass.cli import main

    rec, _ = write_session(seed=39, directions=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.7071, 0.7071, 0.0]], dip_deg=62.0)
    cal = tmp_path / "cal.json"
    assert main(["calibrate", rec.path, "--out", str(cal), "--no-diagnose"]) == 0
    assert "do not span three dimensions" in capsys.readouterr().out
    assert main(["export", str(cal), "--format", "fusion"]) == 2
    err = capsys.readouterr().err
    assert "do not span three" in err and "cal.json" in err and len(err.strip().splitlines()) == 1
