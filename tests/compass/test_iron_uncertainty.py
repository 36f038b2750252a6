"""A tumble file's own uncertainty (hard iron, soft iron, rotation) in the runtime's heading sigma:
compass/iron_uncertainty.py, read by compass/calibration/, used by compass attitude and compass live."""

import copy
import dataclasses
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calibrate.tumble import calibrate_tumble
from compass.attitude import solve_attitude
from compass.calibration import CalibrationFileError, from_dict
from compass.frames import r_world_from_housing, world_field
from compass.sim.tumble import simulate_tumble


@pytest.fixture(scope="module")
def widened():
    """An unexplained tumble (a hard iron wandering by 0.5 uT, outside the vocabulary): its file, whose hard-iron
    sigmas were widened, and the same file with the naive ones (the diagnosis's ``unexplained_cost``)."""
    sim = simulate_tumble(seed=9, n=3000)
    rng = np.random.default_rng(10)
    walk = np.cumsum(rng.normal(size=sim.mag.shape), axis=0)
    walk = 0.5 * (walk - walk.mean(axis=0)) / walk.std()
    doc = calibrate_tumble(sim.mag + walk, sim.accel, t_s=sim.t_s).to_json()
    cost = doc["diagnosis"]["unexplained_cost"]["hard_iron"]
    naive = copy.deepcopy(doc)
    naive["tumble"]["hard_iron_sigma"] = [cost[a]["naive"] for a in ("mx", "my", "mz")]
    return sim, doc, naive


def _level_raw(model, headings_deg, dip_deg):
    """Raw readings of a level housing at ``headings_deg`` through the file's model (its inverse)."""
    field_h = r_world_from_housing(headings_deg, 0.0, 0.0).apply(world_field(dip_deg, model.field_norm), inverse=True)
    x = np.einsum("ij,nj->ni", model.unit_directions, field_h)
    raw = np.column_stack([r.output(x[:, c]) for c, r in enumerate(model.responses)])
    return raw, field_h


def test_a_widened_tumble_file_gives_a_larger_heading_sigma_on_every_sample(widened):
    sim, doc, naive_doc = widened
    wide, naive = from_dict(doc).model, from_dict(naive_doc).model
    assert wide.iron_uncertainty is not None
    assert np.all(wide.iron_uncertainty.hard_iron_sigma >= naive.iron_uncertainty.hard_iron_sigma)
    rows = slice(0, None, 10)
    raw, accel = sim.mag[rows], sim.accel[rows]
    s_wide = solve_attitude(wide, raw, accel=accel)
    s_naive = solve_attitude(naive, raw, accel=accel)
    s_none = solve_attitude(dataclasses.replace(wide, iron_uncertainty=None), raw, accel=accel)
    ok = np.isfinite(s_wide.heading_sigma_deg)
    assert ok.mean() > 0.9
    assert np.all(s_wide.heading_sigma_deg[ok] > s_naive.heading_sigma_deg[ok])
    assert np.all(s_naive.heading_sigma_deg[ok] > s_none.heading_sigma_deg[ok])  # before: no calibration term
    # the weights are the noise's; only a row's dip excess over its (now wider) dip sigma moves an angle, within it
    moved = np.abs(np.mod(s_wide.heading_deg - s_none.heading_deg + 180.0, 360.0) - 180.0)
    assert np.all(moved[ok] < s_none.heading_sigma_deg[ok])
    # compass live / the replay: the filter's heading sigma and the file's at the estimate's attitude
    iron = wide.iron_uncertainty
    r = Rotation.from_euler("ZYX", [30.0, 10.0, -5.0], degrees=True).as_matrix()
    b = r.T @ world_field(wide.dip_deg, wide.field_norm)
    assert iron.heading_sigma_deg(r, b) > naive.iron_uncertainty.heading_sigma_deg(r, b) > 0


