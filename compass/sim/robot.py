"""An industrial robot arm's point-to-point path with ground truth, through :mod:`compass.sim.motion`'s IMU.

Issue 22's hidden check turns low-cost boards on a robot's flange; :mod:`compass.sim.motion` is hand-held.
Here the flange moves between random waypoints (orientations tilted up to ``max_tilt_deg`` about a random
horizontal axis at any heading; positions within ``reach_m`` of a centre), each move a length drawn from
``move_range_s`` with a minimum-jerk profile ``s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5`` in position and in
rotation angle about the move's fixed axis, with dwells drawn from ``dwell_range_s`` between moves:

    R(t) = R_a Exp(s(tau) theta u),    p(t) = p_a + s(tau) (p_b - p_a),    tau = (t - t_a) / T,

``theta u = Log(R_a^T R_b)`` in the flange frame (the same as the housing H: the board sits on the flange at
a lever arm ``r`` from its centre, axes aligned).  The axis is fixed during a move, so the body rate and
angular acceleration are ``omega = s' theta u``, ``alpha = s'' theta u`` (H), and the IMU at
``p_imu = p + R r`` reads the specific force

    f = R^T (p_imu'' + g z) = R^T (p'' + g z) + alpha x r + omega x (omega x r)

(differentiate ``R r`` twice with ``R' = R [omega]x``).  The gyro's true rate over ``(t_k-1, t_k]`` is the
path's mean body rate ``Log(R_k-1^T R_k) / dt``, so ``R_k = R_k-1 Exp(rate_k dt)`` holds exactly (motion.py's
convention), also where an interval spans the end of one move and the start of the next.  The field is
homogeneous (NWU world, SPEC section 1); the sensors are :func:`compass.sim.motion.read_sensors`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from ..frames import world_field
from .motion import GRAVITY, MotionRecording, SensorErrors, moving_rows, read_sensors

__all__ = ["RobotPath", "robot_path", "simulate_robot"]


def _minimum_jerk(tau, duration_s):
    """``s``, ``ds/dt`` (1/s) and ``d2s/dt2`` (1/s^2) of the minimum-jerk profile at ``tau`` in [0, 1]."""
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    s1 = 30.0 * tau**2 * (1.0 - tau) ** 2 / duration_s
    s2 = 60.0 * tau * (1.0 - tau) * (1.0 - 2.0 * tau) / duration_s**2
    return s, s1, s2


@dataclass(frozen=True)
class RobotPath:
    """Moves between waypoints, the flange still between them.

    Attributes
    ----------
    start_s, duration_s : ndarray, shape (m,)
        Each move's start and length, s.
    rotation : Rotation, m rotations
        ``R_world<-H`` at each move's start (NWU world).
    rotvec : ndarray, shape (m, 3)
        Each move's ``theta u`` in H (the turn to the next waypoint), rad.
    position_m, step_m : ndarray, shape (m, 3)
        The flange centre at each move's start and the move's displacement, world, m.
    lever_arm_m : ndarray, shape (3,)
        The IMU's offset from the flange centre, H, m.
    """

    start_s: np.ndarray
    duration_s: np.ndarray
    rotation: Rotation
    rotvec: np.ndarray
    position_m: np.ndarray
    step_m: np.ndarray
    lever_arm_m: np.ndarray

    def _phase(self, t):
        """The move in force at ``t`` (the last started; the first before it) and its ``tau`` in [0, 1]."""
        move = np.clip(np.searchsorted(self.start_s, t, side="right") - 1, 0, len(self.start_s) - 1)
        return move, np.clip((t - self.start_s[move]) / self.duration_s[move], 0.0, 1.0)

    def attitude(self, t) -> Rotation:
        """True ``R_world<-H`` at times ``t`` (s, shape (n,))."""
        move, tau = self._phase(t)
        s = _minimum_jerk(tau, self.duration_s[move])[0]
        return self.rotation[move] * Rotation.from_rotvec(s[:, None] * self.rotvec[move])

    def imu_position(self, t) -> np.ndarray:
        """The IMU's world position ``p + R r`` at times ``t``, m, shape (n, 3)."""
        move, tau = self._phase(t)
        s = _minimum_jerk(tau, self.duration_s[move])[0]
        return self.position_m[move] + s[:, None] * self.step_m[move] + self.attitude(t).apply(self.lever_arm_m)

    def mean_rate(self, t) -> np.ndarray:
        """The exact mean body rate ``Log(R_k-1^T R_k) / (t_k - t_k-1)`` over ``(t_k-1, t_k]`` (0 for the first
        sample), H, rad/s, shape (n, 3); ``t`` increasing, at most half a turn per interval."""
        attitude = self.attitude(t)
        step = (attitude[:-1].inv() * attitude[1:]).as_rotvec() / np.diff(t)[:, None]
        return np.r_[np.zeros((1, 3)), step]

    def specific_force(self, t) -> tuple[np.ndarray, np.ndarray]:
        """The IMU's specific force in H (m/s^2) and its motion acceleration ``p_imu''`` in the world (m/s^2) at
        times ``t``, each shape (n, 3)."""
        move, tau = self._phase(t)
        _, s1, s2 = _minimum_jerk(tau, self.duration_s[move])
        omega, alpha = s1[:, None] * self.rotvec[move], s2[:, None] * self.rotvec[move]
        r = self.lever_arm_m
        arm = np.cross(alpha, r) + np.cross(omega, np.cross(omega, r))
        attitude = self.attitude(t)
        flange = s2[:, None] * self.step_m[move]
        specific = attitude.apply(flange + [0.0, 0.0, GRAVITY], inverse=True) + arm
        return specific, flange + attitude.apply(arm)


