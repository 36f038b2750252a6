"""``compass demo``'s recording: the calibration, the attitude it gives and the errors against the
simulator's truth, in one .rrd whose default layout shows all three (one tab each)."""

from __future__ import annotations

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ..frames import r_world_from_housing
from . import _layout
from ._drawing import log_housing
from ._stream import Recording, columns_index
from .attitude import reference_dip, attitude_views, log_attitude
from .calibration import log_calibration_result

__all__ = ["record_demo", "errors_views"]


def errors_views() -> rrb.Container:
    """Attitude errors against the truth, with the propagated sigma, and the two housings."""
    return rrb.Horizontal(
        _layout.spatial(origin="/world", name="estimate (blue) and truth (grey, beside it); N = magnetic north",
                        eye=(2.6, 3.4, 1.8), target=(0.0, -0.9, 0.0)),
        rrb.Vertical(*(_layout.series(origin=f"/errors/{name}", name=f"{name[:-4]} error (deg), +-1 sigma propagated")
                       for name in ("heading_deg", "pitch_deg", "roll_deg"))),
        column_shares=[1, 2], name="attitude errors against the truth")


def record_demo(path, recording_path, calibration_result, attitude, model, *, t_s, raw, accel, truth_heading_deg,
                truth_pitch_deg, truth_roll_deg, base_residuals=None) -> None:
    """Write the demo's .rrd.

    Parameters
    ----------
    path : path
        The .rrd file.
    recording_path : path
        The four-flip recording that was calibrated.
    calibration_result
        Its result (:func:`compass.viz.calibration.log_calibration_result`).
    attitude : compass.attitude.Attitude
        The attitude solved with that calibration on the runtime recording.
    model : compass.model.SensorModel
    t_s, raw, accel : ndarray
        The runtime recording's time (s), channels and accelerometer.
    truth_heading_deg, truth_pitch_deg, truth_roll_deg : ndarray (n,)
        The simulator's attitude.
    base_residuals : callable, optional
        As :func:`compass.viz.calibration.log_calibration_result`.
    """
    import inspect

    from ..attitude import solve_attitude

    defaults = inspect.signature(solve_attitude).parameters
    with Recording(path, application_id=_layout.APPLICATION_IDS["demo"]) as out:
        rec = out.rec
        calibration = log_calibration_result(rec, calibration_result, recording_path, base_residuals=base_residuals)
        log_attitude(rec, attitude, t_s=t_s, raw=raw, accel=accel, dip_deg=reference_dip(attitude, model),
                     channels=model.channels,
                     field_tolerance=defaults["field_tolerance"].default,
                     dip_tolerance_deg=defaults["dip_tolerance_deg"].default)
        index = columns_index(t_s, np.arange(len(t_s)))
        rec.log("world/beside", rr.Transform3D(translation=[0.0, -1.8, 0.0]), static=True)
        log_housing(rec, "world/beside/truth", color=(170, 170, 170), label="truth", axis_labels=False)
        truth = r_world_from_housing(truth_heading_deg, truth_pitch_deg, truth_roll_deg)
        rec.send_columns("world/beside/truth", indexes=index,
                         columns=rr.Transform3D.columns(quaternion=truth.as_quat()))
        sigma = {"heading_deg": attitude.heading_sigma_deg, "pitch_deg": attitude.pitch_sigma_deg,
                 "roll_deg": attitude.roll_sigma_deg}
        for name, est, true in (("heading_deg", attitude.heading_deg, truth_heading_deg),
                                ("pitch_deg", attitude.pitch_deg, truth_pitch_deg),
                                ("roll_deg", attitude.roll_deg, truth_roll_deg)):
            error = np.mod(est - true + 180.0, 360.0) - 180.0
            rec.log(f"errors/{name}", rr.SeriesPoints(names=[f"{name} error"], marker_sizes=[1.5]), static=True)
            rec.send_columns(f"errors/{name}", indexes=index, columns=rr.Scalars.columns(scalars=error))
            if sigma[name] is not None:
                rec.log(f"errors/{name}/sigma_band", rr.SeriesLines(names=["-1 sigma", "+1 sigma"],
                                                                    colors=[[150, 150, 150]] * 2), static=True)
                rec.send_columns(f"errors/{name}/sigma_band", indexes=index, columns=rr.Scalars.columns(
                    scalars=np.asarray(sigma[name])[:, None] * [-1.0, 1.0]))
        # the time t: the calibration's and the attitude's timeline both (their sample numbers are not one count)
        rec.send_blueprint(_layout.blueprint(rrb.Tabs(calibration, attitude_views(), errors_views(), active_tab=0), "t"))
