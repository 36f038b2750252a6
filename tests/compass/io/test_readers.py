"""Real logs as they come (issue 15.2, 15.3, 15.6) and bad metadata and cells (16.5, 16.6), reader side.

Every recording is generated here from the simulators; the expected warnings and refusals follow
from what was injected (a unit changed, a sign flipped, a cell corrupted), never from what the code
happened to print.
"""

import json

import numpy as np
import pytest

from compass.cli import main
from compass.io.table import ReadOptions, read_table
from compass.io.units import RecordingWarning, gyro_turn_ratio
from compass.sim.fourflip import simulate_fourflip, write_fourflip
from compass.sim.tumble import simulate_tumble


def _csv(path, header, data, sep=",", fmt="%.6f", metadata=(), decimal="."):
    lines = [f"# {m}" for m in metadata] + [sep.join(header)]
    for row in np.atleast_2d(data):
        cells = [fmt % v for v in row]
        lines.append(sep.join(c.replace(".", decimal) for c in cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def _tumble(seed=1, n=600):
    sim = simulate_tumble(seed=seed, n=n)
    rot = sim.attitude
    dt = np.diff(sim.t_s)
    gyro = np.vstack([(rot[:-1].inv() * rot[1:]).as_rotvec() / dt[:, None], np.zeros((1, 3))])  # rad/s, housing
    return sim, gyro


def _run(capsys, *argv):
    status = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def _one_line_refusal(status, err, *expected):
    assert status == 2 and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    for text in expected:
        assert text in err, err


# ---- 15.2: columns as they come ------------------------------------------------------------------

def test_xio_fusion_header_is_read_as_a_tumble_with_its_units(tmp_path, capsys):
    """x-io's log: ``Time (s), Gyroscope X (deg/s), ..., Magnetometer X (uT)`` -> t_s, gx.. (rad/s), mx.."""
    sim, gyro = _tumble()
    header = ["Time (s)"] + [f"Gyroscope {a} (deg/s)" for a in "XYZ"] + [f"Accelerometer {a} (g)" for a in "XYZ"] \
        + [f"Magnetometer {a} (uT)" for a in "XYZ"]
    rec = _csv(tmp_path / "xio.csv", header, np.column_stack([sim.t_s, np.degrees(gyro), sim.accel, sim.mag]))
    with pytest.warns(RecordingWarning, match="read the log's header as t_s = 'Time"):
        table = read_table(rec)
    assert table.has("mx") and table.units["gx"] == "deg/s"
    np.testing.assert_allclose(table.column("gx"), gyro[:, 0], atol=1e-6 * np.pi / 180 + 1e-9)
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "cal.json", "--quiet")
    assert status == 0, err
    assert json.loads((tmp_path / "cal.json").read_text())["model"] == "tumble"
    assert "gx,gy,gz = 'Gyroscope X (deg/s)'" in err and "ignored column" not in err  # the gyro-aided fit reads it
    assert "--gyro-unit" not in err  # named by the header, and consistent with the accelerometer


@pytest.mark.parametrize("how", ["option", "metadata"])
def test_column_mapping_option_and_metadata_line(tmp_path, capsys, how):
    sim = simulate_tumble(seed=2, n=300)
    names = ["MagX", "Mag Y", "mag_z", "seq"]
    metadata = ["columns: mx=MagX,my=Mag Y,mz=mag_z"] if how == "metadata" else []
    rec = _csv(tmp_path / "t.csv", names, np.column_stack([sim.mag, np.arange(300)]), metadata=metadata)
    extra = ["--columns", "mx=MagX,my=Mag Y,mz=MAG_Z"] if how == "option" else []
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json", "--quiet", *extra)
    assert status == 0, err
    assert "ignored column seq" in err


@pytest.mark.parametrize("header, mapping, column, words", [
    (["a", "b", "c"], "mx=a,my=b,mz=z", "column 'z'", "--columns maps mz to 'z'"),  # absent
    (["mx", "my", "mz"], "mx=my", "column 'mx'", "the header's own column 'mx' is left as it is"),  # two mx
    (["a", "b", "c"], "mx=a,my=a,mz=c", "column 'a'", "maps both mx and my to 'a'"),  # one column, two names
    (["a", "b", "c"], "mx=-a,my=a,mz=c", "column 'a'", "maps both mx and my to 'a'"),
])
def test_a_mapping_that_cannot_be_read_names_the_column(tmp_path, capsys, header, mapping, column, words):
    sim = simulate_tumble(seed=2, n=300)
    rec = _csv(tmp_path / "t.csv", header, sim.mag)
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json", "--columns", mapping)
    _one_line_refusal(status, err, "t.csv", column, words)
    assert not (tmp_path / "c.json").exists()


def test_mapping_can_negate_a_column(tmp_path):
    rec = _csv(tmp_path / "t.csv", ["MX", "MY", "MZ"], np.arange(12.0).reshape(4, 3))
    table = read_table(rec, ReadOptions(columns={"mz": "-MZ"}))
    np.testing.assert_array_equal(table.column("mz"), -np.arange(2.0, 12.0, 3.0))


def test_mapping_swaps_columns_already_named_as_ours(tmp_path):
    """Every name maps to the header as read: a magnetometer whose x and y are the IMU's y and x swaps in one go."""
    rec = _csv(tmp_path / "t.csv", ["mx", "my", "mz"], np.arange(12.0).reshape(4, 3))
    table = read_table(rec, ReadOptions(columns={"mx": "my", "my": "mx", "mz": "-mz"}))
    np.testing.assert_array_equal(table.column("mx"), np.arange(1.0, 12.0, 3.0))
    np.testing.assert_array_equal(table.column("my"), np.arange(0.0, 12.0, 3.0))
    np.testing.assert_array_equal(table.column("mz"), -np.arange(2.0, 12.0, 3.0))


def test_upper_case_names_are_spec_names(tmp_path, capsys):
    sim = simulate_tumble(seed=3, n=300)
    rec = _csv(tmp_path / "t.csv", ["T_S", "MX", "MY", "MZ", "AX", "AY", "AZ"], np.column_stack([sim.t_s, sim.mag, sim.accel]))
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json", "--quiet")
    assert status == 0, err


def test_names_equal_but_for_case_are_refused(tmp_path):
    rec = _csv(tmp_path / "t.csv", ["mx", "MX", "my", "mz"], np.ones((3, 4)))
    with pytest.raises(ValueError, match="two columns are named 'mx'"):
        read_table(rec)


@pytest.mark.parametrize("sep, decimal", [(";", "."), (";", ","), ("\t", "."), ("\t", ",")])
def test_separators_and_decimal_commas(tmp_path, sep, decimal):
    data = np.array([[1.5, -2.25, 3.0], [4.0, 5.125, -6.5]])
    rec = _csv(tmp_path / "t.csv", ["mx", "my", "mz"], data, sep=sep, fmt="%.3f", decimal=decimal)
    np.testing.assert_array_equal(read_table(rec).data, data)


def test_decimal_commas_with_comma_separator_are_named(tmp_path, capsys):
    rec = _csv(tmp_path / "bad.csv", ["mx", "my", "mz"], np.ones((20, 3)) * 1.5, decimal=",")
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json")
    _one_line_refusal(status, err, "bad.csv", "row 2", "decimal commas")


def test_attitude_ignores_an_unknown_column_with_a_note(tmp_path, capsys):
    session = simulate_fourflip(seed=4)
    rec, _ = write_fourflip(session, tmp_path / "bench.csv")
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet"]) == 0
    # 20 rows: without --site the site's field is estimated from the recording's quiet rows (>= 10)
    rows = np.column_stack([np.arange(20), session.outputs[:20], np.tile([0.0, 0.0, 1.0], (20, 1))])
    att = _csv(tmp_path / "att.csv", ["seq", *session.channels, "ax", "ay", "az"], rows)
    capsys.readouterr()
    status, _, err = _run(capsys, "attitude", cal, att, "--out", tmp_path / "o.csv")
    assert status == 0 and "ignored column seq" in err


# ---- 15.3: units stated and checked --------------------------------------------------------------

def test_gyro_turn_ratio_tells_deg_from_rad():
    sim, gyro = _tumble(seed=5, n=1500)
    ratio = gyro_turn_ratio(sim.t_s, gyro, sim.accel)
    assert 1.0 <= ratio < 3.0  # a turn about the vertical tilts nothing: the gyro turns at least the tilt
    assert gyro_turn_ratio(sim.t_s, np.degrees(gyro), sim.accel) == pytest.approx(np.degrees(ratio), rel=1e-9)


def test_gyro_in_deg_per_s_read_as_rad_per_s_is_warned_and_the_option_fixes_it(tmp_path, capsys):
    sim, gyro = _tumble(seed=5, n=1500)
    rec = _csv(tmp_path / "t.csv", ["t_s", "mx", "my", "mz", "ax", "ay", "az", "gx", "gy", "gz"],
               np.column_stack([sim.t_s, sim.mag, sim.accel, np.degrees(gyro)]))
    out = tmp_path / "c.json"
    status, _, err = _run(capsys, "calibrate", rec, "--out", out, "--quiet")
    assert status == 0 and "--gyro-unit deg/s" in err and "turns" in err
    status, _, err = _run(capsys, "calibrate", rec, "--out", out, "--quiet", "--force", "--gyro-unit", "deg/s")
    assert status == 0 and "--gyro-unit" not in err


def test_field_strength_in_gauss_is_pointed_out(tmp_path, capsys):
    sim = simulate_tumble(seed=6, n=600)  # uT: |B| 50
    rec = _csv(tmp_path / "t.csv", ["mx", "my", "mz"], sim.mag / 100.0, fmt="%.7f")  # the same field in gauss
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json", "--quiet")
    assert status == 0 and "--mag-unit G" in err
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c2.json", "--quiet", "--mag-unit", "uT")
    assert status == 0 and "not the Earth's 25-65 uT" in err and "--mag-unit G" in err and "uT =" not in err
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c3.json", "--quiet", "--mag-unit", "G")
    assert status == 0 and "warning" not in err
    assert json.loads((tmp_path / "c3.json").read_text())["field_norm"] == pytest.approx(50.0, rel=0.05)


def test_field_strength_in_milligauss_is_pointed_out_with_the_right_unit(tmp_path, capsys):
    """mG data: no unit given was silent (the export then wrote offsets 10x too big); named G, the hint
    judged the value after conversion to uT and proposed nT."""
    from compass.io.tumble import sphere_radius

    sim = simulate_tumble(seed=6, n=600)
    rec = _csv(tmp_path / "t.csv", ["mx", "my", "mz"], sim.mag * 10.0, fmt="%.5f")  # the same field in mG
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json", "--quiet")
    assert status == 0 and "--mag-unit mG" in err
    for wrong in ("G", "uT", "nT"):
        status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / f"c{wrong}.json", "--quiet",
                              "--mag-unit", wrong)
        (line,) = [x for x in err.splitlines() if "field strength" in x]
        assert status == 0 and f"is {sphere_radius(sim.mag * 10.0):.3g} {wrong}" in line  # in the unit named
        assert "--mag-unit mG" in line and "nT would" not in line
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "cmG.json", "--quiet", "--mag-unit", "mG")
    assert status == 0 and "warning" not in err
    assert json.loads((tmp_path / "cmG.json").read_text())["field_norm"] == pytest.approx(50.0, rel=0.05)


