"""What every firmware form of ``compass export`` shares: which of the calibration's channels the firmware
reads as its sensor's x, y and z.

A firmware (x-io Fusion, ArduPilot's AP_Compass, the MotionCal sketches) reads its magnetometer chip as a
vector ``(x, y, z)`` and applies ``matrix (raw - offset)``.  A calibration keeps its channels in the
order the recording's columns came in, which a logger may have written as ``my,mx,mz``: the matrix's
columns and the offset must be put in the chip's order, or the firmware's field is a swapped one (104 deg
RMS of heading for ``my,mx,mz``).  :func:`axis_order` takes the order from the channels' names as the
recording readers read them (:func:`compass.io.table.magnetometer_axis`: ``mx``, ``Magnetometer X``,
``mag_x``, ``x``), or from ``--axes``; names that say no axis (``v1,v2,v3``, a bench's channels) are taken in
the recording's column order, the order the module sent them (said in the output), and names that say some axes
but not each of x, y, z once are refused.

ArduPilot's and MotionCal's matrices are symmetric: the rotation between the sensor's axes and the
accelerometer's (the housing's without one) is left out (:func:`left_out`).  Its cost in heading is more
than its angle: a tilt of the field's frame by ``theta`` about a unit axis ``n`` moves the vertical field
into the horizontal plane.  For a level housing at heading ``psi`` under a field of dip ``delta``, to first
order in ``theta``,

.. math:: \\delta h(\\psi) = \\theta\\, (n_z + \\tan\\delta\\; n_h \\cos(\\psi - \\psi_n)),

``n_h`` and ``psi_n`` the axis's horizontal part and azimuth: up to ``theta (|n_z| + n_h tan delta)``, at
most ``theta / cos delta`` (a horizontal axis at ``tan n_z = cot delta``), below ``theta (1 + tan delta)``:
0.76 deg left out costs 1.69 deg at dip 65 (:func:`heading_cost_deg` computes it exactly, over headings).
"""

from __future__ import annotations

__all__ = ["UNUSABLE", "axis_order", "axes_words", "heading_cost_deg", "left_out", "parse_axes", "rotation_words",
           "warnings_of"]


UNUSABLE = ("not_converged", "undetermined")
"""Warning classes (:data:`compass.production.figures.WARNING_CLASSES`) whose numbers a firmware must not take
without ``--force``: a fit that did not converge, a part the recording did not determine.  The others (coverage,
unexplained structure with widened sigmas...) are repeated and exported."""


def warnings_of(cal, *, force: bool) -> list[str]:
    """The calibration's own warnings, which an export repeats (stderr, and the output's comments).

    Parameters
    ----------
    cal : compass.calibration.Calibration
    force : bool
        ``--force``: export a calibration whose warnings are of an :data:`UNUSABLE` class all the same.

    Returns
    -------
    list of str
        The file's warnings, and the diagnosis's unexplained structure when no warning says it.

    Raises
    ------
    compass.cli.BadInput
        A warning of an :data:`UNUSABLE` class, without ``force``: the first one, in its words.
    """
    from ..cli import BadInput
    from ..production.figures import classify_warning

    words = list(cal.provenance.warnings)
    classes = [classify_warning(w) for w in words]
    if cal.provenance.unexplained and "unexplained" not in classes:
        words.append("the residual diagnosis left structure above the noise floor unexplained: the uncertainties "
                     "were widened to cover it")
    unusable = [(c, w) for c, w in zip(classes, words) if c in UNUSABLE]
    if unusable and not force:
        kinds = sorted({c.replace("_", " ") for c, _ in unusable})
        raise BadInput(f"{cal.path}: its own warnings say its numbers are not to be used ({', '.join(kinds)}): "
                       f"{unusable[0][1]}; recalibrate, or export it all the same with --force")
    return words


def parse_axes(text: str) -> tuple[str, str, str]:
    """``--axes "v2,v1,v3"`` -> the three channel names the firmware reads as x, y, z (ValueError else)."""
    names = tuple(n.strip() for n in text.split(","))
    if len(names) != 3 or any(not n for n in names) or len(set(names)) != 3:
        raise ValueError(f"expected three different channel names separated by commas, the firmware's x, y, z in "
                         f"order (--axes v2,v1,v3), got {text!r}")
    return names


def axis_order(cal, axes: tuple[str, str, str] | None = None) -> tuple[int, int, int]:
    """The indices of the calibration's channels the firmware reads as its sensor's x, y, z.

    Parameters
    ----------
    cal : compass.calibration.Calibration
        Three channels (errors name its ``path``).
    axes : tuple of 3 str, optional
        ``--axes``: the channels' names in the firmware's x, y, z order; default from the names.

    Returns
    -------
    tuple of 3 int
        ``order[k]`` is the index (in ``cal.model.channels``) of the channel read as axis ``k``.

    Raises
    ------
    compass.cli.BadInput
        ``axes`` names a channel the calibration does not have; or, without ``axes``, the names say some axes
        but not each of x, y, z once.
    """
    from ..cli import BadInput
    from ..io.table import magnetometer_axis

    channels = tuple(cal.model.channels)
    if axes is not None:
        unknown = [n for n in axes if n not in channels]
        if unknown:
            raise BadInput(f"{cal.path}: --axes names {', '.join(unknown)}, which the calibration does not have (its "
                           f"channels: {', '.join(channels)})")
        return tuple(channels.index(n) for n in axes)
    said = [magnetometer_axis(n) for n in channels]
    if sorted(a for a in said if a is not None) == ["x", "y", "z"]:
        return tuple(said.index(a) for a in "xyz")
    if all(a is None for a in said):
        return 0, 1, 2
    raise BadInput(f"{cal.path}: its channels {', '.join(channels)} name some of the sensor's axes but not each of "
                   f"x, y and z once, and the firmware reads its chip in that order: give the channels in the "
                   f"firmware's x, y, z order with --axes (--axes {','.join(channels)} if {channels[0]} is x)")


