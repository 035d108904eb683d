"""The whole specular tracer (kernels + image method + fields) against closed forms.

Every scene goes through ``trace_scene(scene_from_dict(...))``: OpenCL candidate
search, float64 image method, ray-cast confirmation and the field physics.
Reference numbers: docs/reference/propagation-physics.md (§1 Fresnel,
§1 monostatic sigma_eq = pi R^2, §4 Doppler, §6.1-6.2, §6.7 polarimetric corners,
§6.8 Brewster).  Conventions (clradcom/em.py): M = [[VV, VH], [HV, HH]]; for a
monostatic radar this is the backscatter-alignment basis (PEC plate -I); two
antennas facing each other have opposite phi-hat, so an H-H line of sight is
-lambda/(4 pi d) e^{-jkd}.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from clradcom.mechanisms.common import build_geometry
from clradcom.physics.em import C0
from clradcom.scene.antenna import euler_deg_to_matrix
from clradcom.scene.reader import scene_from_dict
from clradcom.snapshot import assert_snapshot_equal, load_snapshot, save_snapshot
from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings, trace_scene

F_C = 24e9
LAM = C0 / F_C
K0 = 2 * np.pi / LAM
CANONICAL = Path(__file__).resolve().parent.parent / "scenes" / "canonical"
ROAD = {"name": "road", "base": "concrete_road", "roughness_m": 0.0}  # smooth 5 - j0.1
ETA_ROAD = 5.0 - 0.1j
FACING_MINUS_X = [0.0, 0.0, 180.0]


# ---------------------------------------------------------------------------
# helpers


def scene_dict(objects=(), radars=(), materials=()):
    data = {"scene": {"name": "t", "carrier_hz": F_C}, "objects": list(objects),
            "radars": list(radars)}
    if materials:
        data["materials"] = list(materials)
    return data


def radar(name, position, role="txrx", **kw):
    return {"name": name, "role": role, "position": [float(x) for x in position], **kw}


def plane(name, material, size, position=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0), **kw):
    return {"name": name, "material": material, "shape": "plane",
            "size": [float(s) for s in size], "position": [float(x) for x in position],
            "rotation_deg": [float(a) for a in rotation], **kw}


def box(name, material, extents, position, **kw):
    return {"name": name, "material": material, "shape": "box",
            "extents": [float(e) for e in extents], "position": [float(x) for x in position],
            **kw}


def trace(data, order=1, rays=20_000, los=True, runtime=None, base_dir="."):
    scene = scene_from_dict(data, base_dir=base_dir)
    # specular paths only: these tests check reflections against closed forms
    settings = TraceSettings(
        specular=SpecularSettings(max_reflections=order, rays=rays, line_of_sight=los),
        diffraction=DiffractionSettings(max_diffractions=0))
    return trace_scene(scene, settings, runtime=runtime)


def link_paths(data, **kw):
    snap = trace(data, **kw)
    assert len(snap.links) == 1
    return snap.links[0].paths


def spreading(length):
    """The free-space factor of a path of unfolded length L: lambda/(4 pi L) e^{-jkL}."""
    return LAM / (4 * np.pi * length) * np.exp(-1j * K0 * length)


def fresnel(eta, cos_t):
    """Independent closed form: r_perp (TE), r_par (TM) in the Sionna / em.py basis."""
    a = np.sqrt(eta - (1 - cos_t**2))
    return (cos_t - a) / (cos_t + a), (eta * cos_t - a) / (eta * cos_t + a)


def two_ray_dict(d, pol, h_t=0.5, h_r=0.5, material="road", materials=(ROAD,),
                 offset=(0.0, 0.0, 0.0), size=(200.0, 20.0)):
    o = np.asarray(offset, dtype=float)
    return scene_dict(
        objects=[plane("ground", material, size, position=o + [d / 2, 0, 0])],
        radars=[radar("tx", o + [0, 0, h_t], role="tx", polarization=pol),
                radar("rx", o + [d, 0, h_r], role="rx", polarization=pol,
                      orientation_deg=FACING_MINUS_X)],
        materials=materials)


def two_ray_closed_form(d, h_t, h_r, eta):
    """(L_los, L_ref, cos_theta, r_te, r_tm) of a flat ground with tx/rx heights h_t, h_r."""
    l_ref = math.hypot(d, h_t + h_r)
    l_los = math.hypot(d, h_t - h_r)
    cos_t = (h_t + h_r) / l_ref
    r_te, r_tm = fresnel(eta, cos_t)
    return l_los, l_ref, cos_t, r_te, r_tm


def split(paths):
    """(LOS index, index of the single-reflection path) of a two-ray result."""
    n = np.asarray(paths.n_interactions)
    assert sorted(n.tolist()) == [0, 1], n
    return int(np.flatnonzero(n == 0)[0]), int(np.flatnonzero(n == 1)[0])


def face_sequences(snapshot_paths, tri_face):
    """Set of planar-face sequences (tuples) of a Paths object."""
    out = []
    for i in range(len(snapshot_paths)):
        k = int(snapshot_paths.n_interactions[i])
        out.append(tuple(int(tri_face[t]) for t in snapshot_paths.face_id[i, :k]))
    return out


def sigma_eq(gain, R):
    """Equivalent monostatic RCS of an isotropic-antenna path (G_t = G_r = 1)."""
    return abs(gain) ** 2 * (4 * np.pi) ** 3 * R**4 / LAM**2


# ---------------------------------------------------------------------------
# 1. free space


@pytest.mark.parametrize("d", [1.0, 7.3, 123.4])
def test_free_space_line_of_sight(runtime, d):
    tx = np.array([0.3, -1.2, 1.7])
    u = np.array([2.0, 1.0, -0.5]) / np.linalg.norm([2.0, 1.0, -0.5])
    rx = tx + d * u
    yaw = math.degrees(math.atan2(u[1], u[0]))
    pitch = -math.degrees(math.asin(u[2]))
    # tx boresight along u, rx boresight along -u: both see the other at boresight
    data = scene_dict(radars=[
        radar("tx", tx, role="tx", orientation_deg=[0.0, pitch, yaw]),
        radar("rx", rx, role="rx", orientation_deg=[0.0, -pitch, yaw + 180.0])])
    p = link_paths(data, order=2, rays=1000, runtime=runtime)
    assert len(p) == 1 and p.n_interactions[0] == 0
    assert abs(p.delay_s[0] - d / C0) < 1e-15
    want = spreading(d)
    assert abs(p.gain[0] - want) < 1e-9 * abs(want)
    assert abs(p.gain[0]) == pytest.approx(LAM / (4 * np.pi * d), rel=1e-12)
    if d == 1.0:
        assert 20 * np.log10(abs(p.gain[0])) == pytest.approx(-60.05, abs=0.005)
    # VV = +1, HH = -1 (facing antennas: opposite phi-hat), no cross-pol
    np.testing.assert_allclose(p.matrix[0] / want, [[1, 0], [0, -1]], atol=1e-9)


# ---------------------------------------------------------------------------
# 2. two-ray and Brewster

TWO_RAY_DB = {  # (d, pol): |LOS + ref| / |LOS| in dB, physics reference §6.2
    (10.0, "H"): -19.37, (20.0, "H"): -26.04, (50.0, "H"): 1.30,
    (10.0, "V"): -7.90, (20.0, "V"): -13.04, (50.0, "V"): 0.99,
}


@pytest.mark.parametrize(("d", "pol"), sorted(TWO_RAY_DB))
def test_two_ray_smooth_road(runtime, d, pol):
    p = link_paths(two_ray_dict(d, pol), order=1, rays=20_000, runtime=runtime)
    i_los, i_ref = split(p)
    ratio_db = 20 * np.log10(abs(p.gain.sum()) / abs(p.gain[i_los]))
    assert ratio_db == pytest.approx(TWO_RAY_DB[d, pol], abs=0.005)

    l_los, l_ref, _, r_te, r_tm = two_ray_closed_form(d, 0.5, 0.5, ETA_ROAD)
    assert abs(p.delay_s[i_los] - l_los / C0) < 1e-15
    assert abs(p.delay_s[i_ref] - l_ref / C0) < 1e-15
    np.testing.assert_allclose(p.points[i_ref, 1], [d / 2, 0, 0], atol=1e-12)
    # the reflected path relative to the line of sight: r (L_los/L_ref) e^{-jk(L_ref-L_los)}
    r = r_te if pol == "H" else r_tm
    want_ratio = r * l_los / l_ref * np.exp(-1j * K0 * (l_ref - l_los))
    got_ratio = p.gain[i_ref] / p.gain[i_los]
    assert abs(got_ratio - want_ratio) < 1e-9
    if pol == "V":  # absolute values: theta-hat of both ends agree along both paths
        assert abs(p.gain[i_los] - spreading(l_los)) < 1e-9 * abs(spreading(l_los))
        assert abs(p.gain[i_ref] - r_tm * spreading(l_ref)) < 1e-9 * abs(spreading(l_ref))
    else:  # H-H: opposite phi-hat of facing antennas flips both paths alike
        assert abs(p.gain[i_los] + spreading(l_los)) < 1e-9 * abs(spreading(l_los))
        assert abs(p.gain[i_ref] + r_te * spreading(l_ref)) < 1e-9 * abs(spreading(l_ref))


def test_two_ray_unequal_heights_delays_and_gains(runtime):
    d, h_t, h_r = 13.7, 0.35, 1.4
    p = link_paths(two_ray_dict(d, "V", h_t=h_t, h_r=h_r), order=1, runtime=runtime)
    i_los, i_ref = split(p)
    l_los, l_ref, _, _, r_tm = two_ray_closed_form(d, h_t, h_r, ETA_ROAD)
    assert abs(p.delay_s[i_los] - l_los / C0) < 1e-15
    assert abs(p.delay_s[i_ref] - l_ref / C0) < 1e-15
    # specular point at d h_t / (h_t + h_r)
    np.testing.assert_allclose(p.points[i_ref, 1], [d * h_t / (h_t + h_r), 0, 0], atol=1e-12)
    # tx and rx theta-hat at the two ends of a tilted LOS still coincide for V
    assert abs(p.gain[i_ref] / p.gain[i_los]
               - r_tm * l_los / l_ref * np.exp(-1j * K0 * (l_ref - l_los))) < 1e-9


def test_brewster_angle_kills_tm_not_te(runtime):
    eps = 5.0
    brewster = math.atan(math.sqrt(eps))  # 65.905 deg
    assert math.degrees(brewster) == pytest.approx(65.905, abs=1e-3)
    h = 1.0
    d = 2 * h * math.tan(brewster)  # equal heights: incidence angle atan(d / 2h)
    lossless = {"name": "lossless", "eps_r": eps, "roughness_m": 0.0}
    out = {}
    for pol in ("V", "H"):
        p = link_paths(two_ray_dict(d, pol, h_t=h, h_r=h, material="lossless",
                                    materials=(lossless,), size=(20.0, 20.0)),
                       order=1, runtime=runtime)
        i_los, i_ref = split(p)
        l_ref = math.hypot(d, 2 * h)
        out[pol] = p.gain[i_ref] / spreading(l_ref)  # the effective reflection coefficient
        # the reflected path itself is found and confirmed in both polarisations
        np.testing.assert_allclose(p.points[i_ref, 1], [d / 2, 0, 0], atol=1e-12)
    assert abs(out["V"]) < 1e-3  # TM: the Brewster zero (|r_par| < 1e-3 of a full reflection)
    assert abs(out["V"]) < 1e-9  # ... in fact exact up to float64 geometry
    # TE at the Brewster angle of eps = 5: r_perp = (c - a)/(c + a) = (1 - 5)/(1 + 5) = -2/3
    assert -out["H"] == pytest.approx(-2.0 / 3.0, abs=1e-9)
    # one degree away the TM reflection is back (|r_par| = 0.018)
    d_off = 2 * h * math.tan(brewster - math.radians(1.0))
    p = link_paths(two_ray_dict(d_off, "V", h_t=h, h_r=h, material="lossless",
                                materials=(lossless,), size=(20.0, 20.0)),
                   order=1, runtime=runtime)
    _, i_ref = split(p)
    _, r_tm = fresnel(eps, math.cos(brewster - math.radians(1.0)))
    assert abs(r_tm) > 0.015
    assert abs(p.gain[i_ref] / spreading(math.hypot(d_off, 2 * h)) - r_tm) < 1e-9


# ---------------------------------------------------------------------------
# 3. float64 delays and phases far from the origin


OFFSETS = [(0.0, 0.0, 0.0), (1000.0, 0.0, 0.0), (0.0, -1000.0, 0.0), (731.25, 689.5, 0.0),
           (-2500.0, 1800.0, 120.0), (0.0, 0.0, 1000.0)]


@pytest.mark.parametrize("offset", OFFSETS, ids=lambda o: "_".join(f"{x:g}" for x in o))
def test_delays_and_phases_translation_invariant(runtime, offset):
    d = 20.0
    p = link_paths(two_ray_dict(d, "V", offset=offset), order=1, runtime=runtime)
    i_los, i_ref = split(p)
    l_los, l_ref, _, _, r_tm = two_ray_closed_form(d, 0.5, 0.5, ETA_ROAD)
    # float32 kernels only propose and confirm; the numbers come from float64
    assert abs(p.delay_s[i_los] - l_los / C0) < 1e-12
    assert abs(p.delay_s[i_ref] - l_ref / C0) < 1e-12
    assert abs(p.delay_s[i_ref] - l_ref / C0) < 1e-15  # in fact to a femtosecond
    np.testing.assert_allclose(p.points[i_ref, 1], np.asarray(offset) + [d / 2, 0, 0],
                               rtol=0, atol=1e-9)
    # the same phases as at the origin (k L to 1e-6 rad: 2 nm of path length)
    phase_err_los = np.angle(p.gain[i_los] / spreading(l_los))
    phase_err_ref = np.angle(p.gain[i_ref] / (r_tm * spreading(l_ref)))
    assert abs(phase_err_los) < 1e-6 and abs(phase_err_ref) < 1e-6


# ---------------------------------------------------------------------------
# 4. PEC plate: sigma_eq = pi R^2, one path per planar face


@pytest.mark.parametrize("R", [5.0, 10.0, 20.0])
def test_pec_plate_monostatic_sigma_eq(runtime, R):
    data = tomllib.loads((CANONICAL / "plate.toml").read_text())
    data["objects"][0]["position"] = [R, 0.0, 0.0]
    p = link_paths(data, order=3, rays=30_000, runtime=runtime)
    assert len(p) == 1 and p.n_interactions[0] == 1
    assert abs(p.delay_s[0] - 2 * R / C0) < 1e-15
    np.testing.assert_allclose(p.points[0, 1], [R, 0, 0], atol=1e-12)
    assert sigma_eq(p.gain[0], R) == pytest.approx(np.pi * R**2, rel=1e-9)
    if R == 10.0:
        assert 20 * np.log10(abs(p.gain[0])) == pytest.approx(-86.07, abs=0.005)
    # backscatter alignment: a plate is -I
    np.testing.assert_allclose(p.matrix[0] / spreading(2 * R), -np.eye(2), atol=1e-9)


def grid_plate(n, size, flip_every_other=True):
    """An n x n grid of squares (2 n^2 triangles) on the local yz plane, centred on the
    origin, windings alternating so the triangle normals point both ways."""
    s = np.linspace(-size / 2, size / 2, n + 1)
    verts = [[0.0, float(y), float(z)] for z in s for y in s]
    faces = []
    for j in range(n):
        for i in range(n):
            a, b = j * (n + 1) + i, j * (n + 1) + i + 1
            c, d = a + n + 1, b + n + 1
            tris = [[a, b, d], [a, d, c]]
            if flip_every_other and (i + j) % 2:
                tris = [[a, d, b], [a, c, d]]
            faces += tris
    return verts, faces


@pytest.mark.parametrize(("rotation", "radar_offset"), [
    ((0.0, 0.0, 0.0), (0.0, 0.0)),  # specular point on a vertex shared by 8 triangles
    ((0.0, 0.0, 0.0), (0.0625, 0.0)),  # ... on an edge between two triangles
    ((17.0, -23.0, 41.0), (0.013, -0.0271)),  # tilted: float rounding off the plane
])
def test_tessellated_plate_is_one_reflector(runtime, rotation, radar_offset):
    R, n = 8.0, 8
    verts, faces = grid_plate(n, 1.0)
    rot = euler_deg_to_matrix(rotation)
    centre = np.array([R, 0.3, -0.2])
    normal = rot @ [1.0, 0.0, 0.0]
    # radar on the plate's normal through a local point (0, oy, oz): specular point there
    spec = centre + rot @ [0.0, *radar_offset]
    pos = spec - R * normal
    data = scene_dict(
        objects=[{"name": "plate", "material": "metal", "shape": "triangles",
                  "vertices": verts, "faces": faces, "position": centre.tolist(),
                  "rotation_deg": list(rotation)}],
        radars=[radar("radar", pos)])
    scene = scene_from_dict(data)
    assert len(scene.triangles) == 2 * n * n
    assert build_geometry(scene, runtime).faces.n_faces == 1
    p = trace(data, order=2, rays=50_000, runtime=runtime).links[0].paths
    # 128 coplanar triangles, rays hitting many of them: still one reflection path
    assert len(p) == 1, p.face_id
    assert p.n_interactions[0] == 1
    np.testing.assert_allclose(p.points[0, 1], spec, atol=1e-9)
    assert abs(p.delay_s[0] - 2 * R / C0) < 1e-15
    assert sigma_eq(p.gain[0], R) == pytest.approx(np.pi * R**2, rel=1e-9)


def test_two_triangle_plane_reflection_on_its_diagonal(runtime):
    """The specular point on the shared diagonal of a `plane` shape's two triangles."""
    data = scene_dict(objects=[plane("p", "metal", (2.0, 2.0), (6.0, 0.0, 0.0),
                                     (0.0, -90.0, 0.0))],
                      radars=[radar("radar", (0.0, 0.0, 0.0))])
    for rays in (2_000, 20_000, 200_000):
        p = link_paths(data, order=3, rays=rays, runtime=runtime)
        assert len(p) == 1 and p.n_interactions[0] == 1
        assert sigma_eq(p.gain[0], 6.0) == pytest.approx(np.pi * 36.0, rel=1e-9)