def test_the_heading_sigma_holds_wherever_the_reference_field_points(widened):
    """``heading_sigma_deg`` is ``n^T Sigma_B n / |B_h|^2`` with ``n`` the unit horizontal across the field
    (``up x B``), at any attitude and any azimuth of the field (the live filter's North may have moved to a
    new place's), not only a field along the world's North."""
    _, doc, _ = widened
    iron = from_dict(doc).model.iron_uncertainty
    rng = np.random.default_rng(3)
    for _ in range(20):
        r = Rotation.from_euler("ZYX", rng.uniform([-180, -40, -40], [180, 40, 40]), degrees=True).as_matrix()
        azimuth = rng.uniform(-np.pi, np.pi)
        world = 40.0 * np.array([np.cos(1.0) * np.cos(azimuth), np.cos(1.0) * np.sin(azimuth), -np.sin(1.0)])
        b = r.T @ world
        up = r[2]
        across = np.cross(up, b)
        n = across / np.linalg.norm(across)
        expected = np.degrees(np.sqrt(n @ iron.covariance(b) @ n) / np.linalg.norm(across))
        np.testing.assert_allclose(iron.heading_sigma_deg(r, b), expected, rtol=1e-9)


def test_the_filter_weights_the_noise_alone_and_an_installed_model_drops_the_bench_iron_sigma(widened):
    """A tumble file's own uncertainty is a constant error of the calibration, not noise: the filter's
    ``mag_noise`` is the same with or without it (the reported heading sigma carries it).  An installed
    model's field is the product's, in its frame: the bench's iron sigmas do not describe it."""
    from compass.filter import FilterConfig
    from compass.installed import installed_model

    _, doc, _ = widened
    model = from_dict(doc).model
    bare = dataclasses.replace(model, iron_uncertainty=None)
    config = FilterConfig.from_model(model)
    assert config.calibration_uncertainty is model.iron_uncertainty  # carried to the reported sigma, not fused
    assert dataclasses.replace(config, calibration_uncertainty=None) == FilterConfig.from_model(bare)
    assert np.trace(model.field_covariance(np.zeros(3))) > np.trace(bare.field_covariance(np.zeros(3)))
    late = dataclasses.replace(model, mag_latency_s=0.012)
    inside = installed_model(late, np.array([2.0, -1.0, 0.5]), np.eye(3) * 1.02)
    assert inside.iron_uncertainty is None and inside.mag_latency_s == 0.012


@pytest.mark.parametrize("part", ["hard_iron_sigma", "soft_iron_sigma", "rotation_sigma_rad"])
def test_the_propagated_heading_sigma_agrees_with_a_monte_carlo_over_the_files_covariance(widened, part):
    """Draw the hard iron, the soft iron's six numbers or the rotation from the file's sigmas (independent; one
    part at a time, so that each term is checked, not only the largest), turn the same raw readings into
    headings, and compare the spread with the propagated sigma's calibration part (the total less the
    noise's, in quadrature)."""
    _, doc, _ = widened
    model = from_dict(doc).model
    iron = model.iron_uncertainty
    parts = ("hard_iron_sigma", "soft_iron_sigma", "rotation_sigma_rad")
    scaled = dataclasses.replace(iron, **{p: (10.0 if p == part else 0.0) * getattr(iron, p) for p in parts})
    model = dataclasses.replace(model, iron_uncertainty=scaled)
    headings = np.arange(0.0, 360.0, 30.0)
    raw, field_h = _level_raw(model, headings, model.dip_deg)
    np.testing.assert_allclose(model.field(raw)[0], field_h, atol=1e-9 * model.field_norm)
    total = solve_attitude(model, raw, level=True)
    noise = solve_attitude(dataclasses.replace(model, iron_uncertainty=None), raw, level=True)
    propagated = np.sqrt(total.heading_sigma_deg**2 - noise.heading_sigma_deg**2)
    assert np.all(propagated > 0.02)

    form = from_dict(doc).tumble
    h, s, c = form.hard_iron, form.soft_iron, form.mag_to_accel
    rng = np.random.default_rng(7)
    k = 3000
    errors = np.empty((k, len(headings)))
    iu = np.triu_indices(3)
    for i in range(k):
        dh = rng.normal(0.0, scaled.hard_iron_sigma)
        d_up = np.zeros((3, 3))
        d_up[iu] = rng.normal(0.0, scaled.soft_iron_sigma[iu])
        ds = d_up + np.triu(d_up, 1).T  # symmetric: S_ij and S_ji one number
        turn = Rotation.from_rotvec(rng.normal(0.0, scaled.rotation_sigma_rad)).as_matrix()
        b = (raw - (h + dh)) @ (turn @ c @ (s + ds)).T
        heading = np.degrees(np.arctan2(b[:, 1], b[:, 0]))  # level: the field in H turns back as the housing turns
        errors[i] = np.mod(heading - headings + 180.0, 360.0) - 180.0
    # the level solution's heading is that azimuth (checked on the unperturbed readings)
    b0 = model.field(raw)[0]
    np.testing.assert_allclose(np.mod(np.degrees(np.arctan2(b0[:, 1], b0[:, 0])), 360.0),
                               np.mod(total.heading_deg, 360.0), atol=1e-6)
    spread = errors.std(axis=0)
    # sampling error of a standard deviation from k draws: 1 / sqrt(2 k) (1.3 %); 4 of them, and the first
    # order's remainder
    np.testing.assert_allclose(spread, propagated, rtol=4 / np.sqrt(2 * k) + 0.01)