def test_accelerometer_reading_gravity_is_warned_on_tumble_and_attitude(tmp_path, capsys):
    sim = simulate_tumble(seed=7, n=900)
    still = np.tile(sim.accel[:1] * 0 + [0.0, 0.0, 1.0], (60, 1))  # starts lying face up, still
    mag0 = np.tile(sim.mag[:1], (60, 1)) + np.random.default_rng(0).normal(scale=0.3, size=(60, 3))
    mag, accel = np.vstack([mag0, sim.mag]), np.vstack([still, sim.accel])
    good = _csv(tmp_path / "good.csv", ["mx", "my", "mz", "ax", "ay", "az"], np.column_stack([mag, accel]))
    flipped = _csv(tmp_path / "flip.csv", ["mx", "my", "mz", "ax", "ay", "az"], np.column_stack([mag, -accel]))
    status, _, err = _run(capsys, "calibrate", good, "--out", tmp_path / "g.json", "--quiet")
    assert status == 0 and "--accel-sign" not in err
    status, _, err = _run(capsys, "calibrate", flipped, "--out", tmp_path / "f.json", "--quiet")
    assert status == 0 and "--accel-sign -1" in err and "reads az = -1" in err
    status, _, err = _run(capsys, "calibrate", flipped, "--out", tmp_path / "f2.json", "--quiet", "--accel-sign", "-1")
    assert status == 0 and "--accel-sign" not in err
    status, _, err = _run(capsys, "attitude", tmp_path / "g.json", flipped, "--out", tmp_path / "att.csv")
    assert status == 0 and "--accel-sign -1" in err