# ---------------------------------------------------------------------------
# 5. dihedral and trihedral: orders 2 and 3, polarimetric signatures


def canonical_bistatic(name, separation, scale=1.0, distance=None, roll=None):
    """A canonical corner scene with the radar split into tx and rx `separation` metres
    apart (exactly monostatic corner paths pass through the crease / apex, which is a
    degenerate path the image method rightly refuses)."""
    data = tomllib.loads((CANONICAL / f"{name}.toml").read_text())
    obj = data["objects"][0]
    obj["scale"] = scale
    if roll is not None:
        obj["rotation_deg"] = [roll, 0.0, 0.0]
    if distance is not None:
        obj["position"] = [distance, 0.0, 0.0]
    return data, obj


def split_radar(data, offset):
    e = np.asarray(offset, dtype=float) / 2
    data["radars"] = [radar("tx", e, role="tx"), radar("rx", -e, role="rx")]
    return data


def normalised_matrix(p, i):
    return p.matrix[i] / spreading(p.delay_s[i] * C0)


def dihedral_dict(separation, roll=0.0):
    data, _ = canonical_bistatic("dihedral", separation, scale=3.0, distance=6.0, roll=roll)
    r = math.radians(roll)
    # the offset must be across the crease (crease along (0, -sin r, cos r))
    return split_radar(data, separation * np.array([0.0, math.cos(r), math.sin(r)]))


