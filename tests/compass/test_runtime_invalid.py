"""Non-finite or absurd readings are flagged and skipped at runtime, never fused (16.1 outside the filter, 16.4)."""

import io
import json
import time

import numpy as np

from compass.cli import main
from compass.live import LiveSession
from compass.sample_check import new_readings, skip_codes
from compass.serial_reader import Chunk
from compass.sim.device import PtyDevice, default_model, simulate_device
from compass.calibration import model_to_dict

N = 1200  # 12 s at 100 Hz: the three bad samples come after the reference's quiet second
BAD = {500: "gyro", 600: "accel", 700: "field"}


def _run(samples):
    model = default_model()
    device = PtyDevice(model, rate_hz=100.0)
    stream = device._header + b"".join(device._lines(samples, 0))
    out = io.StringIO()
    session = LiveSession(model, out=out)
    for k in range(0, len(stream), 700):
        session.feed(Chunk(time.perf_counter(), stream[k:k + 700]))  # raises on main: math domain error
    session.close()
    return session, np.genfromtxt(io.StringIO(out.getvalue()), delimiter=",", names=True, skip_header=1)


def test_absurd_readings_in_live_are_skipped_counted_and_change_nothing_else():
    """A gyro, accelerometer and channel reading beyond what the sensors read (yet below the line protocol's
    1e12, beyond which the line itself is invalid): each part skipped and counted, the rest used; the sample
    whose field was skipped writes no row (it has no field ratio nor dip)."""
    model = default_model()
    clean = simulate_device(model, np.arange(N) / 100.0, seed=4)
    dirty = simulate_device(model, np.arange(N) / 100.0, seed=4)
    dirty.gyro[500] = [1e5, 0.0, 0.0]
    dirty.accel[600] = [0.0, 1e9, 0.0]
    dirty.raw[700, 0] = 1e11
    reference, ref_rows = _run(clean)
    session, rows = _run(dirty)
    assert sum(session.skipped.values()) == 3 and reference.skipped == {}
    assert {r.split()[0] for r in session.skipped} == {"gyro", "accel", "field"}
    assert "not fused 3" in session.summary() and session.decoder.stats.invalid == 0
    assert np.array_equal(rows["t_s"], np.delete(ref_rows["t_s"], 700))  # the field's sample: no row
    at = {k: np.flatnonzero(np.isclose(rows["t_s"], t / 100.0))[0] for t, k in BAD.items() if k != "field"}
    assert rows["accel_used"][at["accel"]] == 0
    ref_rows = np.delete(ref_rows, 700)
    # never disabled for good: a few seconds on, the run is the clean run's
    later = rows["t_s"] > 10.0
    assert np.array_equal(rows["accel_used"][later], ref_rows["accel_used"][later])
    assert rows["accel_used"][later].mean() > 0.5
    np.testing.assert_allclose(rows["heading_deg"][later], ref_rows["heading_deg"][later], atol=0.5)
    assert np.all(np.isfinite(rows["heading_deg"])) and np.all(np.isfinite(rows["field_ratio"]))


def test_skip_codes_flag_only_what_no_sensor_reads():
    field = np.array([[20.0, 0, -40], [2e3, 0, 0], [1e5, 0, 0], [np.inf, 0, 0]])  # a magnet (x40) passes
    accel = np.array([[0, 0, 9.81], [0, 0, 30 * 9.81], [np.nan] * 3, [0, 0, 1e300]])  # a 30 g shock passes
    assert skip_codes(field, 50.0).tolist() == [0, 0, 2, 1]
    assert skip_codes(field[:2].repeat(2, 0), 50.0, accel, 9.81).tolist() == [0, 0, 0, 3]
    gyro = np.array([[0.1, 0, 0], [60.0, 0, 0], [np.nan] * 3, [1e300, 0, 0]])  # 60 rad/s: a spin, passes
    assert skip_codes(field[:1].repeat(4, 0), 50.0, gyro=gyro).tolist() == [0, 0, 0, 4]
    assert skip_codes(field, float("nan")).tolist() == [0, 0, 0, 1]  # no scale: only non-finite


def test_attitude_flags_an_absurd_row_instead_of_reporting_it_undisturbed(tmp_path, capsys):
    """16.4: a 1e300 reading gave field_ratio inf with disturbed 0 (now the reader refuses it; 1e10 is read)."""
    model = default_model()
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(model_to_dict(model)))
    s = simulate_device(model, np.arange(300) / 100.0, seed=2)
    s.raw[100, 1] = 1e10  # beyond any field; the reader refuses beyond 1e12 itself (exit 2, row and column)
    rec = tmp_path / "rec.csv"
    names = list(model.channels)
    lines = ["t_s," + ",".join(names) + ",ax,ay,az"]
    lines += [",".join(f"{v:.10g}" for v in (t, *raw, *a)) for t, raw, a in zip(s.t_s, s.raw, s.accel)]
    rec.write_text("\n".join(lines) + "\n")
    att = tmp_path / "att.csv"
    assert main(["attitude", str(cal), str(rec), "--out", str(att)]) == 0
    lines = [line for line in att.read_text().splitlines() if not line.startswith("#")]
    table = np.genfromtxt(lines, delimiter=",", names=True)  # nan cells on skipped rows, by design
    skipped = table["skipped"]
    assert skipped[100] == 2 and np.count_nonzero(skipped) == 1  # 2: field out of range (SKIP_REASONS)
    assert table["disturbed"][100] == 1
    ok = np.arange(300) != 100
    assert np.all(np.isfinite(table["field_ratio"][ok])) and np.all(np.isfinite(table["heading_deg"][ok]))
    assert not np.isfinite(table["heading_deg"][100]) and not np.isfinite(table["field_ratio"][100])
    out = capsys.readouterr().out
    assert "1 skipped" in out
    assert "beyond the field it was calibrated over" not in out  # a skipped row is not extrapolated either


def test_attitude_skips_once_however_many_rows_are_absurd():
    """Skipped rows are flagged once against the whole recording's typical |a| and |B|: a subset whose
    median differs no longer flags again (solving the kept rows twice raised a TypeError, exit 1)."""
    from compass.attitude import solve_attitude

    model = default_model()
    s = simulate_device(model, np.arange(30) / 100.0, seed=3)
    scale = np.r_[np.ones(12), np.full(6, 2000.0), np.full(12, 1e7)]  # the median |a| is absurd itself
    att = solve_attitude(model, s.raw, accel=s.accel * scale[:, None])
    flagged = att.skipped != 0
    assert np.all(np.isnan(att.heading_deg[flagged])) and np.all(np.isfinite(att.heading_deg[~flagged]))
    assert np.all(att.disturbed[flagged] == 1) and flagged.any() and not flagged.all()


def test_new_readings_are_the_rows_that_differ_from_the_row_before_in_some_component():
    readings = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.5], [1.0, 2.0, 3.5], [1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(new_readings(readings), [True, False, True, False, True])
    assert new_readings(readings[:1]).tolist() == [True]