@pytest.mark.parametrize("column", ["flip_deg", "platform_deg"])
def test_radians_in_degree_columns_are_named_and_the_option_reads_them(tmp_path, capsys, column):
    session = simulate_fourflip(seed=8, step_deg=10)
    rec, _ = write_fourflip(session, tmp_path / "bench.csv")
    table = read_table(rec)
    j = table.columns.index(column)
    data = table.data.copy()
    data[:, j] = np.radians(data[:, j])
    bad = _csv(tmp_path / "rad.csv", table.columns, data, fmt="%.9f")
    status, _, err = _run(capsys, "calibrate", bad, "--out", tmp_path / "c.json", "--quiet")
    _one_line_refusal(status, err, "rad.csv", f"column '{column}'", "radians?", "--angle-unit rad")
    if column == "platform_deg":  # both columns in radians: the option reads them
        data[:, table.columns.index("flip_deg")] = np.radians(data[:, table.columns.index("flip_deg")])
        both = _csv(tmp_path / "rad2.csv", table.columns, data, fmt="%.9f")
        status, _, err = _run(capsys, "calibrate", both, "--out", tmp_path / "c.json", "--quiet", "--angle-unit", "rad")
        assert status == 0, err


def test_two_axis_tilt_sensor_upside_down_is_said(tmp_path, capsys):
    from compass.sim.platform3d import simulate_platform3d, write_platform3d

    rec, _ = write_platform3d(simulate_platform3d(seed=1, tilt_axes=2), tmp_path / "p3.csv")
    cal = tmp_path / "p3.json"
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet"]) == 0
    table = read_table(rec)
    upright = np.abs(table.column("platform_x_deg") % 360 - 180) > 60  # the housing's upper side up
    att = tmp_path / "att.csv"
    cols = ["mx", "my", "mz", "ax", "ay"]
    _csv(att, cols, np.column_stack([table.column(c) for c in cols])[upright])
    capsys.readouterr()
    status, _, err = _run(capsys, "attitude", cal, att, "--out", tmp_path / "o.csv")
    assert status == 0 and "az is assumed positive" not in err
    _csv(att, cols, np.column_stack([table.column(c) for c in cols]))
    status, _, err = _run(capsys, "attitude", cal, att, "--out", tmp_path / "o.csv", "--force")
    assert status == 0 and "az is assumed positive" in err
    # with a site: the tilt sensor's own warning, not a turned-over field (its mirrored up mirrors the dip)
    down = ~upright
    _csv(att, cols, np.column_stack([table.column(c) for c in cols])[down])
    status, _, err = _run(capsys, "attitude", cal, att, "--out", tmp_path / "o.csv", "--force", "--site", "47.6,-122.3",
                          "--date", "2026-01-01")
    assert status == 0 and "az is assumed positive" in err and "site_lat_deg" not in err