def test_dihedral_order_two_signature(runtime):
    data = dihedral_dict(0.02)
    p = link_paths(data, order=3, rays=100_000, runtime=runtime)
    n = np.asarray(p.n_interactions)
    assert sorted(n.tolist()) == [0, 2], n  # LOS and exactly one double bounce
    i = int(np.flatnonzero(n == 2)[0])
    # the two bounces are on the two plates: the 90 deg dihedral retro-reflects,
    # the unfolded length is |rx - (tx rotated 180 deg about the crease)|
    crease = np.array([6.0, 0.0, 0.0])
    image = 2 * crease - np.array([0.0, 0.01, 0.0])
    image[2] = 0.0
    L = np.linalg.norm(image - [0.0, -0.01, 0.0])
    assert abs(p.delay_s[i] - L / C0) < 1e-15
    assert len({int(o) for o in p.object_id[i, :2]}) == 1
    faces = build_geometry(scene_from_dict(data), runtime).faces.tri_face
    seq = face_sequences(p, faces)[i]
    assert seq[0] != seq[1]
    # crease vertical (parallel to V): E along the crease is tangential to both plates,
    # reversed twice -> VV = +1; H is reversed -> HH = -1.  A plate is -I (BSA basis),
    # so the dihedral is diag(+1, -1): HH = -VV.
    M = normalised_matrix(p, i)
    np.testing.assert_allclose(M, [[1, 0], [0, -1]], atol=2e-3)
    assert abs(M[0, 0] + M[1, 1]) < 1e-3  # HH = -VV
    # dihedral RCS with isotropic antennas: sigma_eq = pi (L/2)^2 like a plate
    assert sigma_eq(p.gain[i], L / 2) == pytest.approx(np.pi * (L / 2) ** 2, rel=1e-9)


