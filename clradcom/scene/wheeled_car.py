"""A car whose four wheels are separate, rotating objects: the micro-Doppler scene.

The rounded car of :mod:`clradcom.scene.models` has its wheels welded into one mesh, so
every point of it moves with the body. Here the body (superellipsoid body and cabin, as
in :func:`~clradcom.scene.models.car_mesh`) and one wheel mesh are separate, and the
scene places the wheel four times, each an object with the car's ``velocity`` and an
``angular_velocity_deg_s`` about its axle through ``rotation_centre`` = its hub
(docs/scene-format.md "Motion"). Rolling without slip on the road z = 0:

    omega = (z_hat x v) / r,   v_point = v + omega x (p - c)

so the contact point (p - c = -r z_hat) is at rest and the top of the tyre moves at 2v.

The wheels stand just outside the body's width (the track wider than the body, no
fenders), so a radar beside the road sees each near wheel whole: on a real car the wheel
arches hide the upper part of the wheel and with it the fastest points
(docs/microdoppler.md). The wheel is a closed, outward-wound cylinder about the local y
axis, hub at the origin: ``sections`` flat tread facets around and both side discs cut
into ``rings`` annuli, so that PO facets (one return per lit triangle, at its centroid,
with that centroid's velocity) sample the wheel from the hub out to the tread.
:func:`microdoppler_toml` writes the scene file (tools/make_microdoppler.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from clradcom.errors import ArgumentError
from clradcom.scene.models import superellipsoid

__all__ = ["WheeledCar", "body_mesh", "microdoppler_toml", "rolling_omega", "wheel_hubs",
           "wheel_mesh"]


@dataclass(frozen=True)
class WheeledCar:
    """Sizes (m) of the car body and its wheels; the car is centred on x, y with its
    nose at +x and its wheels touching z = 0."""

    length: float = 3.8
    width: float = 1.85
    height: float = 1.7
    wheel_radius: float = 0.32
    wheel_width: float = 0.22
    #: flat tread facets around a wheel
    sections: int = 48
    #: annuli of each side disc (the innermost a fan round the hub)
    rings: int = 6
    #: hub x positions (rear, front) as shares of the length
    axles: tuple[float, float] = (-0.32, 0.3)

    def __post_init__(self):
        for name in ("length", "width", "height", "wheel_radius", "wheel_width"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ArgumentError("must be a positive length in m",
                                    argument=f"WheeledCar.{name}", value=value)
        if 2 * self.wheel_radius >= self.height:
            raise ArgumentError("the wheels must be lower than the car",
                                argument="WheeledCar.wheel_radius", value=self.wheel_radius)
        for name, lo in (("sections", 3), ("rings", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise ArgumentError(f"must be a whole number >= {lo}",
                                    argument=f"WheeledCar.{name}", value=value)


def body_mesh(car: WheeledCar = WheeledCar()) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of the body and cabin without wheels, outward wound, in the car
    frame (the same superellipsoids as :func:`clradcom.scene.models.car_mesh`)."""
    r = car.wheel_radius
    body_h = 0.75 * car.height / 1.7
    body = superellipsoid((car.length, car.width, body_h), 20, 10, 0.25)
    body.apply_translation([0.0, 0.0, r * 0.55 + 0.5 * body_h])
    cabin_h = car.height - (r * 0.55 + body_h) + 0.08
    cabin = superellipsoid((0.55 * car.length, 0.9 * car.width, cabin_h), 14, 8, 0.35)
    cabin.apply_translation([-0.1 * car.length, 0.0, car.height - 0.5 * cabin_h])
    mesh = trimesh.util.concatenate([body, cabin])
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def wheel_mesh(car: WheeledCar = WheeledCar()) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of one wheel: a closed cylinder of ``wheel_radius`` and
    ``wheel_width`` about the local y axis, hub at the origin, wound outward; the side
    discs are a centre fan and ``rings - 1`` annuli of equal radial width."""
    n, k = car.sections, car.rings
    r, h = car.wheel_radius, 0.5 * car.wheel_width
    ang = 2 * np.pi * np.arange(n) / n
    radii = r * np.arange(1, k + 1) / k
    verts = [[0.0, -h, 0.0], [0.0, h, 0.0]]  # 0: hub at -y, 1: hub at +y
    # ring j (1..k) on side s (0: y = -h, 1: y = +h): index 2 + (s * k + j - 1) * n + i
    for y in (-h, h):
        for rad in radii:
            verts += [[rad * math.cos(a), y, rad * math.sin(a)] for a in ang]

    def idx(s, j, i):
        return 2 + (s * k + j - 1) * n + i % n

    faces = []
    # with x = cos a, z = sin a the angle turns from +x towards +z, i.e. about -y; a
    # triangle (hub, i, i+1) then has its normal along -y, outward on the side y = -h
    for s, flip in ((0, False), (1, True)):
        for i in range(n):
            tri = [s, idx(s, 1, i), idx(s, 1, i + 1)]
            faces.append(tri[::-1] if flip else tri)
            for j in range(1, k):
                a, b = idx(s, j, i), idx(s, j, i + 1)
                c, d = idx(s, j + 1, i + 1), idx(s, j + 1, i)
                for t in ([a, d, c], [a, c, b]):
                    faces.append(t[::-1] if flip else t)
    for i in range(n):  # the tread between the outer rings, normals outward:
        # (c - a) x (b - a) ~ (2h y_hat) x (angular) points away from the axis
        a, b = idx(0, k, i), idx(0, k, i + 1)
        c, d = idx(1, k, i + 1), idx(1, k, i)
        faces += [[a, c, b], [a, d, c]]
    return np.array(verts, dtype=np.float64), np.array(faces, dtype=np.int64)


def wheel_hubs(car: WheeledCar = WheeledCar()) -> np.ndarray:
    """(4, 3) hub positions in the car frame: rear left, rear right, front left, front
    right (left = +y). The wheels stand outside the body, 1 cm clear of its width."""
    y = 0.5 * car.width + 0.5 * car.wheel_width + 0.01
    return np.array([[a * car.length, sy, car.wheel_radius]
                     for a in car.axles for sy in (y, -y)], dtype=np.float64)


def rolling_omega(velocity, radius: float) -> np.ndarray:
    """Angular velocity (rad/s, (3,)) of a wheel of ``radius`` rolling without slip on a
    horizontal road at ``velocity``: (z_hat x v) / r."""
    v = np.asarray(velocity, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)) or abs(v[2]) > 1e-12 * (1 + abs(v).max()):
        raise ArgumentError("must be a finite horizontal velocity [vx, vy, 0] in m/s",
                            argument="velocity", value=velocity)
    return np.cross([0.0, 0.0, 1.0], v) / float(radius)


def _vec(xs) -> str:
    return "[" + ", ".join(f"{float(x):.10g}" for x in xs) + "]"


def microdoppler_toml(car: WheeledCar = WheeledCar(), *, start=(25.0, 3.0), speed=10.0,
                      radar_height=0.5, step_s=0.05, count=20,
                      mesh_dir: str = "meshes") -> str:
    """The micro-Doppler scene file: a radar at the origin ``radar_height`` m above the
    road looking along +x, and the car with its four rolling wheels driving towards it
    along -x at ``speed`` m/s from ``start`` = (x, y) of its centre; the ``[time]``
    table has ``count`` instants ``step_s`` apart."""
    v = np.array([-float(speed), 0.0, 0.0])
    omega_deg = np.degrees(rolling_omega(v, car.wheel_radius))
    pos = np.array([start[0], start[1], 0.0])
    hubs = pos + wheel_hubs(car) * [-1.0, -1.0, 1.0]  # the car turned 180 deg: nose at -x
    names = ("wheel_rear_left", "wheel_rear_right", "wheel_front_left", "wheel_front_right")
    lines = [
        "# Micro-Doppler of rolling wheels (written by tools/make_microdoppler.py; see",
        "# docs/microdoppler.md). A car drives towards a radar along -x in the lane beside",
        f"# it at {speed:g} m/s; its four wheels (radius {car.wheel_radius:g} m) are separate "
        "objects that",
        "# move with the car and turn about their axles at omega = v / r (rolling without",
        "# slip: the contact point at rest, the top of the tyre at 2 v).",
        "",
        "[scene]",
        'name = "car_wheels"',
        "carrier_hz = 24e9",
        'description = "a car with rolling wheels driving towards a radar (micro-Doppler)"',
        "",
        "[time]",
        "start_s = 0.0",
        f"step_s = {step_s:g}",
        f"count = {int(count)}",
        "",
        "[[objects]]",
        'name = "road"',
        'material = "concrete_road"',
        'shape = "plane"',
        "size = [60.0, 12.0]",
        "position = [15.0, 0.0, 0.0]",
        "",
        "[[objects]]",
        'name = "car"',
        'material = "metal"',
        f'mesh = "{mesh_dir}/car_body.ply"',
        f"position = {_vec(pos)}",
        "rotation_deg = [0.0, 0.0, 180.0]",
        f"velocity = {_vec(v)}",
        'optics = "both"',
    ]
    for name, hub in zip(names, hubs, strict=True):
        lines += [
            "",
            "[[objects]]",
            f'name = "{name}"',
            'material = "metal"',
            f'mesh = "{mesh_dir}/wheel.ply"',
            f"position = {_vec(hub)}",
            f"velocity = {_vec(v)}",
            f"angular_velocity_deg_s = {_vec(omega_deg)}",
            f"rotation_centre = {_vec(hub)}",
            'optics = "both"',
        ]
    lines += [
        "",
        "[[radars]]",
        'name = "radar"',
        f"position = [0.0, 0.0, {radar_height:g}]",
        "orientation_deg = [0.0, 0.0, 0.0]",
        "# +-30 deg in elevation: the road straight below (0.5 m, 70 dB above the car) unlit",
        'pattern = { type = "sector", azimuth_width_deg = 90.0, elevation_width_deg = 60.0 }',
        'polarization = "V"',
        "tx_power_w = 1.0  # the tyre tops' weak returns stay above the noise at 25 m",
        "noise_figure_db = 10.0",
        "",
    ]
    return "\n".join(lines)
