"""python -m calibrate.realdata counts its work: a bar that ends at its total, exactly."""

import re

import pytest
from scipy.io import loadmat, savemat

from calibrate import realdata
from tests._paths import SHARED

BROAD = SHARED / "data" / "broad"
SOURCES = {"01_undisturbed_slow_rotation_A": "01_a", "02_undisturbed_slow_rotation_B": "02_b",
           "32_disturbed_attached_magnet_1cm": "32_disturbed_c"}


@pytest.mark.skipif(not (BROAD / "01_undisturbed_slow_rotation_A.mat").exists(), reason=f"no BROAD data at {BROAD}")
def test_the_residual_loop_shows_a_bar_that_ends_at_its_total(tmp_path, capsys, progress_terminal):
    for source, name in SOURCES.items():  # the first 80 s of two training trials and one scored trial
        d = loadmat(BROAD / f"{source}.mat", squeeze_me=True)
        n = int(80 * float(d["sampling_rate"]))
        savemat(tmp_path / f"{name}.mat", {k: (v[:n] if k in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "opt_pos",
                                                              "movement") else v)
                                           for k, v in d.items() if not k.startswith("__")})
    terminal = progress_terminal("calibrate.realdata.working")
    assert realdata.main([str(tmp_path)]) == 0
    total = len(SOURCES) + realdata.loop_units(len(SOURCES))
    counts = [(int(a), int(b)) for a, b in re.findall(r"\] (\d+)/(\d+) ", terminal.getvalue())]
    assert {b for _, b in counts} == {total} and counts[-1][0] == total
    assert [a for a, _ in counts] == sorted(a for a, _ in counts)  # only forward
    assert "world-frame field residual" in capsys.readouterr().out