def test_the_files_sigmas_are_checked(widened):
    _, doc, _ = widened
    bad = copy.deepcopy(doc)
    bad["tumble"]["hard_iron_sigma"] = [0.1, -0.2, 0.1]
    with pytest.raises(CalibrationFileError, match=r"tumble.hard_iron_sigma.*must not be negative"):
        from_dict(bad)
    bad["tumble"]["hard_iron_sigma"] = [0.1, 0.2]
    with pytest.raises(CalibrationFileError, match="tumble.hard_iron_sigma"):
        from_dict(bad)
    # a sigma the fit could not give (null or infinite): named undetermined, never read as zero: the stated prior
    bad["tumble"]["hard_iron_sigma"] = [None, 0.1, float("inf")]
    iron = from_dict(bad).model.iron_uncertainty
    assert iron.undetermined == ("the hard iron along mx, mz (taken as 10 % of |B|)",)
    from compass.iron_uncertainty import HARD_IRON_PRIOR

    prior = HARD_IRON_PRIOR * doc["tumble"]["field_norm_recording_units"]
    np.testing.assert_allclose(iron.hard_iron_sigma, [prior, 0.1, prior], rtol=1e-6)
    # anything else is refused, naming the key: text, mixed lists, values no calibration reaches
    for key, value in (("hard_iron_sigma", "abc"), ("hard_iron_sigma", [1, "a", 3]), ("hard_iron_sigma", [1e300, 1, 1]),
                       ("misalignment_rotvec_sigma_deg", "x"), ("soft_iron_sigma", [[0.1] * 3] * 2)):
        bad = copy.deepcopy(doc)
        bad["tumble"][key] = value
        with pytest.raises(CalibrationFileError, match=f"tumble.{key}"):
            from_dict(bad)
    bad = copy.deepcopy(doc)
    bad["tumble"]["gyro"] = "x"
    with pytest.raises(CalibrationFileError, match="tumble.gyro"):
        from_dict(bad)


def test_the_files_latency_reaches_the_model_when_the_magnetometer_is_late_beyond_three_sigma(widened):
    _, doc, _ = widened
    assert from_dict(doc).model.mag_latency_s == 0.0  # no gyro: no latency
    # late beyond 3 sigma with a sigma the data gave (below a fifth of the fit's prior): taken; else 0
    for tau, sigma, expected in ((0.012, 0.0003, 0.012), (0.0005, 0.0003, 0.0), (-0.012, 0.0003, 0.0),
                                 (0.04, 0.012, 0.0)):
        late = copy.deepcopy(doc)
        late["tumble"]["gyro"] = {"method": "gyro", "used": True, "mag_latency_s": tau, "mag_latency_sigma_s": sigma}
        assert from_dict(late).model.mag_latency_s == expected
    for value in ("soon", 0.9):  # not a number; beyond where the filter's first-order turn holds
        late["tumble"]["gyro"]["mag_latency_s"] = value
        with pytest.raises(CalibrationFileError, match="tumble.gyro.mag_latency_s"):
            from_dict(late)
    from calibrate.tumble.gyro import LATENCY_PRIOR_S
    from compass.calibration._read import LATENCY_SIGMA_SEEN_S

    assert LATENCY_SIGMA_SEEN_S == pytest.approx(0.2 * LATENCY_PRIOR_S)  # the calibration's words and the runtime agree