def test_dihedral_horizontal_crease_and_rolled_45(runtime):
    p = link_paths(dihedral_dict(0.02, roll=90.0), order=2, rays=100_000, runtime=runtime)
    i = int(np.flatnonzero(np.asarray(p.n_interactions) == 2)[0])
    # crease horizontal: now H is along the crease -> diag(-1, +1)
    np.testing.assert_allclose(normalised_matrix(p, i), [[-1, 0], [0, 1]], atol=2e-3)
    p = link_paths(dihedral_dict(0.02, roll=45.0), order=2, rays=100_000, runtime=runtime)
    n = np.asarray(p.n_interactions)
    assert sorted(n.tolist()) == [0, 2], n
    M = normalised_matrix(p, int(np.flatnonzero(n == 2)[0]))
    # rolled 45 deg: pure cross-pol, |VH| = |HV| = 1, VV = HH = 0
    assert abs(M[0, 0]) < 2e-3 and abs(M[1, 1]) < 2e-3
    assert abs(M[0, 1]) == pytest.approx(1.0, abs=1e-6)
    assert abs(M[1, 0]) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize("offset_dir", [(0.0, 0.0, 1.0), (0.0, 0.6, 0.8)])
def test_trihedral_order_three_signature(runtime, offset_dir):
    data, _ = canonical_bistatic("corner", 0.02, scale=3.0, distance=6.0)
    data = split_radar(data, 0.02 * np.asarray(offset_dir))
    p = link_paths(data, order=3, rays=100_000, runtime=runtime)
    n = np.asarray(p.n_interactions)
    assert sorted(n.tolist()) == [0, 3], n  # LOS and exactly one triple bounce
    i = int(np.flatnonzero(n == 3)[0])
    faces = build_geometry(scene_from_dict(data), runtime).faces.tri_face
    seq = face_sequences(p, faces)[i]
    assert len(set(seq)) == 3  # all three plates, once each
    # a trihedral retro-reflects through its apex: L = |rx - (2 apex - tx)|
    apex = np.array([6.0, 0.0, 0.0])
    tx = 0.01 * np.asarray(offset_dir)
    L = np.linalg.norm((2 * apex - tx) - (-tx))
    assert abs(p.delay_s[i] - L / C0) < 1e-15
    # three reversals: +I in the backscatter-alignment basis
    np.testing.assert_allclose(normalised_matrix(p, i), np.eye(2), atol=2e-3)


