"""Frames and angle conventions of SPEC section 1, on top of scipy's ``Rotation``.

Bench frame W: Z up, turntable about +Z.  Housing frame H: X along the cube edge on the
turntable's X axis, Z up in the initial position.  A sensing direction seen in W is
``a_W = Rz(phi) Rx(kappa) a_H`` (turntable angle phi, flip kappa, both right-handed).

Runtime world frame: magnetic North, West, Up (NWU); housing FLU;
``R_world<-housing = Rz(-heading) Ry(-pitch) Rx(roll)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "sphere_cells",
    "bench_rotation",
    "field_in_bench",
    "seed_angles",
    "direction_sigma_deg",
    "unit_from_seed_angles",
    "r_world_from_housing",
    "heading_pitch_roll",
    "world_field",
]


def bench_rotation(platform_deg, flip_deg) -> Rotation:
    """Rotation taking housing-frame vectors into the bench frame W.

    Parameters
    ----------
    platform_deg, flip_deg : array_like, shape (n,) or scalar
        Turntable angle phi and flip kappa, degrees.

    Returns
    -------
    Rotation
        ``Rz(phi) Rx(kappa)``, one per sample.
    """
    phi = np.atleast_1d(np.asarray(platform_deg, dtype=float))
    kappa = np.broadcast_to(np.asarray(flip_deg, dtype=float), phi.shape)
    # intrinsic "ZX": Rz(phi) then about the new x by kappa = Rz(phi) Rx(kappa)
    return Rotation.from_euler("ZX", np.column_stack([phi, kappa]), degrees=True)


def field_in_bench(dip_deg: float, azimuth_deg: float, magnitude: float = 1.0) -> np.ndarray:
    """Earth field in the bench frame W, shape (3,).

    ``B_W = |B| (cos(dip) cos(delta), cos(dip) sin(delta), -sin(dip))``; dip > 0 points down.
    """
    dip, delta = np.radians(dip_deg), np.radians(azimuth_deg)
    return magnitude * np.array(
        [np.cos(dip) * np.cos(delta), np.cos(dip) * np.sin(delta), -np.sin(dip)]
    )


def seed_angles(direction) -> dict[str, np.ndarray]:
    """Seed 000's angles of unit vectors in the housing frame, degrees.

    Parameters
    ----------
    direction : array_like, shape (..., 3)

    Returns
    -------
    dict
        ``theta_deg`` (azimuth of the XY projection from X toward Y), ``gamma_deg`` (angle of the
        XZ projection from X toward Z), ``elevation_deg`` (angle to the XY plane), ``psi_deg``
        (angle to the XZ plane).  theta and gamma are singular coordinates for a vector along Z
        (theta undefined) or Y (gamma undefined); they are reported, never estimated.
    """
    a = np.asarray(direction, dtype=float)
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    return {
        "theta_deg": np.degrees(np.arctan2(y, x)),
        "gamma_deg": np.degrees(np.arctan2(z, x)),
        "elevation_deg": np.degrees(np.arctan2(z, np.hypot(x, y))),
        "psi_deg": np.degrees(np.arctan2(y, np.hypot(x, z))),
    }


def direction_sigma_deg(covariance) -> np.ndarray:
    """RMS angular uncertainty of unit vectors, degrees: the ``direction_sigma_deg`` of SPEC section 2.

    Parameters
    ----------
    covariance : array_like, shape (..., 3, 3)
        Covariance of each unit vector's components (rank 2: nothing along the vector).

    Returns
    -------
    ndarray, shape (...)
        ``sqrt(trace(covariance))`` in degrees.
    """
    return np.degrees(np.sqrt(np.trace(np.asarray(covariance, dtype=float), axis1=-2, axis2=-1)))


def unit_from_seed_angles(theta_deg, elevation_deg) -> np.ndarray:
    """Unit vector in H from azimuth theta and elevation, shape (..., 3)."""
    th, el = np.radians(theta_deg), np.radians(elevation_deg)
    return np.stack(
        [np.cos(el) * np.cos(th), np.cos(el) * np.sin(th), np.sin(el)], axis=-1
    )


def r_world_from_housing(heading_deg, pitch_deg, roll_deg) -> Rotation:
    """``R_world<-housing`` for NWU world and FLU housing (SPEC section 1)."""
    angles = np.column_stack(
        np.broadcast_arrays(
            -np.asarray(heading_deg, float), -np.asarray(pitch_deg, float), np.asarray(roll_deg, float)
        )
    )
    return Rotation.from_euler("ZYX", angles, degrees=True)


def heading_pitch_roll(r_world_housing: Rotation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Heading [0, 360), pitch [-90, 90], roll (-180, 180] in degrees from ``R_world<-housing``."""
    zyx = np.atleast_2d(r_world_housing.as_euler("ZYX", degrees=True, suppress_warnings=True))
    heading = np.mod(-zyx[:, 0], 360.0)
    heading[heading >= 360.0] = 0.0
    roll = zyx[:, 2]
    roll = np.where(roll <= -180.0, roll + 360.0, roll)
    return heading, -zyx[:, 1], roll


def world_field(dip_deg: float, magnitude: float = 1.0) -> np.ndarray:
    """Earth field in the NWU world frame (magnetic north), shape (3,)."""
    dip = np.radians(dip_deg)
    return magnitude * np.array([np.cos(dip), 0.0, -np.sin(dip)])


def row_norms(v: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row of ``v`` (shape (n, 3) -> (n,)), any unit.

    ``sqrt(einsum("ij,ij->i"))``: three times faster than ``np.linalg.norm(v, axis=1)``, whose reduction over
    rows of three runs a strided loop per row; the two agree to rounding (one unit in the last place).
    """
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def sphere_cells(n_cells: int) -> np.ndarray:
    """Centres of ``n_cells`` near-equal-area cells on the unit sphere (Fibonacci lattice), shape (n, 3).

    Coverage of a free-motion calibration counts the cells the field's direction has visited
    (frame-free: directions in whatever frame the caller's vectors are).
    """
    i = np.arange(n_cells) + 0.5
    z = 1.0 - 2.0 * i / n_cells
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(1.0 - z**2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