def test_the_live_pipeline_and_its_replay_carry_the_files_sigma(widened):
    """``compass live`` and ``compass attitude --filter`` (one pipeline): the same filter on the same samples,
    the heading sigma with the file's uncertainty larger on every row, the attitudes unchanged."""
    import io

    from compass.filter import FilterConfig
    from compass.live import CSV_COLUMNS, LiveSession
    from compass.replay import replay
    from compass.sim.device import simulate_device

    _, doc, _ = widened
    model = from_dict(doc).model
    bare = dataclasses.replace(model, iron_uncertainty=None)
    t = np.arange(0.0, 12.0, 0.01)
    s = simulate_device(model, t, seed=4)
    tables = []
    for m in (model, bare):  # the filters' configs differ only in the calibration's own uncertainty (above)
        out = io.StringIO()
        replay(LiveSession(m, config=FilterConfig.from_model(m), out=out), t, s.raw, s.accel, s.gyro)
        rows = [line.split(",") for line in out.getvalue().splitlines() if line and not line.startswith(("#", "t_s"))]
        tables.append(np.array(rows, dtype=float))
    wide, plain = tables
    heading, sigma = CSV_COLUMNS.index("heading_deg"), CSV_COLUMNS.index("heading_sigma_deg")
    assert len(wide) == len(plain) > 0.9 * len(t)
    np.testing.assert_array_equal(wide[:, heading], plain[:, heading])
    assert np.all(wide[:, sigma] > plain[:, sigma])


def _replayed(model, t, s, config=None, events=None):
    """The replay's CSV (compass attitude --filter, compass live's pipeline) as an array, and its columns."""
    import io

    from compass.live import CSV_COLUMNS, LiveSession
    from compass.replay import replay

    out = io.StringIO()
    on_event = None if events is None else (lambda level, text: events.append((level, text)))
    replay(LiveSession(model, config=config, out=out, on_event=on_event), t, s.raw, s.accel, s.gyro)
    rows = [line.split(",") for line in out.getvalue().splitlines() if line and not line.startswith(("#", "t_s"))]
    return np.array(rows, dtype=float), CSV_COLUMNS


def test_run_filter_reports_the_heading_sigma_the_replay_reports(widened):
    """The documented offline path (``run_filter(..., FilterConfig.from_model(model))``) gives the replay's and
    compass live's heading sigma on the same samples, the tumble file's own uncertainty included (it gave the
    filter's noise-only sigma)."""
    from compass.filter import FilterConfig, run_filter
    from compass.sim.device import simulate_device

    _, doc, _ = widened
    model = from_dict(doc).model
    t = np.arange(0.0, 12.0, 0.01)
    s = simulate_device(model, t, seed=4)
    table, columns = _replayed(model, t, s)
    track = run_filter(t, s.accel, s.gyro, model.field(s.raw)[0], FilterConfig.from_model(model))
    bare = run_filter(t, s.accel, s.gyro, model.field(s.raw)[0],
                      FilterConfig.from_model(dataclasses.replace(model, iron_uncertainty=None)))
    rows = np.searchsorted(t, table[:, columns.index("t_s")] - 1e-6)
    np.testing.assert_array_equal(t[rows].round(4), table[:, columns.index("t_s")])
    sigma = table[:, columns.index("heading_sigma_deg")]
    np.testing.assert_allclose(track.heading_sigma_deg[rows], sigma, atol=5.1e-4)  # the CSV's 3 decimals
    assert np.all(track.heading_sigma_deg[rows] > bare.heading_sigma_deg[rows] + 1e-3)


