"""``compass export``'s options: a stored calibration is named as the store's, an option given where it does
nothing is refused in one line (exit 2)."""

import json

import numpy as np
import pytest

from compass.calibration import model_to_dict
from compass.cli import main
from compass.model import SensorModel
from compass.production.store import Store
from compass.response import LinearResponse

TUMBLE = {"format": "compass-calibration/1", "model": "tumble", "hard_iron": [1.0, -2.0, 3.0],
          "soft_iron": np.diag([1.1, 0.9, 1.0]).tolist(), "field_norm": 50.0, "mag_to_accel": None,
          "field_ut": 50.0, "dip_deg": 60.0, "noise_floor": [0.3] * 3}


def unit_bench() -> dict:
    """A bench calibration in units of the bench's |B| (no field_ut): MotionCal's packet, in uT, refuses it."""
    model = SensorModel(("mx", "my", "mz"), np.eye(3), (LinearResponse(1.0, 2.0, (-1.0, 1.0)),) * 3, 1.0, dip_deg=60.0)
    return model_to_dict(model) | {"noise_floor": [0.01] * 3}


def store_with(tmp_path, docs: dict) -> str:
    path = tmp_path / "calibrations.sqlite"
    with Store(path) as store:
        for module, doc in docs.items():
            store.add(module_id=module, session_time="2026-11-25T10:00:00", recording_path=f"/line/{module}.csv",
                      recording_sha256=module * 8, toolkit_version="test", kind=doc["model"] if "model" in doc
                      else "fourflip", status="accepted", reasons=[], notes=[], figures={},
                      calibration=json.dumps(doc), spec_text="", spec_sha256="0")
    return str(path)


def test_a_stored_calibration_is_named_as_the_module_in_its_store_never_a_temporary_file(tmp_path, capsys):
    store = store_with(tmp_path, {"M1": unit_bench(), "M2": TUMBLE, "M4": TUMBLE | {"field_ut": None}})
    assert main(["export", "--module", "M1", "--store", store, "--format", "motioncal"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("compass export: module M1, session 2026-11-25T10:00:00 (accepted;")
    assert len(err) == 2 and err[1].startswith(f"compass export: module M1 in {store}: a channels calibration cannot "
                                               f"go into MotionCal's packet: its field is in units of the bench's |B|")
    assert main(["export", "--module", "M2", "--store", store, "--format", "motioncal"]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("bytes 75 54")  # the packet's first two bytes
    assert main(["export", "--module", "M4", "--store", store, "--format", "fusion", "--unit", "gauss"]) == 0
    assert f"compass export: warning: module M4 in {store}: its field norm is 50" in capsys.readouterr().err


def test_a_stored_calibration_that_is_not_json_is_named_too(tmp_path, capsys):
    store = tmp_path / "calibrations.sqlite"
    with Store(store) as s:
        s.add(module_id="M3", session_time="2026-03-02T07:00:00+00:00", recording_path="r", recording_sha256="h", toolkit_version="v",
              kind="tumble", status="accepted", reasons=[], notes=[], figures={}, calibration="{not json",
              spec_text="", spec_sha256="0")
    assert main(["export", "--module", "M3", "--store", str(store), "--format", "fusion"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith(
        f"compass export: module M3 in {store}: not a JSON calibration file")


UNUSED = [
    ("fusion", ["--baud", "9600"], "--baud is for --format motioncal with --port; it does nothing with --format fusion"),
    ("fusion", ["--wait", "2"], "--wait is for --format motioncal with --port; it does nothing with --format fusion"),
    ("fusion", ["--max-rotation-deg", "2"], "--max-rotation-deg is for --format ardupilot or motioncal; it does "
                                            "nothing with --format fusion"),
    ("ardupilot", ["--fusion-api", "1.2"], "--fusion-api is for --format fusion; it does nothing with --format "
                                           "ardupilot"),
    ("ardupilot", ["--port", "/dev/null"], "--port is for --format motioncal; it does nothing with --format ardupilot"),
    ("motioncal", ["--fusion-api", "1.3"], "--fusion-api is for --format fusion; it does nothing with --format "
                                           "motioncal"),
    ("motioncal", ["--baud", "9600"], "--baud is for --format motioncal with --port; it does nothing with --format "
                                      "motioncal without --port (nothing is sent)"),
]


@pytest.mark.parametrize(("fmt", "extra", "words"), UNUSED, ids=[f"{f}{e[0]}" for f, e, _ in UNUSED])
def test_an_option_the_format_does_not_use_is_refused_in_one_line(tmp_path, capsys, fmt, extra, words):
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(TUMBLE))
    out = tmp_path / "out"
    assert main(["export", str(cal), "--format", fmt, "--out", str(out), *extra]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [f"compass export: {words}"]
    assert not out.exists()


def test_without_a_format_the_stored_file_takes_no_format_option(tmp_path, capsys):
    store = store_with(tmp_path, {"M2": TUMBLE})
    assert main(["export", "--module", "M2", "--store", store, "--unit", "gauss"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "compass export: --unit is for --format fusion, ardupilot or motioncal; it does nothing with no --format "
        "(the stored file is written as it is)"]


@pytest.mark.parametrize(("fmt", "extra"), [("fusion", ["--fusion-api", "1.2", "--unit", "uT"]),
                                            ("ardupilot", ["--unit", "gauss"]),
                                            ("motioncal", ["--max-rotation-deg", "2", "--unit", "uT"])])
def test_the_options_a_format_uses_are_taken(tmp_path, capsys, fmt, extra):
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(TUMBLE))
    assert main(["export", str(cal), "--format", fmt, *extra]) == 0
    printed = capsys.readouterr().out
    assert {"fusion": "FusionCalibrationMagnetic", "ardupilot": "COMPASS_OFS_X,-1000.0000",
            "motioncal": "bytes 75 54"}[fmt] in printed
