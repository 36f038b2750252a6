"""Column names with a meaning of their own (SPEC section 2): never a sensor's channel.

A calibration's channel is named after the recording column it reads; a channel called ``t_s``
would read the time as a field, one called ``ax`` the accelerometer.  The calibration file reader
refuses these names as channels, and a four-flip recording takes every other column as one.
"""

from __future__ import annotations

__all__ = ["RESERVED_NAMES"]

RESERVED_NAMES = ("t_s", "seq", "temp_c", "ax", "ay", "az", "gx", "gy", "gz", "flip_deg", "platform_deg",
                  "platform_x_deg", "platform_y_deg", "platform_z_deg", "pitch_deg", "roll_deg", "heading_deg",
                  "heading_ref_deg")
"""Time, sample counter, temperature, accelerometer, gyro, and the angles of the recordings."""
