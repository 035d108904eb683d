"""Specular face sequences of a launch lattice rotated on the device
(RayCaster.lattice_sequences) against the host-rotated directions' sequences; their keys'
set gathered on the device, and on the host where the device has no 64-bit atomics."""

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

from clradcom.device.raycast import RayCaster
from clradcom.device.runtime import Runtime
from clradcom.errors import ArgumentError, DeviceFallbackWarning
from clradcom.geometry.ray_order import coherent_order
from clradcom.mechanisms import specular as sp
from clradcom.mechanisms.specular import fibonacci_sphere
from clradcom.physics.vectors import orthonormal_frame
from clradcom.scene import load_scene
from clradcom.trace import DiffractionSettings, SpecularSettings, TraceSettings, trace_scene

GOLDEN = Path(__file__).resolve().parent / "data" / "all_mechanisms.toml"


def _room():
    """A closed box room with a sphere inside: rays bounce several times."""
    box = trimesh.creation.box(extents=(8.0, 6.0, 4.0))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    ball.apply_translation((1.5, 0.5, 0.0))
    return np.concatenate([box.triangles, ball.triangles]).astype(np.float64)


def test_lattice_sequences_are_the_host_rotated_rays_bit_for_bit(runtime):
    tris = _room()
    caster = RayCaster(tris, runtime=runtime)
    tri_face = np.arange(len(tris), dtype=np.int32) // 2
    local = fibonacci_sphere(5000)
    axis = np.array([0.3, -0.5, 0.81])
    axis /= np.linalg.norm(axis)
    u, v = orthonormal_frame(axis)
    rot = np.stack([axis, u, v], axis=1)   # antenna axes as columns
    origin = np.array([-1.2, 0.4, 0.3])
    dirs = local[:, :1] * rot[:, 0] + local[:, 1:2] * rot[:, 1] + local[:, 2:] * rot[:, 2]
    want = caster.specular_sequences(origin, dirs, tri_face, 4)
    # small batches: the lattice offset of each batch is used
    got = caster.lattice_sequences(origin, local, rot, tri_face, 4, batch=1234)
    np.testing.assert_array_equal(got, want)
    assert (want[:, 3] >= 0).mean() > 0.9   # closed room: most rays bounce four times
    # the kept lattice buffer serves a second rotation of the same array
    rot2 = rot[:, [1, 2, 0]]
    dirs2 = local[:, :1] * rot2[:, 0] + local[:, 1:2] * rot2[:, 1] + local[:, 2:] * rot2[:, 2]
    np.testing.assert_array_equal(caster.lattice_sequences(origin, local, rot2, tri_face, 4),
                                  caster.specular_sequences(origin, dirs2, tri_face, 4))
    assert caster.lattice_sequences(origin, local, rot, tri_face, 0).shape == (5000, 0)


def test_lattice_sequences_refuse_bad_shapes(runtime):
    caster = RayCaster(_room(), runtime=runtime)
    with pytest.raises(ArgumentError, match="local"):
        caster.lattice_sequences(np.zeros(3), np.zeros((4, 2)), np.eye(3), [0], 2)
    with pytest.raises(ArgumentError, match="rotation"):
        caster.lattice_sequences(np.zeros(3), np.zeros((4, 3)), np.eye(2), [0], 2)


