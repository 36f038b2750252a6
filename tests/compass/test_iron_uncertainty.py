"""A tumble file's own uncertainty (hard iron, soft iron, rotation) in the runtime's heading sigma:
compass/iron_uncertainty.py, read by compass/calibration/, used by compass attitude and compass live."""

import copy
import dataclasses

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
    # a sigma the fit could not give (null or infinite): named undetermined, never read as zero
    bad["tumble"]["hard_iron_sigma"] = [None, 0.1, float("inf")]
    assert from_dict(bad).model.iron_uncertainty.undetermined == ("the hard iron along mx, mz",)
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