# ---------------------------------------------------------------------------
# 6. mirror-order loops


def test_parallel_walls_mirror_order_loops(runtime):
    a, b = 3.0, 4.5  # wall A at x = -a, wall B at x = +b
    walls = [plane("A", "metal", (20.0, 20.0), (-a, 0.0, 0.0), (0.0, 90.0, 0.0)),
             plane("B", "metal", (20.0, 20.0), (b, 0.0, 0.0), (0.0, -90.0, 0.0))]
    data = scene_dict(objects=walls, radars=[radar("radar", (0.0, 0.0, 0.0))])
    p = link_paths(data, order=2, rays=20_000, runtime=runtime)
    seqs = [tuple(int(o) for o in p.object_id[i, :p.n_interactions[i]]) for i in range(len(p))]
    assert sorted(seqs) == [(0,), (0, 1), (1,), (1, 0)]
    delay = dict(zip(seqs, p.delay_s, strict=True))
    assert abs(delay[0,] - 2 * a / C0) < 1e-15
    assert abs(delay[1,] - 2 * b / C0) < 1e-15
    assert abs(delay[0, 1] - 2 * (a + b) / C0) < 1e-15
    assert delay[0, 1] == delay[1, 0]
    gain = dict(zip(seqs, p.gain, strict=True))
    # two PEC reflections, spreading over the unfolded length (image method)
    assert abs(gain[0, 1] - spreading(2 * (a + b))) < 1e-9 * abs(gain[0, 1])
    assert gain[0, 1] == pytest.approx(gain[1, 0], rel=1e-12)
    assert abs(gain[0,] + spreading(2 * a)) < 1e-9 * abs(gain[0,])  # plate: -1 (V)


