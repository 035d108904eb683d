"""The two-level BVH (clradcom.geometry.instances, InstancedCaster, GeometryCache).

The instanced traversal (kernels built with -D BVH_INSTANCED) is checked against the
single-level caster over the same world triangles (random rays, rigid transforms with
rotations), and a whole trace_series with the geometry cache against full rebuilds at
every step.
"""

from __future__ import annotations

import numpy as np
import pyopencl as cl
import pytest
from scipy.spatial.transform import Rotation

from clradcom.device import visibility
from clradcom.device.precision import kernel_float64
from clradcom.device.raycast import KERNEL_DEFINES, InstancedCaster, RayCaster, make_rays
from clradcom.errors import ArgumentError
from clradcom.geometry.instances import (
    INSTANCE_DTYPE,
    build_blas,
    instance_boxes,
    refit,
    step_head,
    tlas_nodes,
    two_level,
    world_tri4,
)
from clradcom.geometry.layout import LEAF_GROUP_BITS
from clradcom.geometry.triangles import triangle_normals
from clradcom.mechanisms.common import GeometryCache, build_geometry
from clradcom.physics.em import C0
from clradcom.scene.motion import scene_at
from clradcom.scene.reader import load_scene, scene_from_dict
from clradcom.series import trace_series
from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings, trace_scene

CANON = __import__("pathlib").Path(__file__).parent.parent / "scenes" / "canonical"


def soup(rng, n, size):
    centres = rng.uniform(-size, size, (n, 1, 3))
    return centres + rng.normal(0.0, size / 10, (n, 3, 3))