# ---- 16.5, 16.6: metadata and cells --------------------------------------------------------------

@pytest.mark.parametrize("kind", ["fourflip", "tumble", "platform3d"])
@pytest.mark.parametrize("value", ["nan", "-50", "fifty", "0"])
def test_bad_field_ut_metadata_is_refused_naming_file_and_key(tmp_path, capsys, kind, value):
    if kind == "fourflip":
        rec, _ = write_fourflip(simulate_fourflip(seed=1, step_deg=10), tmp_path / "r.csv")
    elif kind == "tumble":
        from compass.sim.tumble import write_tumble
        rec, _ = write_tumble(simulate_tumble(seed=1, n=200), tmp_path / "r.csv")
    else:
        from compass.sim.platform3d import simulate_platform3d, write_platform3d
        rec, _ = write_platform3d(simulate_platform3d(seed=1), tmp_path / "r.csv")
    rec.write_text(f"# field_ut: {value}\n" + "\n".join(l for l in rec.read_text().splitlines()
                                                        if not l.startswith("# field_ut")) + "\n")
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json", "--quiet")
    _one_line_refusal(status, err, "r.csv", "row 1", "field_ut", repr(value))
    assert not (tmp_path / "c.json").exists()


@pytest.mark.parametrize("cell, message", [("1_5", "'1_5'"), ("0x10", "'0x10'"), ("nan", "finite"), ("-inf", "finite"),
                                           ("1e300", "beyond 1e+12"), ("-2e13", "beyond 1e+12")])