def test_wedge_mirror_order_loops_bistatic(runtime):
    """Two PEC plates at 60 deg, bistatic: radar -> A -> B -> rx and -> B -> A -> rx are
    distinct paths with their own (image-method) lengths."""
    half = math.radians(30.0)
    ua = np.array([math.cos(half), math.sin(half), 0.0])  # plate A along ua from the apex
    ub = np.array([math.cos(half), -math.sin(half), 0.0])
    na = np.array([-ua[1], ua[0], 0.0])
    nb = np.array([ub[1], -ub[0], 0.0])

    def wall(name, u):
        yaw = math.degrees(math.atan2(u[1], u[0]))
        return plane(name, "metal", (10.0, 4.0), 5.0 * u, (90.0, 0.0, yaw))

    tx = np.array([3.0, 0.4, 0.1])
    rx = np.array([4.0, -0.3, -0.2])
    data = scene_dict(objects=[wall("A", ua), wall("B", ub)],
                      radars=[radar("tx", tx, role="tx"), radar("rx", rx, role="rx")])
    p = link_paths(data, order=2, rays=50_000, runtime=runtime)

    def refl(x, n):
        return x - 2 * np.dot(x, n) * n

    want = {(): np.linalg.norm(rx - tx),
            (0,): np.linalg.norm(rx - refl(tx, na)),
            (1,): np.linalg.norm(rx - refl(tx, nb)),
            (0, 1): np.linalg.norm(rx - refl(refl(tx, na), nb)),
            (1, 0): np.linalg.norm(rx - refl(refl(tx, nb), na))}
    seqs = [tuple(int(o) for o in p.object_id[i, :p.n_interactions[i]]) for i in range(len(p))]
    assert sorted(seqs) == sorted(want)
    for s, tau in zip(seqs, p.delay_s, strict=True):
        assert abs(tau - want[s] / C0) < 1e-15, s
    assert abs(want[0, 1] - want[1, 0]) > 0.01  # bistatic: genuinely different lengths


# ---------------------------------------------------------------------------
# 7. Doppler

DOPPLER_PER_MPS = 2 * F_C / C0  # 160.11 Hz per m/s


def plate_doppler(runtime, plate_v, radar_v):
    data = tomllib.loads((CANONICAL / "plate.toml").read_text())
    data["objects"][0]["velocity"] = list(plate_v)
    data["radars"][0]["velocity"] = list(radar_v)
    p = link_paths(data, order=1, rays=5_000, runtime=runtime)
    assert len(p) == 1
    return p.doppler_hz[0]


@pytest.mark.parametrize("v", [1.0, 13.3, -7.5])
def test_doppler_monostatic_plate(runtime, v):
    assert DOPPLER_PER_MPS == pytest.approx(160.11, abs=0.005)
    want = DOPPLER_PER_MPS * v  # v > 0 closing
    # plate (at +x) moving toward the radar; receding for v < 0
    assert plate_doppler(runtime, (-v, 0.0, 0.0), (0.0, 0.0, 0.0)) == pytest.approx(
        want, rel=1e-9)
    # radar moving toward a static plate: the same
    assert plate_doppler(runtime, (0.0, 0.0, 0.0), (v, 0.0, 0.0)) == pytest.approx(
        want, rel=1e-9)
    # sliding along the plate changes nothing (Fermat), closing speeds add
    assert plate_doppler(runtime, (-v, 3.0, -2.0), (v, 0.0, 0.0)) == pytest.approx(
        2 * want, rel=1e-9)