def make_parts(n_movers):
    rng = np.random.default_rng(7)
    static = soup(rng, 1500, 50.0)
    movers = [soup(rng, 800 // n_movers, 3.0) for _ in range(n_movers)]
    out = [(static, np.arange(len(static)))]
    start = len(static)
    for m in movers:
        out.append((m, np.arange(start, start + len(m))))
        start += len(m)
    return out


@pytest.fixture(scope="module")
def parts():
    """A static part and four movers: the top level is one record."""
    return make_parts(4)


def test_instance_record_matches_the_kernel_struct(runtime):
    prog = runtime.program("layout.cl", defines=KERNEL_DEFINES)
    out = np.zeros(7, dtype=np.int32)
    buf = runtime.empty(out.nbytes)
    prog.instance_layout(runtime.queue, (1,), None, buf)
    cl.enqueue_copy(runtime.queue, out, buf)
    f = INSTANCE_DTYPE.fields
    assert out.tolist() == [INSTANCE_DTYPE.itemsize, f["origin"][1], f["local_to_world"][1],
                            f["root"][1], f["identity"][1], f["first_group"][1],
                            f["end_group"][1]]


@pytest.mark.parametrize("n_movers", [4, 11])
def test_layout_shifts_codes_and_codes_instances(n_movers):
    parts = make_parts(n_movers)
    blases = [build_blas(tri, ids) for tri, ids in parts]
    lv = two_level(blases)
    assert lv.head_records == 2 * len(blases)
    assert len(lv.nodes) == lv.head_records + sum(len(b.nodes) for b in blases)
    # every tree's leaves point into its own groups, its inner children into its records
    for k, b in enumerate(blases):
        r0, g0 = int(lv.roots[k]), int(lv.group_range[k, 0])
        child = lv.nodes["child"][r0:r0 + len(b.nodes)].astype(np.int64)
        inner = child > 0
        assert np.all((child[inner] > r0) & (child[inner] < r0 + len(b.nodes)))
        packed = -child[child < 0] - 1
        first = packed >> LEAF_GROUP_BITS
        last = first + (packed & ((1 << LEAF_GROUP_BITS) - 1))
        assert first.min() >= g0 and last.max() <= lv.group_range[k, 1]
        np.testing.assert_array_equal(
            lv.slot_prim[4 * g0:4 * int(lv.group_range[k, 1])], b.slot_prim)
    # the top level: one leaf per instance, each instance once, boxes holding the parts
    lo = np.array([tri.min(axis=(0, 1)) for tri, _ in parts])
    hi = np.array([tri.max(axis=(0, 1)) for tri, _ in parts])
    lo32, hi32 = instance_boxes(lo, hi, 60.0)
    assert np.all(lo32 < lo) and np.all(hi32 > hi)
    top = tlas_nodes(lo32, hi32)
    leaves = top["child"][top["child"] < 0].astype(np.int64)
    assert sorted(((-leaves - 1) >> LEAF_GROUP_BITS).tolist()) == list(range(len(parts)))
    assert np.all((-leaves - 1) & ((1 << LEAF_GROUP_BITS) - 1) == 1)
    head = step_head(top, len(parts), np.tile(np.eye(3), (len(parts), 1, 1)),
                     np.zeros((len(parts), 3)), lv.roots, lv.group_range,
                     [True] + [False] * (len(parts) - 1))
    assert head["pad"][0, 0] == len(parts) and head["pad"][0, 1] == len(parts)
    inst = head[len(parts):].view(INSTANCE_DTYPE)
    np.testing.assert_array_equal(inst["root"], lv.roots)
    assert inst["identity"].tolist() == [1] + [0] * n_movers
    if n_movers > 8:   # a real top-level tree: every leaf box is its instance's box
        for rec in top:
            for j in np.flatnonzero(rec["child"] < 0):
                k = (-int(rec["child"][j]) - 1) >> LEAF_GROUP_BITS
                assert rec["minx"][j] == lo32[k, 0] and rec["maxz"][j] == hi32[k, 2]


def test_refit_of_an_unmoved_tree_is_the_tree_and_of_a_moved_one_bounds_it(parts):
    lv = two_level([build_blas(tri, ids) for tri, ids in parts])
    world = np.concatenate([tri for tri, _ in parts])
    for k in range(len(parts)):
        (g0, g1), r0 = lv.group_range[k], int(lv.roots[k])
        recs = lv.nodes[r0:r0 + lv.n_records[k]]
        tri4 = world_tri4(world, lv.slot_prim[4 * g0:4 * g1])
        np.testing.assert_array_equal(tri4, lv.tri4[g0:g1])
        assert refit(recs, tri4, r0, int(g0)).tobytes() == recs.tobytes()
    # moved: every leaf box holds its groups' moved vertices, every inner box its record
    rot = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    moved = world @ rot.T + np.array([5.0, -3.0, 1.0])
    (g0, g1), r0 = lv.group_range[1], int(lv.roots[1])
    tri4 = world_tri4(moved, lv.slot_prim[4 * g0:4 * g1])
    recs = refit(lv.nodes[r0:r0 + lv.n_records[1]], tri4, r0, int(g0))
    assert not np.array_equal(recs["minx"], lv.nodes[r0:r0 + lv.n_records[1]]["minx"])
    for rec in recs:
        for j, c in enumerate(rec["child"]):
            if c < 0:
                p = -int(c) - 1
                first, cnt = (p >> LEAF_GROUP_BITS) - g0, p & ((1 << LEAF_GROUP_BITS) - 1)
                xs = tri4[first:first + cnt, [0, 3, 6], :]
                assert rec["minx"][j] == xs.min() and rec["maxx"][j] == xs.max()
            elif c > 0:
                sub = recs[c - r0]
                assert rec["minz"][j] == sub["minz"].min() and rec["maxy"][j] == sub["maxy"].max()


def place_random(caster, parts, seed):
    """Rotate and move the movers at random (the first part stays): the world triangles."""
    rng = np.random.default_rng(seed)
    n = len(parts)
    rot = np.array([np.eye(3)] + [Rotation.random(random_state=seed * 10 + k).as_matrix()
                                  for k in range(1, n)])
    org = np.vstack([np.zeros(3), rng.uniform(-40.0, 40.0, (n - 1, 3))])
    world = np.concatenate([tri @ r.T + p for (tri, _), r, p in zip(parts, rot, org,
                                                                    strict=True)])
    caster.place(world, rot, org, [True] + [False] * (n - 1))
    return world


@pytest.mark.parametrize("seed, n_movers", [(1, 4), (2, 4), (3, 11)])
def test_instanced_hits_are_the_flat_bvh_hits(runtime, seed, n_movers):
    parts = make_parts(n_movers)
    caster = InstancedCaster(parts, runtime=runtime)
    world = place_random(caster, parts, seed)
    flat = RayCaster(world, runtime=runtime)
    rng = np.random.default_rng(100 + seed)
    n = 8000
    target = world[rng.integers(0, len(world), n)].mean(axis=1)
    origin = rng.uniform(-60.0, 60.0, (n, 3))
    rays = make_rays(origin, target - origin)
    a, b = flat.closest_hit(rays), caster.closest_hit(rays)
    same = a["prim"] == b["prim"]
    assert same.mean() >= 0.999
    hit = same & (a["prim"] >= 0)
    assert hit.mean() > 0.99
    moved = hit & (a["prim"] >= len(parts[0][0]))   # hits on the rotated parts
    assert moved.sum() > 100
    np.testing.assert_allclose(b["t"][hit], a["t"][hit], rtol=1e-5, atol=1e-4)
    # normals in the world frame, rotated out of the parts' frames (float32 normals of
    # small triangles: a few 1e-4 on slivers)
    cos = np.einsum("ij,ij->i", a["ng"][hit].astype(float), b["ng"][hit].astype(float))
    assert cos.min() > 1.0 - 1e-6 and np.median(np.abs(1.0 - cos)) < 1e-7
    # static-part hits are the flat hits to the bit (identity instance: the ray as is)
    # as long as no moved part is nearer: compare the same ray against a static-only pair
    short = make_rays(origin, target - origin, tmax=0.999)
    oa, ob = flat.occluded(short), caster.occluded(short)
    assert (oa == ob).mean() >= 0.999 and 0.2 < oa.mean() < 0.999
    # specular bounces walk the same faces (the world normal of a moved part reflects)
    tri_face = np.arange(len(world), dtype=np.int32)
    dirs = rng.normal(size=(2000, 3))
    sa = flat.specular_sequences(np.zeros(3), dirs, tri_face, 3)
    sb = caster.specular_sequences(np.zeros(3), dirs, tri_face, 3)
    assert (sa == sb).all(axis=1).mean() >= 0.99


def test_refit_parts_give_the_flat_hits_bit_for_bit(runtime):
    parts = make_parts(4)
    caster = InstancedCaster(parts, runtime=runtime, refit=[False] + [True] * 4)
    flat = None
    for seed in (1, 2):   # place twice: the second refit starts from the first's boxes
        world = place_random(caster, parts, seed)
        flat = RayCaster(world, runtime=runtime)
    rng = np.random.default_rng(9)
    target = world[rng.integers(0, len(world), 8000)].mean(axis=1)
    origin = rng.uniform(-60.0, 60.0, (8000, 3))
    rays = make_rays(origin, target - origin)
    a, b = flat.closest_hit(rays), caster.closest_hit(rays)
    assert a.tobytes() == b.tobytes()
    short = make_rays(origin, target - origin, tmax=0.999)
    np.testing.assert_array_equal(flat.occluded(short), caster.occluded(short))


def test_a_wrong_transform_is_seen(runtime, parts):
    """The test above could not pass with the transform ignored: the same world with
    the movers placed at the identity misses the flat BVH's hits on them."""
    caster = InstancedCaster(parts, runtime=runtime)
    world = place_random(caster, parts, 1)
    n = len(parts)
    caster.place(world, np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3)), [True] * n)
    flat = RayCaster(world, runtime=runtime)
    rng = np.random.default_rng(5)
    target = world[len(parts[0][0]):].mean(axis=1)[rng.integers(0, 800, 2000)]
    origin = rng.uniform(-60.0, 60.0, (2000, 3))
    rays = make_rays(origin, target - origin)
    assert (flat.closest_hit(rays)["prim"] == caster.closest_hit(rays)["prim"]).mean() < 0.9