def test_bad_cells_are_named_by_row_and_column(tmp_path, capsys, cell, message):
    sim = simulate_tumble(seed=9, n=200)
    lines = _csv(tmp_path / "bad.csv", ["mx", "my", "mz"], sim.mag).read_text().splitlines()
    cells = lines[57].split(",")
    cells[1] = cell
    lines[57] = ",".join(cells)
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    status, _, err = _run(capsys, "calibrate", tmp_path / "bad.csv", "--out", tmp_path / "c.json")
    _one_line_refusal(status, err, "bad.csv", "row 58", "column 'my'", message)


def test_huge_channels_are_refused_at_the_reader(tmp_path, capsys):
    """16.5: a whole channel at 1e300 used to reach the fits ("initial guess outside bounds", exit 1)."""
    sim = simulate_tumble(seed=9, n=200)
    rec = _csv(tmp_path / "bad.csv", ["mx", "my", "mz"], sim.mag * [1, 1, 1e298], fmt="%.6g")
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json")
    _one_line_refusal(status, err, "bad.csv", "row 2", "column 'mz'", "no sensor output")


@pytest.mark.parametrize("edit, column", [(lambda d: np.delete(d, 2, axis=1), "mz"), (lambda d: d * [1, 1, 0] + [0, 0, 7], "mz")])
def test_missing_or_constant_mz_is_named(tmp_path, capsys, edit, column):
    sim = simulate_tumble(seed=10, n=200)
    data = edit(sim.mag)
    rec = _csv(tmp_path / "bad.csv", ["mx", "my", "mz"][: data.shape[1]], data)
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json", "--kind", "tumble")
    _one_line_refusal(status, err, "bad.csv", f"column '{column}'")


def test_fourflip_time_going_back_is_refused_naming_the_row(tmp_path, capsys):
    session = simulate_fourflip(seed=1, step_deg=10, effects=("offset_drift",))
    rec, _ = write_fourflip(session, tmp_path / "r.csv")
    table = read_table(rec)
    assert table.has("t_s")
    lines = rec.read_text().splitlines()
    j = table.columns.index("t_s")
    first = table.header_line  # the header's 1-based line = the first data line's 0-based index
    cells = lines[first + 10].split(",")
    cells[j] = "-1"
    lines[first + 10] = ",".join(cells)
    rec.write_text("\n".join(lines) + "\n")
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json", "--quiet")
    _one_line_refusal(status, err, "r.csv", f"row {first + 11}", "column 't_s'", "must not decrease")


# ---- 15.6: the command line's gaps --------------------------------------------------------------

