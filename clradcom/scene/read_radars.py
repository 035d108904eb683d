"""The ``[[radars]]`` entries of a scene file -> :class:`Radar` records: pose (in the
world, or in the frame of the object it ``rides_on``), velocity, role, power, noise
figure, pattern and polarisation, and the radar's own waveform where it has one."""

from __future__ import annotations

import difflib
from pathlib import Path

import numpy as np

from clradcom.scene.antenna import euler_deg_to_matrix
from clradcom.scene.bounds import (
    NOISE_FIGURE_MAX_DB,
    TX_POWER_MAX_W,
    check_coordinates,
    check_speed,
)
from clradcom.scene.fields import FieldReader
from clradcom.scene.motion import (
    MOTION_KEYS,
    read_motion,
    trajectory_position,
    trajectory_velocity,
)
from clradcom.scene.read_arrays import read_arrays
from clradcom.scene.read_patterns import read_pattern
from clradcom.scene.read_waveform import read_waveform_table
from clradcom.scene.records import ROLES, Radar, SceneObject

__all__ = ["RADAR_KEYS", "read_radars"]

RADAR_KEYS = ("name", "position", "rides_on", "orientation_deg", "velocity", "pattern",
              "polarization", "role", "tx_power_w", "noise_figure_db", "description",
              "array", "tx_array", "rx_array", "waveform", *MOTION_KEYS)


def read_radars(fields: FieldReader, entries: list, objects: list[SceneObject],
                base_dir: Path, wavelength_m: float | None = None,
                span=(0.0, 0.0)) -> list[Radar]:
    """Radars in file order; ``objects`` are the ones they may ride on; ``wavelength_m``
    (the scene's carrier) scales array spacings given in wavelengths; ``span`` is the first
    and last instant traced (trajectories must cover it; poses are at the first)."""
    seen: dict = {}
    return [_read_radar(fields, f"radars[{i}]", tbl, seen, objects, base_dir, wavelength_m,
                        span)
            for i, tbl in enumerate(entries)]


def _read_radar(fields, kp, tbl, seen, objects, base_dir, wavelength_m,
                span=(0.0, 0.0)) -> Radar:
    fields.check_keys(tbl, RADAR_KEYS, kp)
    name = fields.unique_name(tbl, kp, seen, "radar")
    motion = None
    if "rides_on" in tbl:
        for key in MOTION_KEYS:
            if key in tbl:
                raise fields.err(f"{kp}.{key}", tbl[key], "a radar that rides_on an object "
                                 f"moves with it; remove {key} (set it on the object)")
    if "trajectory" in tbl and "rides_on" not in tbl:
        motion = read_motion(fields, tbl, kp, None, span)  # refuses position and velocity
        pos_local = trajectory_position(motion.trajectory, span[0])
    else:
        pos_local = fields.get_vec3(tbl, "position", kp, unit="m")
        if "rides_on" not in tbl:
            motion = read_motion(fields, tbl, kp, pos_local, span)
    ori_deg = fields.get_vec3(tbl, "orientation_deg", kp, default=(0.0, 0.0, 0.0),
                              unit="deg")
    r_local = euler_deg_to_matrix(ori_deg)
    if "rides_on" in tbl:
        rides = _mount_object(fields, tbl, kp, objects)
        obj = objects[rides]
        position = obj.position + obj.rotation @ pos_local
        orientation = obj.rotation @ r_local
        velocity = obj.velocity.copy()
        if obj.motion is not None and obj.motion.angular_velocity_deg_s is not None:
            velocity = velocity + np.cross(obj.motion.angular_velocity,
                                           position - obj.motion.rotation_centre)
    else:
        rides = -1
        position = pos_local
        orientation = r_local
        velocity = fields.get_vec3(tbl, "velocity", kp, default=(0.0, 0.0, 0.0), unit="m/s")
        if "velocity" in tbl:
            check_speed(fields, velocity, tbl["velocity"], f"{kp}.velocity")
        if motion is not None and motion.trajectory is not None:
            velocity = trajectory_velocity(motion.trajectory, span[0])
        if motion is not None and motion.angular_velocity_deg_s is not None:
            velocity = velocity + np.cross(motion.angular_velocity,
                                           position - motion.rotation_centre)
    check_coordinates(fields, position[None, :], f"{kp}.position",
                      tbl.get("position", tbl.get("trajectory")),
                      "the radar's position" + (" on its object" if rides >= 0 else ""))
    role = fields.get_str(tbl, "role", kp, default="txrx", choices=ROLES)
    power = fields.get_float(tbl, "tx_power_w", kp, default=1.0, lo=0.0, unit="W")
    if power > TX_POWER_MAX_W:
        raise fields.err(f"{kp}.tx_power_w", tbl["tx_power_w"],
                         f"must be <= {TX_POWER_MAX_W:g} W (a terawatt, far above any "
                         "transmitter built)")
    nf = fields.get_float(tbl, "noise_figure_db", kp, default=None, unit="dB")
    if nf is not None and nf < 0:
        raise fields.err(f"{kp}.noise_figure_db", tbl["noise_figure_db"],
                         "must be >= 0 dB: a noise figure F = SNR_in / SNR_out is at "
                         "least 1 (0 dB, a noiseless receiver) by definition")
    if nf is not None and nf > NOISE_FIGURE_MAX_DB:
        raise fields.err(f"{kp}.noise_figure_db", tbl["noise_figure_db"],
                         f"must be <= {NOISE_FIGURE_MAX_DB:g} dB (real receivers have "
                         "0-20 dB)")
    pattern, pol, pol_name = read_pattern(fields, tbl, kp, base_dir)
    tx_array, rx_array = read_arrays(fields, tbl, kp, wavelength_m, base_dir)
    # the radar's own frame, over the scene's [waveform] (docs/scene-format.md)
    waveform = (read_waveform_table(fields, tbl["waveform"], f"{kp}.waveform")
                if "waveform" in tbl else None)
    return Radar(
        name=name, position=np.asarray(position, dtype=np.float64), rides_on=rides,
        orientation=orientation, pattern=pattern, polarization=pol,
        polarization_name=pol_name, velocity=velocity, role=role, tx_power_w=power,
        noise_figure_db=nf, position_local=pos_local, orientation_deg=ori_deg,
        tx_array=tx_array, rx_array=rx_array, motion=motion, waveform=waveform,
    )


def _mount_object(fields, tbl, kp, objects) -> int:
    """Index of the object named by ``rides_on``; a riding radar must not give velocity."""
    names = [o.name for o in objects]
    obj_name = fields.get_str(tbl, "rides_on", kp)
    if obj_name not in names:
        close = difflib.get_close_matches(obj_name, names, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise fields.err(f"{kp}.rides_on", obj_name,
                         f"no object with this name{hint}; objects: "
                         f"{', '.join(names) if names else '(none)'}")
    if "velocity" in tbl:
        raise fields.err(f"{kp}.velocity", tbl["velocity"],
                         "a radar that rides_on an object moves with it; remove "
                         "velocity (set it on the object)")
    return names.index(obj_name)