def test_instanced_caster_refuses_bad_input(runtime, parts):
    caster = InstancedCaster(parts, runtime=runtime)
    rays = make_rays(np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(ArgumentError, match="place"):
        caster.closest_hit(rays)
    with pytest.raises(ArgumentError, match="exactly one part"):
        InstancedCaster([parts[0], parts[0]], runtime=runtime)
    n = len(parts)
    world = np.concatenate([tri for tri, _ in parts])
    with pytest.raises(ArgumentError, match="rotations"):
        caster.place(world, np.zeros((n - 1, 3, 3)), np.zeros((n, 3)))
    with pytest.raises(ArgumentError, match="triangles"):
        caster.place(world[1:], np.zeros((n, 3, 3)), np.zeros((n, 3)))


def spinner_doc():
    """A static wall and ground, a square plate turning about z (a rotating object with a
    rotation centre) and a box driving along x, seen by a fixed radar."""
    ground = {"name": "ground", "material": "concrete_road", "shape": "plane",
              "size": [40.0, 20.0], "position": [0.0, 0.0, 0.0]}
    wall = {"name": "wall", "material": "metal", "shape": "box",
            "extents": [20.0, 0.5, 4.0], "position": [0.0, 6.0, 2.0]}
    plate = {"name": "plate", "material": "metal", "shape": "box",
             "extents": [1.5, 0.05, 1.5], "position": [4.0, -2.0, 1.5],
             "angular_velocity_deg_s": [0.0, 0.0, 60.0], "rotation_centre": [4.0, -2.0, 1.5]}
    car = {"name": "car", "material": "metal", "shape": "box", "extents": [3.8, 1.85, 1.7],
           "position": [-6.0, 1.5, 0.85], "velocity": [8.0, 0.0, 0.0]}
    return {"scene": {"name": "spinner", "carrier_hz": 24e9},
            "objects": [ground, wall, plate, car],
            "radars": [{"name": "r", "position": [0.0, -8.0, 1.0],
                        "orientation_deg": [0.0, 0.0, 90.0], "pattern": "isotropic"}]}


GO = TraceSettings(specular=SpecularSettings(max_reflections=2, rays=100_000),
                   diffraction=DiffractionSettings(max_diffractions=1))


def assert_same_series(a, b):
    assert a.n_tracks == b.n_tracks > 0
    for name in ("link", "interaction", "object_id", "face_id", "present"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    m = a.present
    np.testing.assert_allclose(a.delay_s[m], b.delay_s[m], rtol=0, atol=1e-15)
    np.testing.assert_allclose(a.doppler_hz[m], b.doppler_hz[m], rtol=1e-9, atol=1e-9)
    assert np.max(np.abs(a.gain[m] - b.gain[m]) / np.abs(b.gain[m])) <= 1e-9


@pytest.mark.parametrize("scene_of, settings, placement", [
    (lambda: load_scene(CANON / "moving_car.toml"), TraceSettings.preset("fast"), "transform"),
    (lambda: load_scene(CANON / "moving_car.toml"), TraceSettings.preset("fast"), "refit"),
    (lambda: scene_from_dict(spinner_doc()), GO, "transform"),
    (lambda: scene_from_dict(spinner_doc()), GO, "refit"),
])
def test_series_with_the_cache_is_the_series_with_rebuilds(runtime, scene_of, settings,
                                                           placement):
    scene = scene_of()
    times = [0.0, 0.1, 0.25]
    cached = trace_series(scene, settings, times, runtime=runtime, placement=placement)
    rebuilt = trace_series(scene, settings, times, runtime=runtime, rebuild=True)
    assert_same_series(cached, rebuilt)
    # the paths really move: delays change over the steps
    moving = cached.present.all(axis=0)
    assert np.ptp(cached.delay_s[:, moving], axis=0).max() * C0 > 0.5


@pytest.mark.parametrize("placement", GeometryCache.PLACEMENTS)
def test_cache_places_instead_of_rebuilding(runtime, placement):
    scene = scene_from_dict(spinner_doc())
    cache = GeometryCache(scene, runtime, placement=placement)
    assert [scene.objects[i].name for i in cache.moving] == ["plate", "car"]
    caster = cache.caster
    assert isinstance(caster, InstancedCaster)
    g = cache.at(0.4)
    assert g.caster is caster
    # faces: the moved planes are those of a full build at t, the grouping is the first's
    full = build_geometry(scene_at(scene, 0.4), runtime)
    np.testing.assert_array_equal(g.faces.tri_face, full.faces.tri_face)
    np.testing.assert_array_equal(g.faces.normal, full.faces.normal)
    np.testing.assert_array_equal(g.faces.offset, full.faces.offset)
    np.testing.assert_array_equal(g.caster.triangles, full.caster.triangles)
    np.testing.assert_array_equal(g.caster.normals64(), full.caster.normals64())
    # the float64 device copy follows the moved parts, in the bytes the kernels read:
    # doubles, or (hi, lo) pairs without fp64 (kernel_float64)
    def on_device(buf, values):
        got = np.empty_like(kernel_float64(runtime, values))
        cl.enqueue_copy(runtime.queue, got, buf, is_blocking=True)
        return got

    g.caster.scene_data64()   # made at 0.4 s, then rewritten in place by the step to 0.8 s
    g2 = cache.at(0.8)
    want = scene_at(scene, 0.8)
    np.testing.assert_array_equal(on_device(g2.caster.scene_data64()["vertices"],
                                            want.triangles),
                                  kernel_float64(runtime, want.triangles))
    np.testing.assert_array_equal(on_device(g2.caster.scene_data64()["normals"],
                                            g2.caster.normals64()),
                                  kernel_float64(runtime, triangle_normals(want.triangles)))
    # so do the faces' boxes the visibility kernels cut by (and their float64 copy)
    g = cache.at(0.0)
    visibility.scene64_args(g.caster, g.faces.tri_face)
    g = cache.at(0.6)
    args = visibility.scene64_args(g.caster, g.faces.tri_face)
    want = visibility.face_tables(scene_at(scene, 0.6).triangles, g.faces.tri_face)
    np.testing.assert_array_equal(on_device(args[6], want["face_box"]),
                                  kernel_float64(runtime, want["face_box"]))
    assert args[0] is g.caster.scene_data64()["vertices"]
    # and antenna_blocked's shortlist of triangles near an antenna
    # (a corner of a moving triangle at 0.2 s, far from it at 0.6 s)
    ant = scene_at(scene, 0.2).triangles[-1].min(axis=0)
    assert len(visibility._boxes_near(g.caster, ant, 1e-3)) == 0
    g = cache.at(0.2)
    lo, hi = g.caster.triangle_bounds()
    want = np.flatnonzero(np.all((ant >= lo - 1e-3) & (ant <= hi + 1e-3), axis=1))
    assert len(want)
    np.testing.assert_array_equal(visibility._boxes_near(g.caster, ant, 1e-3), want)
    # a still scene gets one plain caster
    still = scene_from_dict({**spinner_doc(), "objects": spinner_doc()["objects"][:2]})
    sc = GeometryCache(still, runtime)
    assert type(sc.caster) is RayCaster and sc.at(1.0).caster is sc.caster


def test_geometry_cache_refuses_bad_input(runtime):
    with pytest.raises(ArgumentError, match="placement"):
        GeometryCache(scene_from_dict(spinner_doc()), runtime, placement="warp")
    with pytest.raises(ArgumentError, match="engine"):
        GeometryCache(scene_from_dict(spinner_doc()), runtime, engine="gpu")


def test_trace_scene_refuses_a_geometry_of_another_scene(runtime):
    scene = scene_from_dict(spinner_doc())
    cache = GeometryCache(scene, runtime)
    g = cache.at(0.1)
    with pytest.raises(ArgumentError, match="geometry"):
        trace_scene(scene, GO, runtime, geometry=g)
