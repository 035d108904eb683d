"""Rigid motion of objects and radars over time: the scene file's motion keys and
``[time]`` table, and :func:`scene_at`, the scene moved to another instant.

Every object and every radar that rides on nothing moves rigidly (docs/scene-format.md,
"Motion"): its position follows a constant ``velocity`` or a piecewise-linear
``trajectory`` (rows ``[t, x, y, z]``, the velocity that of the segment), and it may turn
at a constant ``angular_velocity_deg_s`` (a world vector, right hand) about an axis
through ``rotation_centre`` (default: its position), a centre that travels with the
position. A material point x then moves as

    x(t) = c(t) + Q(omega (t - t_s)) (x(t_s) - c(t_s)),   dx/dt = v(t) + omega x (x - c(t))

with Q the rotation by the angle |omega| dt about omega (Rodrigues), c(t) the rotation
centre and v(t) the translation velocity; :meth:`Scene.point_velocity
<clradcom.scene.records.Scene.point_velocity>` gives dx/dt for the Doppler of every
interaction point. A radar that ``rides_on`` an object moves with it (position,
orientation and the velocity of its own point). Poses as written hold at the scene's
start time (``[time] start_s``, default 0 s); trajectories give absolute times.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.spatial.transform import Rotation

from clradcom.errors import ArgumentError, ArgumentTypeError
from clradcom.scene.bounds import check_coordinates, check_speed
from clradcom.scene.fields import FieldReader
from clradcom.scene.records import Motion, Radar, Scene, SceneObject, TimeAxis

__all__ = ["MAX_TIME_STEPS", "MOTION_KEYS", "TIME_KEYS", "covers", "read_motion", "read_time_axis",
           "rotation_matrix", "scene_at", "trajectory_position", "trajectory_velocity"]

#: the keys of an object or a free radar that describe motion beyond ``velocity``
MOTION_KEYS = ("angular_velocity_deg_s", "rotation_centre", "trajectory")
#: the keys of the ``[time]`` table
TIME_KEYS = ("start_s", "step_s", "count")
#: the most instants a ``[time]`` table may ask for
MAX_TIME_STEPS = 1_000_000


# ---------------------------------------------------------------------------
# the scene file


def read_time_axis(fields: FieldReader, data: dict) -> TimeAxis | None:
    """The optional ``[time]`` table (``start_s`` default 0, ``step_s`` > 0, ``count``
    1 .. MAX_TIME_STEPS), or None when the document has none."""
    if "time" not in data:
        return None
    tbl = data["time"]
    if not isinstance(tbl, dict):
        raise fields.err("time", tbl, "expected a table, written [time]")
    fields.check_keys(tbl, TIME_KEYS, "time")
    start = fields.get_float(tbl, "start_s", "time", default=0.0, unit="s")
    step = fields.get_float(tbl, "step_s", "time", lo=0.0, lo_open=True, unit="s")
    count = fields.get(tbl, "count", "time")
    if isinstance(count, bool) or not isinstance(count, int) or not (
            1 <= count <= MAX_TIME_STEPS):
        raise fields.err("time.count", count,
                         f"expected a whole number of instants from 1 to {MAX_TIME_STEPS}")
    last = start + step * (count - 1)
    if not math.isfinite(last) or abs(last) > 1e15:
        raise fields.err("time.step_s", tbl["step_s"], f"the last instant {last:g} s is "
                         "beyond 1e15 s")
    return TimeAxis(start_s=start, step_s=step, count=count)


def read_motion(fields: FieldReader, tbl: dict, kp: str, position: np.ndarray | None,
                span: tuple[float, float]) -> Motion | None:
    """The motion keys of one object or free radar -> :class:`Motion` (None without any).

    ``position`` is the entry's position as written (None when it gives none: then a
    ``trajectory`` is required); ``span`` = (first, last) instant the scene will be
    traced at, which a trajectory must cover. ``trajectory`` excludes ``position`` and
    ``velocity``; ``rotation_centre`` needs ``angular_velocity_deg_s``."""
    if not any(k in tbl for k in MOTION_KEYS):
        return None
    omega = fields.get_vec3(tbl, "angular_velocity_deg_s", kp, default=None, unit="deg/s") \
        if "angular_velocity_deg_s" in tbl else None
    if "rotation_centre" in tbl and omega is None:
        raise fields.err(f"{kp}.rotation_centre", tbl["rotation_centre"],
                         "a rotation centre needs angular_velocity_deg_s")
    traj = None
    if "trajectory" in tbl:
        for other in ("position", "velocity"):
            if other in tbl:
                raise fields.err(f"{kp}.{other}", tbl[other],
                                 f"a trajectory gives the {other}; remove {other} (or the "
                                 "trajectory)")
        traj = _read_trajectory(fields, tbl["trajectory"], f"{kp}.trajectory", span)
        position = trajectory_position(traj, span[0])
    centre = None
    if omega is not None:
        centre = (fields.get_vec3(tbl, "rotation_centre", kp, unit="m")
                  if "rotation_centre" in tbl else np.array(position, dtype=np.float64))
        check_coordinates(fields, centre[None], f"{kp}.rotation_centre",
                          tbl.get("rotation_centre"), "the rotation centre")
    return Motion(angular_velocity_deg_s=omega, rotation_centre=centre, trajectory=traj)


def _read_trajectory(fields: FieldReader, value, key: str,
                     span: tuple[float, float]) -> np.ndarray:
    what = "an array of at least 2 rows [t (s), x, y, z (m)]"
    if not isinstance(value, list) or len(value) < 2:
        raise fields.err(key, value, f"expected {what}")
    rows = np.array([fields.vector(row, f"{key}[{i}]", 4, "t s, x y z m")
                     for i, row in enumerate(value)])
    t = rows[:, 0]
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise fields.err(f"{key}[{i}]", value[i], f"times must increase strictly "
                         f"(row {i} at {t[i]:g} s follows {t[i - 1]:g} s)")
    check_coordinates(fields, rows[:, 1:], key, value, "the trajectory")
    for i in range(len(rows) - 1):
        v = (rows[i + 1, 1:] - rows[i, 1:]) / (t[i + 1] - t[i])
        if not np.all(np.isfinite(v)):
            raise fields.err(f"{key}[{i + 1}]", value[i + 1], "the segment's speed "
                             "overflows")
        check_speed(fields, v, value[i + 1], f"{key}[{i + 1}]")
    lo, hi = span
    if not (covers(rows, lo) and covers(rows, hi)):
        raise fields.err(key, value, f"covers {t[0]:g} .. {t[-1]:g} s, but the scene is "
                         f"traced from {lo:g} to {hi:g} s ([time] or 0 s): extend it")
    return rows


# ---------------------------------------------------------------------------
# poses at a time


def covers(traj: np.ndarray, t: float) -> bool:
    """Whether ``t`` lies in the trajectory's span, give or take 1e-9 of the time (so
    ``start_s + step_s * (count - 1)`` rounded past the last waypoint still counts; the
    pose there is the waypoint's)."""
    slack = 1e-9 * max(1.0, abs(t))
    return bool(traj[0, 0] - slack <= t <= traj[-1, 0] + slack)