def _channel_model(scale=1.0):
    """The simulated device's model with a four-flip's kind of uncertainty: each channel's direction covariance
    (0.2 deg about each axis across the direction), offset sigma and gain sigma times ``scale`` (none of them in
    the filter's ``mag_noise``: :meth:`FilterConfig.from_model` takes the white noise alone)."""
    from compass.sim.device import default_model

    model = default_model()
    a = model.unit_directions
    across = np.eye(3)[None] - a[:, :, None] * a[:, None, :]
    cov = (scale * np.radians(0.2)) ** 2 * across
    sigma = scale * np.column_stack([0.002 * np.abs(model.gains) * model.field_norm, 0.002 * np.abs(model.gains)])
    return dataclasses.replace(model, direction_covariance=cov, response_sigma=sigma)


def test_a_channel_forms_own_uncertainty_is_its_field_covariance_less_the_noise():
    """``ChannelUncertainty`` is the calibration part of ``SensorModel.component_variance``; its per-sample
    heading sigma is ``n^T Sigma_B n / |B_h|^2`` at any attitude."""
    model = _channel_model()
    own = model.calibration_uncertainty
    assert own is not None and not own.undetermined
    quiet = dataclasses.replace(model, noise=None)
    rng = np.random.default_rng(5)
    for _ in range(20):
        r = Rotation.from_euler("ZYX", rng.uniform([-180, -40, -40], [180, 40, 40]), degrees=True).as_matrix()
        b = r.T @ world_field(60.0, model.field_norm) + rng.normal(0.0, 2.0, 3)
        np.testing.assert_allclose(own.covariance(b), quiet.field_covariance(b), rtol=1e-12, atol=1e-15)
        across = np.cross(r[2], b)
        expected = np.degrees(np.sqrt(across @ own.covariance(b) @ across) / (across @ across))
        assert own.heading_sigma_deg(r, b) == pytest.approx(expected, rel=1e-9)
        assert own.heading_sigma_deg(r.ravel().tolist(), b.tolist()) == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("kind", ["four-flip", "installation"])
def test_a_widened_channel_calibration_reaches_the_replay_and_run_filter(kind):
    """A four-flip's (or an installation's) widened sigmas reach compass live, its replay and run_filter: the
    heading sigma grows on every row against the naive file's, the attitudes unchanged (never fused)."""
    from compass.filter import FilterConfig, run_filter
    from compass.installed import installed_model
    from compass.sim.device import simulate_device

    if kind == "four-flip":
        naive, wide = _channel_model(1.0), _channel_model(3.0)
    else:
        base = dataclasses.replace(_channel_model(), direction_covariance=None, response_sigma=None)
        cov = np.diag([0.05**2] * 3 + [0.002**2] * 6)  # the installation's hard and soft iron: uT^2, 1
        naive = installed_model(base, [1.0, -0.5, 0.2], np.eye(3), covariance=cov)
        cov *= 9.0  # the hard iron's and the soft iron's: none of it in the filter's mag_noise
        wide = installed_model(base, [1.0, -0.5, 0.2], np.eye(3), covariance=cov)
    t = np.arange(0.0, 12.0, 0.01)
    s = simulate_device(naive, t, seed=6)
    (plain, columns), (widened_table, _) = _replayed(naive, t, s), _replayed(wide, t, s)
    heading, sigma = columns.index("heading_deg"), columns.index("heading_sigma_deg")
    assert len(plain) == len(widened_table) > 0.9 * len(t)
    np.testing.assert_array_equal(plain[:, heading], widened_table[:, heading])
    assert np.all(widened_table[:, sigma] > plain[:, sigma])
    bare = dataclasses.replace(naive, direction_covariance=None, response_sigma=None)
    noise_only, _ = _replayed(bare, t, s)
    assert np.all(plain[:, sigma] > noise_only[:, sigma])  # before: the noise's alone
    # the white noise alone: the offset sigma, three times larger, is not in mag_noise (it was, counted twice)
    assert FilterConfig.from_model(wide).mag_noise == FilterConfig.from_model(bare).mag_noise
    track = run_filter(t, s.accel, s.gyro, wide.field(s.raw)[0], FilterConfig.from_model(wide))
    rows = np.searchsorted(t, widened_table[:, columns.index("t_s")] - 1e-6)
    np.testing.assert_allclose(track.heading_sigma_deg[rows], widened_table[:, sigma], atol=5.1e-4)