def test_simulate_every_kind_and_calibrate_or_solve_it(tmp_path, capsys):
    for kind in ("tumble", "reference", "fourflip"):
        assert main(["simulate", kind, "--out", str(tmp_path / f"{kind}.csv")]) == 0
        assert main(["calibrate", str(tmp_path / f"{kind}.csv"), "--out", str(tmp_path / f"{kind}.json"), "--quiet"]) == 0
    assert "# source: compass simulate reference" in (tmp_path / "reference.csv").read_text()
    rt = tmp_path / "run.csv"
    assert main(["simulate", "runtime", "--out", str(rt), "--truth", str(tmp_path / "fourflip.truth.json"),
                 "--samples", "200", "--max-tilt-deg", "30"]) == 0
    assert main(["attitude", str(tmp_path / "fourflip.json"), str(rt), "--out", str(tmp_path / "att.csv")]) == 0
    att, truth = read_table(tmp_path / "att.csv"), json.loads((tmp_path / "run.truth.json").read_text())
    err = (att.column("heading_deg") - np.array(truth["heading_deg"]) + 180) % 360 - 180
    assert np.sqrt(np.mean((err / att.column("heading_sigma_deg")) ** 2)) < 2.0
    assert main(["simulate", "runtime", "--out", str(rt), "--truth", str(tmp_path / "tumble.csv")]) == 2


def test_version(capsys):
    from importlib.metadata import version

    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0 and capsys.readouterr().out.strip() == f"compass {version('compass-toolkit')}"


def test_simulate_effect_names_match_the_simulator():
    from compass.commands.simulate import SIM_EFFECTS
    from compass.sim import fourflip

    assert SIM_EFFECTS == fourflip.SIM_EFFECTS


def test_recording_warnings_are_warnings_in_the_library(tmp_path):
    sim = simulate_tumble(seed=6, n=300)
    rec = _csv(tmp_path / "t.csv", ["mx", "my", "mz", "extra"], np.column_stack([sim.mag, np.arange(300)]))
    from compass.io.tumble import read_tumble

    with pytest.warns(RecordingWarning, match="ignored column extra"):
        read_tumble(rec)


def test_a_short_attitude_recording_is_refused_for_its_length_not_its_accelerometer(tmp_path, capsys):
    session = simulate_fourflip(seed=4)
    rec, _ = write_fourflip(session, tmp_path / "bench.csv")
    cal = tmp_path / "cal.json"
    assert main(["calibrate", str(rec), "--out", str(cal), "--quiet"]) == 0
    rows = np.column_stack([session.outputs[:6], np.tile([0.0, 0.0, 1.0], (6, 1))])  # 6 rows, all at exactly 1 g
    att = _csv(tmp_path / "att.csv", [*session.channels, "ax", "ay", "az"], rows)
    capsys.readouterr()
    status, _, err = _run(capsys, "attitude", cal, att, "--out", tmp_path / "o.csv")
    _one_line_refusal(status, err, "has 6 usable rows", "at least 10", "--site")
    assert "gravity alone" not in err and not (tmp_path / "o.csv").exists()


def test_a_nan_cell_is_named_as_python_writes_it(tmp_path, capsys):
    data = np.ones((20, 3))
    data[5, 1] = np.nan
    rec = _csv(tmp_path / "nan.csv", ["mx", "my", "mz"], data)
    status, _, err = _run(capsys, "calibrate", rec, "--out", tmp_path / "c.json")
    _one_line_refusal(status, err, "nan.csv", "found nan", "my")
    assert "np.float64" not in err


def test_warnings_about_the_input_come_before_the_report(tmp_path, monkeypatch):
    """The accelerometer sign warning was printed after the report and after "wrote": a reader took the
    report's dip (-17.8 deg on the CK log) first. Both streams into one buffer keep their order."""
    import io

    sim = simulate_tumble(seed=7, n=900)
    still = np.tile([0.0, 0.0, 1.0], (60, 1))
    mag0 = np.tile(sim.mag[:1], (60, 1)) + np.random.default_rng(0).normal(scale=0.3, size=(60, 3))
    flipped = _csv(tmp_path / "flip.csv", ["mx", "my", "mz", "ax", "ay", "az"],
                   np.column_stack([np.vstack([mag0, sim.mag]), -np.vstack([still, sim.accel])]))
    both = io.StringIO()
    monkeypatch.setattr("sys.stdout", both)
    monkeypatch.setattr("sys.stderr", both)
    assert main(["calibrate", str(flipped), "--out", str(tmp_path / "f.json")]) == 0
    text = both.getvalue()
    assert "--accel-sign -1" in text and "dip" in text
    assert text.index("--accel-sign -1") < text.index("Tumble calibration") < text.index("wrote")
