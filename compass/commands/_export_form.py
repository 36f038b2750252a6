"""What every firmware form of ``compass export`` shares: which of the calibration's channels the firmware
reads as its sensor's x, y and z.

A firmware (x-io Fusion, ArduPilot's AP_Compass, the MotionCal sketches) reads its magnetometer chip as a
vector ``(x, y, z)`` and applies ``matrix (raw - offset)``.  A calibration keeps its channels in the
order the recording's columns came in, which a logger may have written as ``my,mx,mz``: the matrix's
columns and the offset must be put in the chip's order, or the firmware's field is a swapped one (104 deg
RMS of heading for ``my,mx,mz``).  :func:`axis_order` takes the order from the channels' names as the
recording readers read them (:func:`compass.io.table.magnetometer_axis`: ``mx``, ``Magnetometer X``,
``mag_x``, ``x``), or from ``--axes``; names that say no axis (``v1,v2,v3``) are refused rather than
taken in their order.
"""

from __future__ import annotations

__all__ = ["axis_order", "axes_words", "mirrored_words", "parse_axes"]


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
        ``axes`` names a channel the calibration does not have; or, without ``axes``, the names do not
        say each of x, y, z once.
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
    raise BadInput(f"{cal.path}: its channels {', '.join(channels)} do not say which is the sensor's x, y and z "
                   f"(names mx,my,mz, x,y,z or mag_x.. say it), and the firmware reads its chip in that order: give "
                   f"the channels in the firmware's x, y, z order with --axes (--axes {','.join(channels)} if "
                   f"{channels[0]} is x)")


def axes_words(cal, order) -> str:
    """``"x, y, z = channels my, mx, mz"``: the order an export wrote, for its comment."""
    names = [cal.model.channels[i] for i in order]
    return f"sensor x, y, z = the calibration's channels {', '.join(names)}"


def mirrored_words(rotation, axes: str) -> str | None:
    """Why a form that leaves ``rotation`` out (a symmetric matrix: ArduPilot's, MotionCal's) cannot take it, or
    None: a reflection (determinant -1) is no rotation to leave out or to name by an angle.

    Parameters
    ----------
    rotation : ndarray, shape (3, 3)
        The orthogonal factor of the firmware's matrix (:func:`compass.commands.export.channel_form`).
    axes : str
        :func:`axes_words` of the order the matrix is in.
    """
    import numpy as np

    if np.linalg.det(rotation) > 0:
        return None
    return (f"with {axes}, the sensor's axes are a left-handed set against the field's frame (a determinant of -1: "
            f"two channels swapped, or one read with its sign turned), which a symmetric matrix cannot hold; check the "
            f"order (--axes) and the channels' signs, or export --format fusion (a full matrix)")