def test_doppler_bistatic_two_ray_moving_rx(runtime):
    d, h, v = 15.0, 0.5, np.array([-9.0, 2.5, 0.4])

    def two_ray(rx_pos, vel=None):
        data = two_ray_dict(d, "V")
        data["radars"][1]["position"] = list(rx_pos)
        if vel is not None:
            data["radars"][1]["velocity"] = list(vel)
        p = link_paths(data, order=1, runtime=runtime)
        i_los, i_ref = split(p)
        return p, i_los, i_ref

    rx0 = np.array([d, 0.0, h])
    p, i_los, i_ref = two_ray(rx0, v)

    def lengths(rx):
        tx = np.array([0.0, 0.0, h])
        img = tx * [1, 1, -1]
        return np.linalg.norm(rx - tx), np.linalg.norm(rx - img)

    dt = 1e-4
    lp, lm = lengths(rx0 + v * dt), lengths(rx0 - v * dt)
    fd_los = -(lp[0] - lm[0]) / (2 * dt) / LAM
    fd_ref = -(lp[1] - lm[1]) / (2 * dt) / LAM
    assert p.doppler_hz[i_los] == pytest.approx(fd_los, rel=1e-7)
    assert p.doppler_hz[i_ref] == pytest.approx(fd_ref, rel=1e-7)
    assert abs(fd_los - fd_ref) > 1.0  # the two paths are told apart
    # ... and against the tracer's own delays at displaced receiver positions
    dt = 1e-3
    pp, jl, jr = two_ray(rx0 + v * dt)
    pm, kl, kr = two_ray(rx0 - v * dt)
    fd_los_tr = -C0 * (pp.delay_s[jl] - pm.delay_s[kl]) / (2 * dt) / LAM
    fd_ref_tr = -C0 * (pp.delay_s[jr] - pm.delay_s[kr]) / (2 * dt) / LAM
    assert p.doppler_hz[i_los] == pytest.approx(fd_los_tr, rel=1e-6)
    assert p.doppler_hz[i_ref] == pytest.approx(fd_ref_tr, rel=1e-6)


# ---------------------------------------------------------------------------
# 8. convergence with ray density


STREET_TX = np.array([0.0, -1.5, 0.6])
STREET_RX = np.array([25.0, 1.0, 1.2])


def facing_plate(name, size, position):
    """A PEC plate whose normal bisects the directions to STREET_TX and STREET_RX, so it
    has a specular tx -> plate -> rx path through its centre."""
    pos = np.asarray(position, dtype=float)
    n = sum((q - pos) / np.linalg.norm(q - pos) for q in (STREET_TX, STREET_RX))
    n /= np.linalg.norm(n)
    rot = (0.0, math.degrees(math.acos(n[2])), math.degrees(math.atan2(n[1], n[0])))
    return plane(name, "metal", size, pos, rot)


def street_dict():
    """A street canyon: road, two house rows, a car and two small signs (0.3 m at 11 m,
    0.5 m at 16 m) that a coarse ray lattice misses."""
    return scene_dict(
        objects=[
            plane("road", "concrete_road", (70.0, 24.0), (15.0, 0.0, 0.0)),
            box("house_l", "concrete_building", (50.0, 6.0, 8.0), (15.0, 9.0, 4.0)),
            box("house_r", "concrete_building", (50.0, 6.0, 8.0), (15.0, -9.0, 4.0)),
            box("car", "metal", (3.8, 1.85, 1.7), (6.0, 3.8, 0.85)),
            facing_plate("sign", (0.3, 0.3), (10.0, -4.5, 2.5)),
            facing_plate("sign2", (0.5, 0.5), (14.0, 4.0, 3.0)),
        ],
        radars=[radar("tx", STREET_TX, role="tx"), radar("rx", STREET_RX, role="rx")])


def test_path_set_converges_with_ray_density(runtime):
    data = street_dict()
    faces = build_geometry(scene_from_dict(data), runtime).faces.tri_face
    counts, sets = [], []
    for rays in (1_000, 3_000, 10_000, 30_000, 100_000, 300_000):
        p = link_paths(data, order=3, rays=rays, runtime=runtime)
        seqs = face_sequences(p, faces)
        assert len(set(seqs)) == len(seqs)  # no path twice
        counts.append(len(seqs))
        sets.append(set(seqs))
        objs = {int(o) for o in p.object_id[p.object_id >= 0]}
    # lattices of different sizes are not nested, so a sparse one may find a path a
    # slightly denser one misses; but every path any lattice finds is in the converged
    # set, and the two densest agree exactly
    assert all(s <= sets[-1] for s in sets), counts
    assert sets[-1] == sets[-2], (counts, sets[-1] ^ sets[-2])
    assert counts[0] < counts[-1]  # the coarsest lattice misses the small signs ...
    assert {4, 5} <= objs  # ... which the dense ones find
    assert counts[-1] == 13  # LOS + 5 single, 4 double, 3 triple bounces (checked to 3e6 rays)
    assert {len(s) for s in sets[-1]} == {0, 1, 2, 3}


# ---------------------------------------------------------------------------
# 9. determinism


def test_trace_is_deterministic(runtime, tmp_path):
    data = street_dict()
    a = trace(data, order=3, rays=30_000, runtime=runtime)
    b = trace(data, order=3, rays=30_000, runtime=runtime)
    assert a.total_paths > 10
    assert_snapshot_equal(a, b)
    fa = save_snapshot(tmp_path / "a.npz", a)
    fb = save_snapshot(tmp_path / "b.npz", b)
    assert fa.read_bytes() == fb.read_bytes()
    assert_snapshot_equal(load_snapshot(fa), a)


# ---------------------------------------------------------------------------
# 10. visibility: blocked line of sight, reflection point off the plate


