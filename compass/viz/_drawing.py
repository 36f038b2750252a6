"""Shapes drawn in 3-D: a housing whose axes can be read, cones for limits and uncertainties."""

from __future__ import annotations

import numpy as np
import rerun as rr

__all__ = ["log_housing", "log_north", "cone_strips", "AXIS_COLORS", "FIELD_COLOR", "GRAVITY_COLOR", "REFERENCE_COLOR"]

AXIS_COLORS = np.array([[230, 60, 60], [60, 190, 60], [70, 110, 240]], dtype=np.uint8)  # X red, Y green, Z blue
FIELD_COLOR = [240, 170, 30]
GRAVITY_COLOR = [150, 90, 220]
REFERENCE_COLOR = [70, 70, 70]  # dark grey: reads on the viewer's light and dark backgrounds
# the housing's own axes, short (long names overlapped once the housing turned) and right however
# it is turned ("Z up" pointed down when it was upside down); the nose and fin tell front and top
AXIS_LABELS = ["+X", "+Y", "+Z"]

# the body: a flat slab longer along X, a nose on its +X end, a fin on top at the back (+Z, -X),
# so forward/back, left/right and up/down can each be told at a glance (FLU, SPEC section 1)
_BODY_CENTERS = [[0.0, 0.0, 0.0], [0.55, 0.0, 0.0], [-0.35, 0.0, 0.16]]
_BODY_HALF_SIZES = [[0.45, 0.28, 0.06], [0.10, 0.12, 0.04], [0.08, 0.02, 0.10]]


def log_housing(rec, path: str, *, color=(90, 140, 220), label: str | None = None, scale: float = 1.0,
                axis_labels: bool = True) -> None:
    """Log a housing (static) at ``path``: body, nose (+X), fin (+Z) and labelled X/Y/Z arrows.

    Turn it by logging a ``Transform3D`` at ``path`` (``R_parent<-housing``).

    Parameters
    ----------
    rec : rerun.RecordingStream
    path : str
        Entity path of the housing frame; shapes go to ``path/body`` and ``path/axes``.
    color : rgb
    label : str, optional
        Shown on the body (e.g. "estimate", "truth").
    scale : float
        Size factor (the body is 1.1 long at scale 1).
    axis_labels : bool
        Name the X/Y/Z arrows (off where other labelled arrows lie along them).
    """
    body = [label or "housing", "nose (+X)", "top (+Z)"]
    rec.log(f"{path}/body", rr.Boxes3D(centers=scale * np.array(_BODY_CENTERS),
                                        half_sizes=scale * np.array(_BODY_HALF_SIZES),
                                        colors=[color] * 3, labels=body, show_labels=False,
                                        fill_mode=rr.components.FillMode.Solid), static=True)
    rec.log(f"{path}/axes", rr.Arrows3D(vectors=scale * 0.9 * np.eye(3), colors=AXIS_COLORS, labels=AXIS_LABELS,
                                        show_labels=axis_labels), static=True)


def log_north(rec, path: str, *, length: float = 1.8, height: float = -0.9) -> None:
    """A compass rose on the floor of an NWU world (static): N along +X, W along +Y, labelled.

    Parameters
    ----------
    path : str
        Entity path (the world frame).
    length : float
        Arrow length, world units.
    height : float
        Z of the floor it is drawn on (below the housing, clear of its arrows).
    """
    rec.log(path, rr.Arrows3D(origins=[[0.0, 0.0, height]] * 2, vectors=[[length, 0.0, 0.0], [0.0, 0.6 * length, 0.0]],
                              colors=[[200, 40, 40], [120, 120, 120]], radii=[0.02, 0.01],
                              labels=["N (magnetic north)", "W"], show_labels=True), static=True)


def cone_strips(axis, half_angle_rad: float, length: float = 1.0, n_ring: int = 24, n_lines: int = 6) -> list:
    """Line strips outlining a cone from the origin about ``axis``.

    Parameters
    ----------
    axis : array-like, shape (3,)
        Cone axis (any length; normalised).
    half_angle_rad : float
        Half opening angle, radians (below pi/2).
    length : float
        Distance along the axis of the ring drawn at the cone's open end.

    Returns
    -------
    list of ndarray
        A closed ring at ``length`` and ``n_lines`` generators from the origin to the ring.
    """
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    helper = np.eye(3)[np.argmin(np.abs(a))]
    u = np.cross(a, helper)
    u /= np.linalg.norm(u)
    v = np.cross(a, u)
    radius = length * np.tan(min(half_angle_rad, np.radians(89.0)))
    phi = np.linspace(0.0, 2.0 * np.pi, n_ring + 1)
    ring = length * a + radius * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    step = n_ring // n_lines
    return [ring] + [np.array([np.zeros(3), ring[k]]) for k in range(0, n_ring, step)]
