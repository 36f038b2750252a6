"""One contract for every calibration kind (issue 12, as scikit-learn's ``check_estimator``).

Every registered kind goes recording -> its calibrator -> calibration file -> ``SensorModel`` ->
attitude, and its result honours the :class:`calibrate.contract.Calibration` contract.
"""

import json
from pathlib import Path
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.contract import Calibration, Calibrator, CannotCalibrate
from calibrate.kinds import KINDS, sniff
from compass.attitude import solve_attitude
from compass.calibration import FORMAT, KIND_KEY, dumps, load
from compass.cli import main
from compass.io.table import read_table

N_RUNTIME = 400
DIP_DEG = 60.0
FIELD_UT = 50.0


def fourflip_session(tmp_path):
    from compass.sim.fourflip import simulate_fourflip, write_fourflip

    session = simulate_fourflip(seed=3)
    path, _ = write_fourflip(session, tmp_path / "rec.csv")
    t = session.truth
    g = np.asarray(t["directions"]) * np.asarray(t["gains_per_ut"])[:, None]
    return path, g, np.asarray(t["offsets"]), t["dip_deg"]


def platform3d_session(tmp_path):
    from compass.sim.platform3d import simulate_platform3d, write_platform3d

    sim = simulate_platform3d(seed=3, tilt_axes=3)
    path, _ = write_platform3d(sim, tmp_path / "rec.csv")
    return path, np.asarray(sim.truth["mag_matrix"]), np.asarray(sim.truth["mag_offset"]), sim.truth["dip_deg"]


def reference_session(tmp_path):
    from compass.sim.reference import simulate_reference, write_reference

    sim = simulate_reference(seed=3, n_sensors=1, n_fields=30)
    path, _ = write_reference(sim, tmp_path / "rec.csv")
    s = sim.truth["sensors"]["s1"] if "s1" in sim.truth["sensors"] else next(iter(sim.truth["sensors"].values()))
    return path, np.asarray(s["G"]), np.asarray(s["offset"]), None


def tumble_session(tmp_path):
    from compass.sim.tumble import simulate_tumble, write_tumble

    sim = simulate_tumble(seed=3, n=3000, motion_g=0.0)
    path, _ = write_tumble(sim, tmp_path / "rec.csv")
    t = sim.truth  # raw = hard_iron + inv(soft_iron) @ m, m = C^T B in the accelerometer frame
    g = np.linalg.inv(np.asarray(t["soft_iron"])) @ np.asarray(t["mag_to_accel"]).T
    return path, g, np.asarray(t["hard_iron"]), t["dip_deg"]


def installed_session(tmp_path):
    """A four-flip bench sensor in a product (hard and soft iron), tumbled; '# base:' names its bench file."""
    from calibrate import calibrate_fourflip
    from compass.calibration import dumps
    from compass.io.fourflip import read_fourflip
    from compass.sim.fourflip import simulate_fourflip, write_fourflip
    from compass.sim.installation import random_installation, simulate_installation, write_installation

    session = simulate_fourflip(seed=3)
    bench, _ = write_fourflip(session, tmp_path / "bench.csv")
    (tmp_path / "bench.json").write_text(dumps(calibrate_fourflip(read_fourflip(bench)).to_json()))
    t, inst = session.truth, random_installation(3)
    path, _ = write_installation(simulate_installation(t, inst, kind="tumble", n=1500, seed=3), tmp_path / "rec.csv",
                                 base="bench.json")
    a, k = np.asarray(t["directions"]), np.asarray(t["gains_per_ut"])[:, None]  # raw = V0 + K a.(S B + h)
    return path, k * a @ inst.soft_iron, np.asarray(t["offsets"]) + k[:, 0] * (a @ inst.hard_iron_ut), t["dip_deg"]


SESSIONS = {"installed": installed_session, "fourflip": fourflip_session, "platform3d": platform3d_session, "reference": reference_session,
            "tumble": tumble_session}


def test_every_registered_kind_has_a_contract_case():
    assert set(KINDS) <= set(SESSIONS), "add the new kind's session to SESSIONS"