def test_wall_blocks_line_of_sight(runtime):
    radars = [radar("tx", (0.0, 0.0, 1.0), role="tx"), radar("rx", (10.0, 0.0, 1.0), role="rx")]
    free = link_paths(scene_dict(radars=radars), order=1, runtime=runtime)
    assert len(free) == 1 and free.n_interactions[0] == 0
    wall = box("wall", "concrete_building", (0.2, 4.0, 3.0), (5.0, 0.0, 1.5))
    p = link_paths(scene_dict(objects=[wall], radars=radars), order=1, runtime=runtime)
    assert len(p) == 0
    # a wall that stops just below the line of sight does not block it (its top may add
    # a grazing reflection at x = 5 m)
    low = box("wall", "concrete_building", (0.2, 4.0, 0.99), (5.0, 0.0, 0.495))
    p = link_paths(scene_dict(objects=[low], radars=radars), order=1, runtime=runtime)
    assert 0 in np.asarray(p.n_interactions).tolist()
    for i in np.flatnonzero(np.asarray(p.n_interactions) == 1):
        np.testing.assert_allclose(p.points[i, 1], [5.0, 0.0, 0.99], atol=1e-9)


@pytest.mark.parametrize("edge", ["near", "far"])
def test_reflection_point_leaving_the_plate_drops_the_path(runtime, edge):
    d, h_t, h_r, size = 6.0, 0.8, 1.6, 1.0
    x_spec = d * h_t / (h_t + h_r)  # 2.0 m
    tx, rx = (0.0, 0.0, h_t), (d, 0.0, h_r)

    def reflected(centre_x):
        data = scene_dict(
            objects=[plane("plate", "metal", (size, size), (centre_x, 0.0, 0.0))],
            radars=[radar("tx", tx, role="tx"), radar("rx", rx, role="rx")])
        p = link_paths(data, order=1, rays=20_000, runtime=runtime)
        return [i for i in range(len(p)) if p.n_interactions[i] == 1], p

    sign = 1.0 if edge == "near" else -1.0
    # the plate edge at x_spec: centre_x = x_spec + sign * size/2
    for eps, present in ((-0.003, True), (0.003, False), (-0.05, True), (0.05, False)):
        refl, p = reflected(x_spec + sign * (size / 2 + eps))
        assert bool(refl) == present, (edge, eps)
        if present:
            np.testing.assert_allclose(p.points[refl[0], 1], [x_spec, 0, 0], atol=1e-12)
            assert abs(p.delay_s[refl[0]] - math.hypot(d, h_t + h_r) / C0) < 1e-15


@pytest.mark.parametrize("x0", [0.0, 100.0, 1000.0, 3000.0])
@pytest.mark.parametrize("thickness", [0.002, 0.005])
def test_thin_sheet_far_from_origin_keeps_both_sides(runtime, x0, thickness):
    """The two sides of a thin PEC sheet are two planes, wherever the sheet is (a plane
    tolerance growing with |d| once merged them into one plane between them)."""
    R = 10.0
    data = scene_dict(objects=[box("sheet", "metal", (thickness, 1.0, 1.0), (x0 + R, 0, 0))],
                      radars=[radar("radar", (x0, 0.0, 0.0))])
    assert build_geometry(scene_from_dict(data), runtime).faces.n_faces == 6
    p = link_paths(data, order=2, rays=20_000, runtime=runtime)
    assert len(p) == 1 and p.n_interactions[0] == 1
    L = 2 * (R - thickness / 2)  # off the front side
    assert abs(p.delay_s[0] - L / C0) < 1e-15
    np.testing.assert_allclose(p.points[0, 1], [x0 + R - thickness / 2, 0, 0], atol=1e-9)


def test_paths_outside_the_antenna_pattern_are_not_emitted(runtime):
    """A wall behind a forward-looking sector antenna gives no path; an isotropic one sees it."""
    def scene(pattern):
        return scene_from_dict({
            "scene": {"name": "behind", "carrier_hz": 24e9},
            "objects": [{"name": "wall", "material": "metal", "shape": "plane",
                         "size": [4.0, 4.0], "position": [-5.0, 0.0, 0.0],
                         "rotation_deg": [0.0, 90.0, 0.0]},
                        {"name": "front", "material": "metal", "shape": "plane",
                         "size": [4.0, 4.0], "position": [6.0, 0.0, 0.0],
                         "rotation_deg": [0.0, -90.0, 0.0]}],
            "radars": [{"name": "r", "position": [0.0, 0.0, 0.0], "pattern": pattern}]})

    settings = TraceSettings(specular=SpecularSettings(max_reflections=1, rays=20000),
                             diffraction=DiffractionSettings(max_diffractions=0))
    iso = trace_scene(scene("isotropic"), settings, runtime=runtime).links[0].paths
    sector = trace_scene(scene("sector"), settings, runtime=runtime).links[0].paths
    assert sorted(np.round(iso.delay_s * C0, 6)) == [10.0, 12.0]
    np.testing.assert_allclose(sector.delay_s * C0, [12.0], rtol=1e-12)
    assert np.all(sector.gain != 0)