def trajectory_position(traj: np.ndarray, t: float) -> np.ndarray:
    """(3,) position of a piecewise-linear trajectory at ``t`` (inside its span)."""
    return np.array([np.interp(t, traj[:, 0], traj[:, j]) for j in (1, 2, 3)])


def trajectory_velocity(traj: np.ndarray, t: float) -> np.ndarray:
    """(3,) velocity at ``t``: that of the segment holding t (at a waypoint, the one
    starting there; at the last, the last segment)."""
    k = int(np.clip(np.searchsorted(traj[:, 0], t, side="right") - 1, 0, len(traj) - 2))
    return (traj[k + 1, 1:] - traj[k, 1:]) / (traj[k + 1, 0] - traj[k, 0])


def rotation_matrix(angular_velocity: np.ndarray, dt: float) -> np.ndarray:
    """(3, 3) rotation by the angle |omega| dt about omega (rad/s)."""
    return Rotation.from_rotvec(np.asarray(angular_velocity, np.float64) * dt).as_matrix()


@dataclasses.dataclass
class _Move:
    """One rigid body's displacement from the scene's time to ``t``."""

    shift: np.ndarray  #: (3,) translation of the position (and of the centre)
    velocity: np.ndarray  #: (3,) translation velocity at t
    turn: np.ndarray | None = None  #: (3,3) rotation, None when the body does not turn
    centre: np.ndarray | None = None  #: rotation centre at the scene's time
    omega: np.ndarray | None = None  #: rad/s

    def points(self, x: np.ndarray) -> np.ndarray:
        if self.turn is None:
            return x + self.shift
        return (self.centre + self.shift) + (x - self.centre) @ self.turn.T

    def velocity_at(self, x_new: np.ndarray) -> np.ndarray:
        """Velocity of a body point at its new position."""
        if self.omega is None:
            return self.velocity.copy()
        return self.velocity + np.cross(self.omega, x_new - (self.centre + self.shift))

    def motion(self, m: Motion | None) -> Motion | None:
        if m is None or m.rotation_centre is None:
            return m
        return dataclasses.replace(m, rotation_centre=m.rotation_centre + self.shift)