@pytest.mark.parametrize("name", list(KINDS))
def test_kind_fits_writes_reads_back_and_solves_attitude(tmp_path, name):
    path, g_true, offset_true, dip_true = SESSIONS[name](tmp_path)
    table = read_table(path)
    kind = sniff(table)
    assert kind is KINDS[name] and issubclass(kind.calibrator, Calibrator)
    calibrator = kind.calibrator()
    assert "fit" not in vars(calibrator) and not any(k.endswith("_") for k in vars(calibrator))  # no work in __init__
    result = calibrator.fit(kind.read(table))

    # one result contract
    assert isinstance(result, Calibration) and result.calibration_kind == name
    assert isinstance(result.warnings, tuple) and all(isinstance(w, str) for w in result.warnings)
    assert result.parameters and all(len(v) == 2 and np.isfinite(v[0]) for v in result.parameters.values())
    assert isinstance(result.report(), str) and result.report()
    # it draws only what its calibrator declares (compass calibrate checks those names against --force)
    written = result.plots(kind.read(table), tmp_path / "plots")
    assert {p.name for p in map(Path, written)} <= set(kind.calibrator.plot_files)
    doc = result.to_json()
    assert doc["format"] == FORMAT and doc[KIND_KEY] == name
    for key in ("noise_floor", "steps", "effects", "residual_rms_before", "residual_rms_after", "unexplained"):
        assert key in doc["diagnosis"]
    assert doc["diagnosis"]["effects"] == [] and doc["diagnosis"]["unexplained"] is not True  # clean session

    # the file: written once, read back by the one reader
    cal = tmp_path / "cal.json"
    cal.write_text(dumps(doc))
    loaded = load(cal)
    assert loaded.kind == name and json.loads(cal.read_text())[KIND_KEY] == name
    model = loaded.model

    # attitude on fresh samples of the true sensor: heading error within 3 sigma of what the
    # calibration's uncertainty and the sensor noise propagate to, or (without a covariance) of
    # the field-direction error the true sensor's noise floor allows
    rng = np.random.default_rng(7)
    angles = np.column_stack([rng.uniform(0, 360, N_RUNTIME), rng.uniform(-50, 50, N_RUNTIME),
                              rng.uniform(-50, 50, N_RUNTIME)])
    rot = Rotation.from_euler("ZYX", angles * [-1, -1, 1], degrees=True)  # R_world<-housing (SPEC section 1)
    dip = np.radians(dip_true if dip_true is not None else DIP_DEG)
    b_h = rot.apply(FIELD_UT * np.array([np.cos(dip), 0.0, -np.sin(dip)]), inverse=True)  # every simulator's |B|
    raw = offset_true + b_h @ g_true.T
    accel = rot.apply([0.0, 0.0, 1.0], inverse=True)
    if model.dip_deg is None:  # a reference-field calibration carries no dip: the site gives it
        model = replace(model, dip_deg=DIP_DEG)
    att = solve_attitude(model, raw, accel=accel)
    err = np.mod(att.heading_deg - angles[:, 0] + 180.0, 360.0) - 180.0
    # the field direction's error from the noise floor alone, over the fit's samples
    n_fit = len(table.rows)
    floor = np.degrees(np.max(model.component_noise) * model.field_norm / FIELD_UT / np.sqrt(n_fit / 12)
                       / (model.field_norm * np.cos(dip)))
    sigma = np.sqrt(np.mean(att.heading_sigma_deg**2)) if model.direction_covariance is not None else floor
    assert np.sqrt(np.mean(err**2)) < 3 * max(sigma, floor)


def test_cannot_calibrate_is_exit_2_in_words(tmp_path, capsys):
    from compass.sim.reference import simulate_reference, write_reference

    path, _ = write_reference(simulate_reference(seed=4, n_sensors=1, fields="coplanar"), tmp_path / "rec.csv")
    with pytest.raises(CannotCalibrate, match="coplanar"):
        KINDS["reference"].calibrator().fit(KINDS["reference"].read(read_table(path)))
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal.json")]) == 2
    assert "coplanar" in capsys.readouterr().err and not (tmp_path / "cal.json").exists()


@pytest.mark.parametrize("kind", ["reference", "platform3d"])
@pytest.mark.parametrize("damage, message", [("constant", "never changes"), ("huge cell", "row {row}, column")])
def test_absurd_fits_are_refused_naming_the_column(tmp_path, capsys, kind, damage, message):
    # issue 16.3: a constant channel gave a gain of 1.9e-17, one 1e9 cell a gain of 4.5e6, exit 0 (the
    # reader now refuses a constant column before the fit, which refuses it too when called directly)
    path = tmp_path / "rec.csv"
    if kind == "reference":
        from compass.sim.reference import simulate_reference, write_reference

        write_reference(simulate_reference(seed=5, n_sensors=1, n_fields=20), path)
    else:
        from compass.sim.platform3d import simulate_platform3d, write_platform3d

        write_platform3d(simulate_platform3d(seed=5), path)
    lines = path.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    col = 5  # mz, or the reference array's s1_z
    for i in range(first + 1, len(lines)):
        cells = lines[i].split(",")
        if damage == "constant":
            cells[col] = "1.5"
        elif i == first + 3:
            cells[col] = "1e9"
        lines[i] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal.json"), "--quiet"]) == 2
    err = capsys.readouterr().err
    column, message = lines[first].split(",")[col], message.format(row=first + 4)
    assert message in err and f"'{column}'" in err and "rec.csv" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "cal.json").exists()


def test_a_registry_line_naming_another_kinds_calibrator_is_refused_when_used():
    from calibrate.kinds import Kind

    wrong = Kind("fourflip", "flip_deg", lambda t: True, "compass.io.fourflip:fourflip_from_table",
                 "calibrate.tumble:TumbleCalibrator")
    with pytest.raises(ValueError, match="TumbleCalibrator is for 'tumble'"):
        wrong.calibrator
