"""Runtime.kernel_seconds: the wall time spent inside kernel launches, the number a
benchmark divides by the trace time (tools/bench_trace.py)."""

import time

import numpy as np
import pytest
import trimesh

from clradcom.device.raycast import RayCaster, make_rays
from clradcom.scene.reader import scene_from_dict


@pytest.fixture(scope="module")
def caster(runtime):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    return RayCaster(np.asarray(sphere.vertices)[np.asarray(sphere.faces)], runtime=runtime)


def rays_at_origin(n, seed=0):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return make_rays(np.tile([0.0, 0.0, 5.0], (n, 1)), -np.array([0.0, 0.0, 5.0]) + d)


def counted(runtime, call):
    """(kernel seconds added by call(), wall seconds of the call, its result)."""
    k0, t0 = runtime.kernel_seconds, time.perf_counter()
    out = call()
    wall = time.perf_counter() - t0
    return runtime.kernel_seconds - k0, wall, out


@pytest.mark.parametrize("query", ["closest_hit", "occluded"])
def test_every_cast_adds_its_time_and_no_more_than_its_wall_time(runtime, caster, query):
    rays = rays_at_origin(20_000)
    k0, t0 = runtime.kernel_seconds, time.perf_counter()
    for _ in range(3):
        dk, wall, _ = counted(runtime, lambda: getattr(caster, query)(rays))
        assert 0.0 < dk <= wall
    # the counter is a running sum, never reset: three launches stay inside their wall time
    assert 0.0 < runtime.kernel_seconds - k0 <= time.perf_counter() - t0


def test_an_empty_launch_adds_nothing(runtime, caster):
    dk, _, hits = counted(runtime, lambda: caster.closest_hit(rays_at_origin(0)))
    assert len(hits) == 0 and dk == 0.0


def test_specular_sequences_and_run_kernel_are_counted(runtime, caster):
    d = np.random.default_rng(1).normal(size=(5_000, 3))
    faces = np.arange(len(caster.triangles), dtype=np.int32)
    dk, wall, seq = counted(runtime, lambda: caster.specular_sequences(
        [0.0, 0.0, 0.0], d, faces, 2))
    assert seq.shape == (5_000, 2) and 0.0 < dk <= wall
    # run_kernel: any kernel with the BVH buffers first, here closest_hit itself
    import pyopencl as cl

    rays = rays_at_origin(1_000)
    mf = cl.mem_flags
    ray_buf = cl.Buffer(runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=rays)
    out = np.empty(len(rays), dtype=caster.closest_hit(rays[:1]).dtype)
    out_buf = cl.Buffer(runtime.context, mf.WRITE_ONLY, size=out.nbytes)
    dk, wall, _ = counted(runtime, lambda: caster.run_kernel(
        "raycast.cl", "closest_hit", len(rays), ray_buf, None, out_buf, np.int32(len(rays))))
    assert 0.0 < dk <= wall
    cl.enqueue_copy(runtime.queue, out, out_buf)
    assert np.array_equal(out["prim"], caster.closest_hit(rays)["prim"])


def test_a_whole_trace_spends_part_of_its_time_in_kernels(runtime):
    """What bench_trace reports: the kernel share of a trace is in (0, 1]."""
    from clradcom.trace import SpecularSettings, TraceSettings, trace_scene

    scene = scene_from_dict({
        "scene": {"name": "plate", "carrier_hz": 24e9},
        "objects": [{"name": "road", "material": "concrete_road", "shape": "plane",
                     "size": [40.0, 10.0]},
                    {"name": "plate", "material": "metal", "shape": "plane",
                     "size": [2.0, 2.0], "position": [20.0, 0.0, 1.0],
                     "rotation_deg": [0.0, -90.0, 0.0]}],
        "radars": [{"name": "A", "position": [0.0, 0.0, 1.0]}]})
    settings = TraceSettings(specular=SpecularSettings(rays=20_000, max_reflections=2))
    dk, wall, snap = counted(runtime, lambda: trace_scene(scene, settings, runtime=runtime))
    assert snap.links[0].paths.n_paths > 0
    assert 0.0 < dk <= wall


def test_the_clock_counts_a_block_that_raises(runtime):
    k0 = runtime.kernel_seconds
    with pytest.raises(RuntimeError), runtime.kernel_clock():
        time.sleep(0.01)
        raise RuntimeError("kernel failed")
    assert runtime.kernel_seconds - k0 >= 0.01