@pytest.mark.parametrize("part, words", [
    ("misalignment_rotvec_sigma_deg", "the rotation to the accelerometer about x, y, z (taken as 1.2 deg per axis)"),
    ("mag_to_accel", "the rotation from the magnetometer to the accelerometer (not fitted"),
    ("soft_iron_sigma", "the soft iron's S_xy (taken as 5 %)"),
])
def test_an_undetermined_part_takes_its_stated_prior_everywhere(widened, part, words):
    """A part the fit could not determine is never read as zero: compass attitude, compass live (from a byte
    stream), its replay and run_filter all count its stated prior in the heading sigma (larger than the
    determined file's on every row, finite) and say once which part and what it adds; the attitudes are those
    of the determined file (never fused) and finite."""
    import io
    import time

    from compass.filter import FilterConfig, run_filter
    from compass.frames import r_world_from_housing
    from compass.io.lines import format_line
    from compass.live import LiveSession
    from compass.serial_reader import Chunk
    from compass.sim.device import simulate_device

    sim, doc, _ = widened
    bad = copy.deepcopy(doc)
    if part == "soft_iron_sigma":
        bad["tumble"][part][0][1] = None
    elif part == "mag_to_accel":  # no rotation fitted (a tumble without accelerometer): as calibrate writes it
        bad[part] = bad["tumble"]["misalignment_rotvec_sigma_deg"] = None
    else:
        bad["tumble"][part] = None
    good, model = from_dict(doc).model, from_dict(bad).model
    own = model.calibration_uncertainty
    assert words in own.undetermined[0]
    # the priors' part adds in quadrature: at a level housing, total^2 = determined^2 + priors^2, and the cost
    # the words give is its RMS over headings
    determined = dataclasses.replace(own, hard_iron_sigma=own.hard_iron_sigma - own.prior.hard_iron_sigma,
                                     soft_iron_sigma=own.soft_iron_sigma - own.prior.soft_iron_sigma,
                                     rotation_sigma_rad=own.rotation_sigma_rad - own.prior.rotation_sigma_rad,
                                     undetermined=(), prior=None)
    rot = r_world_from_housing(np.arange(0.0, 360.0, 30.0), 0.0, 0.0)
    fields = rot.apply(world_field(model.dip_deg or 60.0, model.field_norm), inverse=True)
    total, known = ([u.heading_sigma_deg(m, b) for m, b in zip(rot.as_matrix(), fields)] for u in (own, determined))
    added = np.sqrt(np.mean(np.array(total) ** 2 - np.array(known) ** 2))
    assert added > 0.1 and own.cost_deg(model.field_norm, model.dip_deg or 60.0) == pytest.approx(added, rel=1e-9)

    t = np.arange(0.0, 12.0, 0.01)
    s = simulate_device(good, t, seed=4)
    events = []
    table, columns = _replayed(model, t, s, events=events)
    reference, _ = _replayed(good, t, s, config=dataclasses.replace(FilterConfig.from_model(model),
                                                                  calibration_uncertainty=good.calibration_uncertainty))
    sigma, heading = columns.index("heading_sigma_deg"), columns.index("heading_deg")
    said = [text for level, text in events if "undetermined" in text]
    assert len(said) == 1 and words in said[0] and "stated priors" in said[0] and "\n" not in said[0]
    assert re.search(r"add \S+ deg to a level housing's heading sigma", said[0])
    assert np.all(np.isfinite(table)) and len(table) == len(reference)
    if part != "mag_to_accel":  # else the model's rotation differs: other attitudes
        np.testing.assert_array_equal(table[:, heading], reference[:, heading])
        # (an entry's term vanishes where the field has no component it acts on: equal there, as written)
        assert np.all(table[:, sigma] >= reference[:, sigma]) and np.mean(table[:, sigma] > reference[:, sigma]) > 0.9
    # compass live from the module's byte stream: the same
    live_events = []
    live = LiveSession(model, out=io.StringIO(), on_event=lambda level, text: live_events.append(text))
    names = ["t_s", *model.channels, "ax", "ay", "az", "gx", "gy", "gz"]
    data = format_line(names) + b"".join(format_line([repr(v) for v in row.tolist()])
                                         for row in np.column_stack([t, s.raw, s.accel, s.gyro]))
    for k in range(0, len(data), 4096):
        live.feed(Chunk(time.perf_counter(), data[k:k + 4096]))
    live.close()
    assert sum(words in text for text in live_events) == 1
    assert live.estimate.heading_sigma_deg == pytest.approx(table[-1, sigma], abs=5.1e-4)
    # run_filter: the replay's sigma, said in its events
    track = run_filter(t, s.accel, s.gyro, model.field(s.raw)[0], FilterConfig.from_model(model))
    rows = np.searchsorted(t, table[:, columns.index("t_s")] - 1e-6)
    np.testing.assert_allclose(track.heading_sigma_deg[rows], table[:, sigma], atol=5.1e-4)
    assert sum(words in text for _, text in track.events) == 1
    # compass attitude: the prior counts there too
    att = solve_attitude(model, sim.mag[::50], accel=sim.accel[::50])
    plain = solve_attitude(dataclasses.replace(model, iron_uncertainty=determined), sim.mag[::50],
                           accel=sim.accel[::50])
    ok = np.isfinite(att.heading_sigma_deg)
    assert ok.mean() > 0.9 and np.all(att.heading_sigma_deg[ok] >= plain.heading_sigma_deg[ok])
    assert np.mean(att.heading_sigma_deg[ok] > plain.heading_sigma_deg[ok] + 1e-6) > 0.9