def _waypoint(rng, max_tilt_deg: float, reach_m: float) -> tuple[Rotation, np.ndarray]:
    """A random flange pose: any heading, tilted up to ``max_tilt_deg`` about a random horizontal axis; the
    position uniform in a ball of radius ``reach_m``."""
    axis = rng.uniform(0.0, 2.0 * np.pi)
    tilt = np.radians(rng.uniform(0.0, max_tilt_deg)) * np.array([np.cos(axis), np.sin(axis), 0.0])
    attitude = Rotation.from_rotvec(tilt) * Rotation.from_euler("z", rng.uniform(0.0, 360.0), degrees=True)
    direction = rng.normal(size=3)
    return attitude, reach_m * rng.uniform() ** (1.0 / 3.0) * direction / np.linalg.norm(direction)


def robot_path(rng, *, duration_s: float = 60.0, rest_s: float = 3.0, move_range_s=(1.0, 3.0),
               dwell_range_s=(0.5, 2.0), max_tilt_deg: float = 60.0, reach_m: float = 0.5,
               lever_arm_range_m=(0.05, 0.15)) -> RobotPath:
    """Random waypoints and moves: still for ``rest_s`` at both ends, moves of a length uniform in
    ``move_range_s`` (s) between dwells uniform in ``dwell_range_s`` (s), the IMU at a lever arm of length uniform
    in ``lever_arm_range_m`` (m) in a random direction.

    Parameters
    ----------
    rng : numpy.random.Generator
    duration_s, rest_s : float
    move_range_s, dwell_range_s, lever_arm_range_m : pair of floats
        Each a (min, max).
    max_tilt_deg, reach_m : float

    Returns
    -------
    RobotPath
    """
    direction = rng.normal(size=3)
    arm = rng.uniform(*lever_arm_range_m) * direction / np.linalg.norm(direction)
    attitude, position = _waypoint(rng, max_tilt_deg, reach_m)
    starts, lengths, attitudes, rotvecs, positions, steps = [], [], [], [], [], []
    t = rest_s
    while True:
        length = rng.uniform(*move_range_s)
        if t + length > duration_s - rest_s:
            break
        target, target_position = _waypoint(rng, max_tilt_deg, reach_m)
        starts.append(t)
        lengths.append(length)
        attitudes.append(attitude.as_quat())
        rotvecs.append((attitude.inv() * target).as_rotvec())
        positions.append(position)
        steps.append(target_position - position)
        attitude = attitude * Rotation.from_rotvec(rotvecs[-1])  # the waypoint the move reaches exactly
        position = target_position
        t += length + rng.uniform(*dwell_range_s)
    if not starts:
        raise ValueError(f"no move of {move_range_s[0]:g} s fits between {rest_s:g} s rests in {duration_s:g} s")
    return RobotPath(np.array(starts), np.array(lengths), Rotation.from_quat(attitudes), np.array(rotvecs),
                     np.array(positions), np.array(steps), arm)


def simulate_robot(seed: int, *, duration_s: float = 60.0, rate_hz: float = 285.714,
                   errors: SensorErrors = SensorErrors(), field_ut: float = 43.0, dip_deg: float = 69.0,
                   **path) -> MotionRecording:
    """Simulate one robot-arm trial (kind ``"robot"``).

    Parameters
    ----------
    seed : int
        Seeds the path and the noise.
    duration_s, rate_hz : float
    errors : SensorErrors
    field_ut, dip_deg : float
        The homogeneous field (a Berlin-like default).
    **path
        :func:`robot_path`'s options (``rest_s``, ``move_range_s``, ``dwell_range_s``, ``max_tilt_deg``,
        ``reach_m``, ``lever_arm_range_m``).

    Returns
    -------
    MotionRecording
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration_s * rate_hz))) / rate_hz
    robot = robot_path(rng, duration_s=duration_s, **path)
    rotation = robot.attitude(t)
    rate = robot.mean_rate(t)
    specific, accel_world = robot.specific_force(t)
    field_h = rotation.apply(world_field(dip_deg, field_ut), inverse=True)
    gyro, accel, mag = read_sensors(rng, t, rate_hz, rate, specific, field_h, errors)
    return MotionRecording("robot", t, rotation, rate, specific, moving_rows(rate, accel_world), gyro, accel, mag,
                           field_ut, dip_deg, errors)