def _move(name: str, motion: Motion | None, velocity: np.ndarray, t0: float,
          t: float) -> _Move:
    dt = t - t0
    if motion is not None and motion.trajectory is not None:
        traj = motion.trajectory
        if not covers(traj, t):
            raise ArgumentError(f"lies outside the trajectory of {name} ({traj[0, 0]:g} "
                                f"to {traj[-1, 0]:g} s)", argument="t", value=t)
        shift = trajectory_position(traj, t) - trajectory_position(traj, t0)
        vel = trajectory_velocity(traj, t)
    else:
        shift = np.asarray(velocity, np.float64) * dt
        vel = np.asarray(velocity, np.float64).copy()
    move = _Move(shift=shift, velocity=vel)
    if motion is not None and motion.angular_velocity_deg_s is not None:
        move.omega = motion.angular_velocity
        move.centre = motion.rotation_centre
        if dt != 0.0:
            move.turn = rotation_matrix(move.omega, dt)
    return move


def _euler_deg(rotation: np.ndarray) -> np.ndarray:
    """[roll, pitch, yaw] (deg) of R = Rz(yaw) Ry(pitch) Rx(roll) (extrinsic x-y-z)."""
    return Rotation.from_matrix(rotation).as_euler("xyz", degrees=True) + 0.0


def scene_at(scene: Scene, t: float) -> Scene:
    """The scene moved from its time ``scene.time_s`` to ``t`` (s): triangles, object
    poses and velocities, radars (those riding on objects follow them), rotation
    centres. Objects and radars that do not move keep their arrays bit for bit; at
    ``t == scene.time_s`` nothing changes. A ``t`` outside a trajectory's span is an
    :class:`~clradcom.errors.ArgumentError` naming ``t``."""
    if not isinstance(scene, Scene):
        raise ArgumentTypeError("must be a Scene (clradcom.scene.load_scene)",
                                argument="scene", value=scene)
    if isinstance(t, bool) or not isinstance(t, int | float | np.integer | np.floating) \
            or not math.isfinite(float(t)):
        raise ArgumentError("must be a finite time in seconds", argument="t", value=t)
    t = float(t)
    t0 = float(scene.time_s)
    moves = [_move(f"objects[{i}] ({o.name})", o.motion, o.velocity, t0, t)
             for i, o in enumerate(scene.objects)]
    triangles = scene.triangles.copy()
    objects: list[SceneObject] = []
    for o, mv in zip(scene.objects, moves, strict=True):
        sl = o.tri_slice
        if mv.turn is not None or np.any(mv.shift != 0):
            triangles[sl] = mv.points(scene.triangles[sl].reshape(-1, 3)).reshape(-1, 3, 3)
        rotation = o.rotation if mv.turn is None else mv.turn @ o.rotation
        objects.append(dataclasses.replace(
            o, position=mv.points(o.position[None])[0], rotation=rotation,
            rotation_deg=o.rotation_deg if mv.turn is None else _euler_deg(rotation),
            velocity=mv.velocity, motion=mv.motion(o.motion)))
    radars: list[Radar] = []
    for i, r in enumerate(scene.radars):
        if r.rides_on >= 0:
            mv = moves[r.rides_on]
        else:  # a radar's velocity is that of its point: take the turn out of it
            v = r.velocity
            if r.motion is not None and r.motion.angular_velocity_deg_s is not None:
                v = v - np.cross(r.motion.angular_velocity,
                                 r.position - r.motion.rotation_centre)
            mv = _move(f"radars[{i}] ({r.name})", r.motion, v, t0, t)
        pos = mv.points(r.position[None])[0]
        radars.append(dataclasses.replace(
            r, position=pos,
            orientation=r.orientation if mv.turn is None else mv.turn @ r.orientation,
            velocity=mv.velocity_at(pos),
            motion=r.motion if r.rides_on >= 0 else mv.motion(r.motion)))
    return dataclasses.replace(
        scene, objects=objects, radars=radars, triangles=triangles,
        object_velocity=np.array([o.velocity for o in objects],
                                 dtype=np.float64).reshape(-1, 3), time_s=t)