def test_the_attitude_command_says_an_undetermined_part_once(widened, tmp_path, capsys):
    from compass.calibration import save
    from compass.cli import main
    from compass.io.table import format_table, read_table

    sim, doc, _ = widened
    bad = copy.deepcopy(doc)
    bad["tumble"]["misalignment_rotvec_sigma_deg"] = None
    cal, rec, out = tmp_path / "cal.json", tmp_path / "rec.csv", tmp_path / "att.csv"
    save(cal, bad)
    columns = {c: v for c, v in zip(("mx", "my", "mz", "ax", "ay", "az"), np.hstack([sim.mag, sim.accel])[::50].T)}
    rec.write_text(format_table(columns, {}, {c: "%.17g" for c in columns}))
    assert main(["attitude", str(cal), str(rec), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    said = [line for line in err.splitlines() if "undetermined" in line]
    assert len(said) == 1 and "the rotation to the accelerometer about x, y, z" in said[0]
    assert "stated priors" in said[0]
    table = read_table(out)  # every number finite (read_table refuses anything else)
    assert np.all(table.column("heading_sigma_deg") > 0)


def test_a_null_lower_soft_iron_entry_adds_its_prior_to_the_upper_ones_sigma_in_quadrature(widened):
    """``S`` is symmetric, so a null ``S_yx`` beside a finite ``S_xy`` makes the one number undetermined: its sigma
    is the finite one and the prior in quadrature (independent), not their sum."""
    from compass.iron_uncertainty import SOFT_IRON_PRIOR

    _, doc, _ = widened
    half = copy.deepcopy(doc)
    half["tumble"]["soft_iron_sigma"][1][0] = None
    own = float(doc["tumble"]["soft_iron_sigma"][0][1])
    iron = from_dict(half).model.iron_uncertainty
    scale = abs(np.linalg.det(np.array(doc["soft_iron"]))) ** (1.0 / 3.0)
    assert iron.prior.soft_iron_sigma[0, 1] == pytest.approx(SOFT_IRON_PRIOR * scale, rel=1e-12)
    assert iron.soft_iron_sigma[0, 1] == pytest.approx(np.hypot(own, SOFT_IRON_PRIOR * scale), rel=1e-12)
    assert own > 0 and iron.soft_iron_sigma[0, 1] < own + SOFT_IRON_PRIOR * scale - 1e-3 * own
    assert any("S_xy" in part for part in iron.undetermined)


def test_a_channel_forms_null_sigma_takes_its_stated_prior_and_is_said():
    """A channel whose direction covariance (or offset sigma) the file leaves null beside channels that give
    theirs is never read as zero (it dropped every channel's before): the direction takes the mounting's
    rotation prior ``sigma^2 (I - a a^T)``, the offset 10 % of |B|; one warning line names them; the file
    written back says null again."""
    from compass.calibration._format import model_to_dict
    from compass.iron_uncertainty import HARD_IRON_PRIOR, ROTATION_PRIOR_AXIS_DEG, undetermined_words

    model = _channel_model()
    doc = model_to_dict(model)
    first, second = model.channels[0], model.channels[1]
    doc["channels"][first]["direction_covariance"] = None
    doc["channels"][second]["response_sigma"]["offset"] = None
    read = from_dict(doc).model
    own = read.calibration_uncertainty
    a = read.unit_directions[0]
    expected = np.radians(ROTATION_PRIOR_AXIS_DEG) ** 2 * (np.eye(3) - np.outer(a, a))
    np.testing.assert_allclose(read.direction_covariance[0], expected, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(read.direction_covariance[1:], model.direction_covariance[1:], rtol=1e-12)
    assert read.response_sigma[1, 0] == pytest.approx(HARD_IRON_PRIOR * read.field_norm * abs(read.gains[1]))
    np.testing.assert_allclose(read.response_sigma[[0, 2]], model.response_sigma[[0, 2]], rtol=1e-12)
    words = undetermined_words(own, read.field_norm, read.dip_deg)
    assert words is not None and "\n" not in words
    assert f"the direction of {first} (taken as" in words and f"the offset of {second} (taken as 10 % of |B|)" in words
    assert own.cost_deg(read.field_norm, 60.0) > 0
    back = model_to_dict(read)
    assert back["channels"][first]["direction_covariance"] is None
    assert back["channels"][second]["response_sigma"]["offset"] is None
    assert undetermined_words(from_dict(back).model.calibration_uncertainty, read.field_norm, read.dip_deg) == words
    # the prior is in the heading sigma: above the same file with that channel's entries read as zero
    zeroed = dataclasses.replace(read, direction_covariance=model.direction_covariance * [[[0]], [[1]], [[1]]],
                                 sigma_priors=None)
    r = Rotation.from_euler("ZYX", [40.0, 5.0, -3.0], degrees=True).as_matrix()
    b = r.T @ world_field(60.0, read.field_norm)
    assert own.heading_sigma_deg(r, b) > zeroed.calibration_uncertainty.heading_sigma_deg(r, b)


@pytest.mark.parametrize("form", ["tumble", "channels"])
def test_the_vectorised_calibration_sigma_is_the_per_sample_one(widened, form):
    """``with_calibration_sigma_many`` (run_filter, after its loop) gives compass live's per-sample
    ``with_calibration_sigma`` on every sample, for either form's uncertainty."""
    from compass.iron_uncertainty import with_calibration_sigma, with_calibration_sigma_many

    own = from_dict(widened[1]).model.iron_uncertainty if form == "tumble" else _channel_model().calibration_uncertainty
    rng = np.random.default_rng(8)
    r = Rotation.from_euler("ZYX", rng.uniform([-180, -50, -50], [180, 50, 50], size=(40, 3)), degrees=True)
    matrices = r.as_matrix()
    b = r.apply(world_field(60.0, 40.0), inverse=True) + rng.normal(0.0, 1.0, (40, 3))
    sigma = rng.uniform(0.1, 2.0, 40)
    expected = [with_calibration_sigma(s, own, m, f) for s, m, f in zip(sigma, matrices, b)]
    np.testing.assert_allclose(with_calibration_sigma_many(sigma, own, matrices, b), expected, rtol=1e-10)
    np.testing.assert_array_equal(with_calibration_sigma_many(sigma, None, matrices, b), sigma)