def test_lattice_keys_are_the_host_keys_of_the_sequences(runtime):
    """The device's one-key-per-ray candidate search (kernels/reflect.cl:
    trace_reflection_keys_rotated) gives the host's exact keys of the same rays' face
    sequences, the cut at a repeated face included, and so the same candidates."""
    tris = _room()
    caster = RayCaster(tris, runtime=runtime)
    # faces of two triangles: a ray often re-hits a neighbour of the face it just left
    # in float32, which the keys must cut exactly as the host does
    tri_face = np.arange(len(tris), dtype=np.int32) // 2
    local = fibonacci_sphere(5000)
    rot = np.eye(3)[:, [2, 0, 1]]
    origin = np.array([-1.2, 0.4, 0.3])
    k = 5
    base = sp.key_base(int(tri_face.max()) + 1, k)
    seqs = caster.lattice_sequences(origin, local, rot, tri_face, k)
    keys = caster.lattice_keys(origin, local, rot, tri_face, k, base, batch=1234)
    np.testing.assert_array_equal(keys, sp.sequence_keys(seqs, base))
    repeats = (seqs[:, 1:] == seqs[:, :-1]) & (seqs[:, 1:] >= 0)
    assert repeats.any(axis=1).sum() > 100   # the cut is exercised
    # a key's digits are its row's faces up to the first escape or repeat
    assert np.all(keys // base ** (k - 1) - 1 == seqs[:, 0])
    got = sp.candidates_from_keys(keys, base, k)
    want = sp.unique_candidates(seqs)
    assert got.keys() == want.keys()
    for order in want:
        np.testing.assert_array_equal(got[order], want[order])
    assert len(want[k]) > 10


def test_lattice_keys_refuse_an_overflowing_base(runtime):
    caster = RayCaster(_room(), runtime=runtime)
    tri_face = np.arange(len(caster.triangles), dtype=np.int32)
    with pytest.raises(ArgumentError, match="base"):
        caster.lattice_keys(np.zeros(3), np.zeros((4, 3)), np.eye(3), tri_face, 3,
                            base=len(tri_face))   # not above every face id + 1
    with pytest.raises(ArgumentError, match="base"):
        caster.lattice_keys(np.zeros(3), np.zeros((4, 3)), np.eye(3), tri_face, 16,
                            base=2**20)


def test_lattice_key_set_is_the_distinct_keys_and_survives_a_full_table(runtime):
    """The device's hash set of keys (collect_reflection_keys_rotated) holds exactly the
    distinct non-zero keys of every ray; a table too small for them is noticed and the
    keys are then gathered on the host, with the same result."""
    tris = _room()
    caster = RayCaster(tris, runtime=runtime)
    tri_face = np.arange(len(tris), dtype=np.int32) // 2
    local = fibonacci_sphere(20000)
    rot = np.eye(3)
    origin = np.array([0.7, -0.4, 0.2])
    base = sp.key_base(int(tri_face.max()) + 1, 4)
    keys = caster.lattice_keys(origin, local, rot, tri_face, 4, base)
    want = np.unique(keys[keys > 0])
    assert len(want) > 200
    told = []
    np.testing.assert_array_equal(
        caster.lattice_key_set(origin, local, rot, tri_face, 4, base, batch=7000,
                               on_host=told.append), want)
    assert told == [] and caster.key_set_refusal() is None
    # 2^6 slots for hundreds of keys: the set overflows, the host's path answers, and
    # says so
    np.testing.assert_array_equal(
        caster.lattice_key_set(origin, local, rot, tri_face, 4, base, table_bits=6,
                               on_host=told.append), want)
    assert len(told) == 1 and "2^6 slots filled up" in told[0]
    with pytest.raises(ArgumentError, match="table_bits"):
        caster.lattice_key_set(origin, local, rot, tri_face, 4, base, table_bits=40)


def test_coherent_launch_order_finds_the_same_candidates(runtime):
    """specular.prepare launches its lattice in coherent order (docs/performance.md): each
    ray's key is its own, so the set of candidates is the Fibonacci order's."""
    tris = _room()
    caster = RayCaster(tris, runtime=runtime)
    tri_face = np.arange(len(tris), dtype=np.int32) // 2
    local = fibonacci_sphere(20000)
    ordered = np.ascontiguousarray(local[coherent_order(local)])
    rot = np.eye(3)[:, [1, 2, 0]]
    origin = np.array([0.7, -0.4, 0.2])
    base = sp.key_base(int(tri_face.max()) + 1, 5)
    keys = caster.lattice_keys(origin, local, rot, tri_face, 5, base)
    keys_ordered = caster.lattice_keys(origin, ordered, rot, tri_face, 5, base)
    # ray for ray the same key, only in the new order
    np.testing.assert_array_equal(keys_ordered, keys[coherent_order(local)])
    want = caster.lattice_key_set(origin, local, rot, tri_face, 5, base)
    assert len(want) > 200
    np.testing.assert_array_equal(
        caster.lattice_key_set(origin, ordered, rot, tri_face, 5, base), want)


# ---------------------------------------------------------------------------
# a device without 64-bit atomics (cl_khr_int64_base_atomics)

def without_int64_atomics(runtime) -> Runtime:
    """A fresh runtime on the session's device, in its fp64 mode, whose info says the
    device has no 64-bit atomics: what the code reads to choose the key set's engine."""
    info = runtime.info
    fresh = Runtime(f"{info.platform_index}:{info.device_index}", fp64=runtime.has_double)
    fresh.info = dataclasses.replace(fresh.info, int64_atomics=False)
    return fresh


def test_key_set_without_64_bit_atomics_is_gathered_on_the_host(runtime):
    """Without the atomics the set is not gathered on the device: every ray's key comes
    back, the host de-duplicates them and says why; the result is the device's set (or,
    on a device that lacks the atomics itself, the distinct keys)."""
    tris = _room()
    tri_face = np.arange(len(tris), dtype=np.int32) // 2
    local, rot, origin = fibonacci_sphere(20000), np.eye(3), np.array([0.7, -0.4, 0.2])
    base = sp.key_base(int(tri_face.max()) + 1, 4)
    plain = RayCaster(tris, runtime=without_int64_atomics(runtime))
    told = []
    got = plain.lattice_key_set(origin, local, rot, tri_face, 4, base, on_host=told.append)
    assert told == [plain.key_set_refusal()] and "64-bit atomics" in told[0]
    caster = RayCaster(tris, runtime=runtime)
    keys = caster.lattice_keys(origin, local, rot, tri_face, 4, base)
    np.testing.assert_array_equal(got, np.unique(keys[keys > 0]))
    if runtime.info.int64_atomics:
        np.testing.assert_array_equal(
            got, caster.lattice_key_set(origin, local, rot, tri_face, 4, base))
    assert len(got) > 200


def test_trace_without_64_bit_atomics_says_so_and_finds_the_same_paths(runtime):
    """The golden scene's specular paths traced on a device without 64-bit atomics: the
    candidates' stage is recorded as left to the host with the reason, said once, and
    the snapshot is the one the device's own key set gives, bit for bit."""
    scene = load_scene(GOLDEN)
    settings = TraceSettings(specular=SpecularSettings(max_reflections=3, rays=20_000),
                             diffraction=DiffractionSettings(max_diffractions=0))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = trace_scene(scene, settings, runtime=without_int64_atomics(runtime))
    said = [w for w in caught if issubclass(w.category, DeviceFallbackWarning)
            and "specular.candidates" in str(w.message)]
    assert len(said) == 1 and "64-bit atomics" in str(said[0].message)
    assert "64-bit atomics" in got.metadata["engine.specular.candidates"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")   # the scene's expected physics warnings
        want = trace_scene(scene, settings, runtime=runtime)
    assert [lk.label for lk in got] == [lk.label for lk in want]
    for a, b in zip(got.links, want.links, strict=True):
        assert a.paths.n_paths == b.paths.n_paths > 0, a.label
        for name in ("gain", "delay_s", "points", "face_id", "interaction"):
            np.testing.assert_array_equal(getattr(a.paths, name), getattr(b.paths, name),
                                          err_msg=f"{a.label} {name}")