def axes_words(cal, order, axes=None) -> str:
    """``"sensor x, y, z = the calibration's channels my, mx, mz"``: the order an export wrote (``axes``: the
    ``--axes`` given), for its comment; names that say no axis are said to be taken in their column order."""
    from ..io.table import magnetometer_axis

    names = [cal.model.channels[i] for i in order]
    words = f"sensor x, y, z = the calibration's channels {', '.join(names)}"
    if axes is None and all(magnetometer_axis(n) is None for n in names):
        words += " in the recording's column order (their names say no axis; --axes names another)"
    return words


def rotation_words(cal) -> str:
    """What the rotation a symmetric matrix leaves out is, in words: into the accelerometer's frame, or (a bench
    calibration without one) into the housing's."""
    if cal.tumble is not None or cal.imu.rotation is not None:
        return "magnetometer-to-accelerometer rotation"
    return "rotation of the sensor's axes into the housing's (the file has no accelerometer)"


def heading_cost_deg(rotation, dip_deg: float, n_headings: int = 360) -> tuple[float, float]:
    """RMS and largest heading error of a level housing whose firmware leaves ``rotation`` out, degrees.

    Parameters
    ----------
    rotation : array_like, shape (3, 3)
        The rotation the full form applies last (``field = rotation @ soft @ (raw - offset)``, into the
        accelerometer's frame); the firmware's field is ``rotation.T`` of the true one.
    dip_deg : float
        The field's dip (> 0 pointing down), degrees.
    n_headings : int
        Headings over the full turn.

    Returns
    -------
    rms_deg, max_deg : float
    """
    import numpy as np

    psi, dip = np.radians(np.arange(n_headings) * 360.0 / n_headings), np.radians(dip_deg)
    b = np.column_stack([np.cos(dip) * np.cos(psi), np.cos(dip) * np.sin(psi), np.full_like(psi, -np.sin(dip))])
    seen = b @ np.asarray(rotation, dtype=float)  # rows: rotation.T @ b
    error = np.angle(np.exp(1j * (np.arctan2(seen[:, 1], seen[:, 0]) - psi)), deg=True)
    return float(np.sqrt(np.mean(error ** 2))), float(np.max(np.abs(error)))


def dip_of(cal) -> float | None:
    """The dip the calibration knows, degrees: its site's (World Magnetic Model), else its own; None."""
    if cal.site is not None:
        return float(cal.site.field().dip_deg)
    return cal.model.dip_deg


def left_out(cal, rotation, *, axes: str, max_rotation_deg: float, what: str, form: str) -> str | None:
    """Words for ``rotation`` left out of a symmetric matrix (None when it is under 0.005 deg).

    Parameters
    ----------
    cal : compass.calibration.Calibration
    rotation : ndarray, shape (3, 3)
        The orthogonal factor of the firmware's full matrix, in the firmware's x, y, z order.
    axes : str
        :func:`axes_words` of that order.
    max_rotation_deg : float
        ``--max-rotation-deg``: the largest left out.
    what : str
        The rotation, in words.
    form : str
        The form that leaves it out (``ArduPilot's COMPASS_* parameters``), for the refusal.

    Raises
    ------
    compass.cli.BadInput
        A reflection (determinant -1: no rotation leaves it out), or an angle above ``max_rotation_deg``:
        the words name its heading cost and Fusion's form, which folds the rotation in.
    """
    import math

    import numpy as np
    from scipy.spatial.transform import Rotation

    from ..cli import BadInput

    def refuse(why: str):
        article = "an" if cal.kind[0] in "aeiou" else "a"
        return BadInput(f"{cal.path}: {article} {cal.kind} calibration cannot go into {form}: {why}")

    if np.linalg.det(rotation) < 0:
        raise refuse(f"with {axes}, the sensor's axes are a left-handed set against the field's frame (a determinant "
                     f"of -1: two channels swapped, or one read with its sign turned), which a symmetric matrix cannot "
                     f"hold; check the order (--axes) and the channels' signs, or export --format fusion (a full matrix)")
    angle_deg = math.degrees(Rotation.from_matrix(rotation).magnitude())
    if angle_deg <= 0.005:
        return None
    cost = _cost_words(rotation, dip_of(cal))
    if angle_deg > max_rotation_deg:
        raise refuse(f"the {what} is {angle_deg:.2f} deg, which its symmetric matrix cannot hold; left out, {cost}; "
                     f"export --format fusion (its matrix folds the rotation in), or raise --max-rotation-deg "
                     f"(now {max_rotation_deg:g}) to leave it out")
    return f"the {what} of {angle_deg:.2f} deg (under --max-rotation-deg {max_rotation_deg:g}): {cost}"


def _cost_words(rotation, dip_deg: float | None) -> str:
    """``"it costs up to 1.69 deg of heading (1.15 RMS) at the calibration's dip 65.0 deg"``."""
    if dip_deg is not None:
        rms, worst = heading_cost_deg(rotation, dip_deg)
        return f"it costs up to {worst:.2f} deg of heading ({rms:.2f} RMS) at the calibration's dip {dip_deg:.1f} deg"
    costs = {dip: heading_cost_deg(rotation, dip)[1] for dip in (60.0, 75.0)}
    return ("it costs up to " + " and ".join(f"{c:.2f} deg of heading at dip {d:g}" for d, c in costs.items())
            + " (the calibration knows no dip)")
