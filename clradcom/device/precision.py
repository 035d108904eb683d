"""Precise lengths on the device: the host side of ``kernels/precise.h``.

A kernel whose lengths become phases carries them in ``preal``: ``double`` where the
device has fp64, else a double-float (hi + lo pair of floats, docs/precision.md).
Float64 values cross to such kernels as float32 ``(hi, lo)`` pairs
(:func:`split_pairs`) and come back the same way (:func:`join_pairs`), so one kernel
signature serves every mode. Kernels that must read float64 values exactly where the
device has fp64 (the visibility, image-point, edge, window and tile kernels) take them
as ``pr_elem`` instead: the float64 array where the runtime computes in double, its pairs
without (:func:`kernel_float64`, :func:`kernel_scalar64`, :func:`host_float64`; the same
bytes either way). :func:`precise_ops`, :func:`precise_decisions`,
:func:`polyline_lengths` and :func:`bounce_lengths` run the probes of
``kernels/precision_probe.cl``; the tests hold their phases at 24 and 77 GHz to the
float64 host values.
"""

from __future__ import annotations

import numpy as np

from clradcom.device.runtime import Runtime, get_runtime
from clradcom.errors import ArgumentError
from clradcom.geometry.triangles import triangle_normals

__all__ = ["MODES", "split_pairs", "join_pairs", "kernel_float64", "kernel_scalar64",
           "host_float64", "triangle_plane_pairs", "mode_defines", "build_mode",
           "precise_ops", "precise_decisions", "polyline_lengths", "bounce_lengths"]

#: Requested precision modes: "auto" (fp64 where the device has it, else double-float),
#: "fp64", "double-float" (forced, through ``-D CLRADCOM_NO_FP64=1``) and "float32"
#: (plain float, the tests' negative control: never for results).
MODES = ("auto", "fp64", "double-float", "float32")

#: PRECISE_MODE of kernels/precise.h -> mode name
_MODE_NAMES = {2: "fp64", 1: "double-float", 0: "float32"}

_SOURCE = "precision_probe.cl"


def split_pairs(x) -> np.ndarray:
    """float64 array (...) -> float32 array (..., 2) of (hi, lo): hi = f32(x),
    lo = f32(x - hi), so hi + lo equals x to 2^-48 |x| (about 4e-12 m at 1 km). A value
    that is not finite as a float (inf, NaN, beyond float's range) has lo = 0, so it
    joins back to itself (a PEC's infinite permittivity stays inf, not inf - inf)."""
    x = np.asarray(x, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        hi = x.astype(np.float32)
        lo = np.where(np.isfinite(hi), x - hi.astype(np.float64), 0.0).astype(np.float32)
    return np.ascontiguousarray(np.stack([hi, lo], axis=-1))


def join_pairs(pairs) -> np.ndarray:
    """float32 array (..., 2) of (hi, lo) -> float64 array (...): hi + lo."""
    pairs = np.asarray(pairs)
    return pairs[..., 0].astype(np.float64) + pairs[..., 1].astype(np.float64)


def kernel_float64(runtime: Runtime, x) -> np.ndarray:
    """float64 values as a kernel reads them through ``kernels/precise.h``'s ``pr_elem``:
    the float64 array itself where ``runtime``'s builds compute in double
    (``runtime.has_double``), else its :func:`split_pairs` (..., 2) float32 -- the same
    bytes, so buffer sizes and offsets do not depend on the mode."""
    x = np.ascontiguousarray(x, dtype=np.float64)
    return x if runtime.has_double else split_pairs(x)


def kernel_scalar64(runtime: Runtime, x):
    """One float64 kernel argument of type ``pr_elem``: a numpy float64, or a float2
    (hi, lo) where the device computes without fp64."""
    if runtime.has_double:
        return np.float64(x)
    from pyopencl import cltypes

    hi, lo = split_pairs(float(x))
    return cltypes.make_float2(hi, lo)


def host_float64(runtime: Runtime, raw: np.ndarray) -> np.ndarray:
    """A kernel's ``pr_elem`` results, copied into the float64 array ``raw`` of their
    shape, as float64: ``raw`` itself with fp64, else the (hi, lo) pairs its bytes hold
    joined (:func:`join_pairs`)."""
    if runtime.has_double:
        return raw
    return join_pairs(raw.view(np.float32).reshape(*raw.shape, 2))


def triangle_plane_pairs(triangles) -> tuple[np.ndarray, np.ndarray]:
    """The float64 planes of triangles (T, 3, 3) as a kernel reads them with
    ``pr3_load_pairs``: (T, 3, 2) float32 pairs of each first vertex and of its unit
    normal (:func:`clradcom.geometry.triangles.triangle_normals`, the host's own, so a
    device plane hit agrees with the host's). Zero-area triangles are refused."""
    tri = np.asarray(triangles, dtype=np.float64)
    if tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise ArgumentError("must have shape (T, 3, 3)", argument="triangles",
                            value=tri.shape)
    _finite("triangles", tri)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = triangle_normals(tri)
    bad = ~np.isfinite(normals).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ArgumentError(f"triangle {i} has zero area: no plane", argument="triangles",
                            value=tri[i].tolist())
    return split_pairs(tri[:, 0]), split_pairs(normals)


def mode_defines(mode: str, runtime: Runtime) -> dict[str, int]:
    """The ``-D`` macros that build ``kernels/precise.h`` in ``mode`` on ``runtime``'s
    device; "fp64" on a device without it is refused."""
    if mode not in MODES:
        raise ArgumentError(f"must be one of {', '.join(MODES)}", argument="mode", value=mode)
    if mode == "fp64" and not runtime.has_double:
        raise ArgumentError("this OpenCL device has no fp64 (use 'auto' or 'double-float')",
                            argument="mode", value=mode)
    if mode == "double-float":
        return {"CLRADCOM_NO_FP64": 1}
    if mode == "float32":
        return {"CLRADCOM_PRECISE_FLOAT32": 1}
    return {}


def _runtime(runtime):
    return runtime if runtime is not None else get_runtime()


def build_mode(mode: str = "auto", runtime: Runtime | None = None) -> str:
    """The mode a build for ``mode`` actually runs in, as the kernel reports it:
    "fp64", "double-float" or "float32"."""
    import pyopencl as cl

    rt = _runtime(runtime)
    kernel = rt.kernel(_SOURCE, "precise_mode", defines=mode_defines(mode, rt))
    out = np.full(1, -1, dtype=np.int32)
    buf = rt.empty(out.nbytes)
    kernel(rt.queue, (1,), None, buf)
    cl.enqueue_copy(rt.queue, out, buf, is_blocking=True)
    return _MODE_NAMES[int(out[0])]


def _run(rt, mode, kernel_name, n, inputs, scalars_before, outputs, scalars_after=()):
    """Launch one probe over n items: read-only ``inputs`` arrays, then ints, then
    ``outputs`` (name -> (shape, dtype)) returned as arrays."""
    import pyopencl as cl

    kernel = rt.kernel(_SOURCE, kernel_name, defines=mode_defines(mode, rt))
    in_bufs = [rt.to_device(np.ascontiguousarray(a)) for a in inputs]
    results = {name: np.empty(shape, dtype=dtype) for name, (shape, dtype) in outputs.items()}
    out_bufs = [rt.empty(arr.nbytes) for arr in results.values()]
    if n > 0:
        args = [*in_bufs, *(np.int32(s) for s in scalars_before), *out_bufs,
                *(np.int32(s) for s in scalars_after)]
        kernel(rt.queue, (int(n),), None, *args)
        for arr, buf in zip(results.values(), out_bufs, strict=True):
            if arr.nbytes:
                cl.enqueue_copy(rt.queue, arr, buf, is_blocking=True)
    return results


def _finite(name: str, arr: np.ndarray) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ArgumentError(f"is not finite at index {list(index)}", argument=name,
                            value=float(arr[index]))


def _points(name: str, value, ndim: int, shape_text: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != ndim or arr.shape[-1] != 3:
        raise ArgumentError(f"must have shape {shape_text}", argument=name, value=arr.shape)
    _finite(name, arr)
    return arr


def _operands(a, b) -> tuple[np.ndarray, np.ndarray]:
    """Two flat float64 arrays of one shape, finite, for the element-wise probes."""
    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.asarray(b, dtype=np.float64).ravel()
    if a.shape != b.shape:
        raise ArgumentError(f"must have the shape of a {a.shape}", argument="b",
                            value=b.shape)
    _finite("a", a)
    _finite("b", b)
    return a, b


def precise_ops(a, b, mode: str = "auto", runtime: Runtime | None = None) -> dict:
    """Scalar ``preal`` operations on the device, element by element over float64 arrays
    ``a`` and ``b`` (split into pairs first): a dict of float64 arrays "add", "sub",
    "mul", "div", "sqrt" (of |a|), "add_f" and "mul_f" (b rounded to float32)."""
    a, b = _operands(a, b)
    rt = _runtime(runtime)
    n = len(a)
    out = _run(rt, mode, "precise_ops", n, [split_pairs(a), split_pairs(b)], (),
               {"out": ((n, 7, 2), np.float32)}, (n,))["out"]
    values = join_pairs(out)
    names = ("add", "sub", "mul", "div", "sqrt", "add_f", "mul_f")
    return {name: values[:, i] for i, name in enumerate(names)}


def precise_decisions(a, b, mode: str = "auto", runtime: Runtime | None = None) -> dict:
    """The decisions and conversions of ``preal`` on the device, element by element over
    float64 arrays ``a`` and ``b`` (split into pairs first): a dict of "lt" and "le"
    (bool: a < b, a <= b), "fmax", "fmin", "floor" (of a) as float64, and "phase" (a
    less its whole turns, as a float: ``pr_phase_reduced``)."""
    a, b = _operands(a, b)
    rt = _runtime(runtime)
    n = len(a)
    out = _run(rt, mode, "precise_decisions", n, [split_pairs(a), split_pairs(b)], (),
               {"out": ((n, 6, 2), np.float32)}, (n,))["out"]
    values = join_pairs(out)
    return {"lt": values[:, 0] != 0, "le": values[:, 1] != 0, "fmax": values[:, 2],
            "fmin": values[:, 3], "floor": values[:, 4], "phase": values[:, 5]}


def polyline_lengths(points, mode: str = "auto", runtime: Runtime | None = None) -> np.ndarray:
    """(P,) float64 unfolded lengths sum_i |x_{i+1} - x_i| of polylines ``points``
    (P, V, 3) float64 (a path: tx, K interaction points, rx), summed on the device in
    ``preal``."""
    pts = _points("points", points, 3, "(P, V, 3)")
    rt = _runtime(runtime)
    n_paths, n_vertices = pts.shape[:2]
    out = _run(rt, mode, "polyline_lengths", n_paths, [split_pairs(pts)], (n_vertices,),
               {"lengths": ((n_paths, 2), np.float32)}, (n_paths,))
    return join_pairs(out["lengths"])


def bounce_lengths(origins, directions, plane_points, plane_normals, plane_seq,
                   mode: str = "auto", runtime: Runtime | None = None):
    """Rays from ``origins`` (P, 3) along ``directions`` (P, 3) mirrored off planes in
    turn, on the device in ``preal``, as an SBR ray tube is (kernels/precision_probe.cl).

    Planes: ``plane_points`` (F, 3) and ``plane_normals`` (F, 3) (normalised here, in
    float64); ``plane_seq`` (P, K) int indices into them, -1 ending a path's sequence.
    Returns ``(lengths, hits)``: (P,) float64 unfolded lengths from the origin to the
    last hit (|d| times the ray parameter, summed) and (P, K, 3) float64 hit points
    (zeros after a path's last hit).
    """
    org = _points("origins", origins, 2, "(P, 3)")
    dirs = _points("directions", directions, 2, "(P, 3)")
    if dirs.shape != org.shape:
        raise ArgumentError(f"must have the shape of origins {org.shape}",
                            argument="directions", value=dirs.shape)
    zero = ~np.any(dirs != 0.0, axis=1)
    if zero.any():
        i = int(np.flatnonzero(zero)[0])
        raise ArgumentError(f"row {i} is the zero vector", argument="directions",
                            value=dirs[i].tolist())
    v0 = _points("plane_points", plane_points, 2, "(F, 3)")
    nrm = _points("plane_normals", plane_normals, 2, "(F, 3)")
    if nrm.shape != v0.shape:
        raise ArgumentError(f"must have the shape of plane_points {v0.shape}",
                            argument="plane_normals", value=nrm.shape)
    n_len = np.linalg.norm(nrm, axis=1)
    if (n_len == 0).any():
        i = int(np.flatnonzero(n_len == 0)[0])
        raise ArgumentError(f"row {i} is the zero vector", argument="plane_normals",
                            value=nrm[i].tolist())
    nrm = nrm / n_len[:, None]
    seq = np.asarray(plane_seq)
    if seq.ndim != 2 or seq.shape[0] != len(org) or not np.issubdtype(seq.dtype, np.integer):
        raise ArgumentError(f"must be an integer array of shape ({len(org)}, K)",
                            argument="plane_seq", value=f"{seq.dtype} {seq.shape}")
    if ((seq < -1) | (seq >= len(v0))).any():
        index = tuple(int(i) for i in np.argwhere((seq < -1) | (seq >= len(v0)))[0])
        raise ArgumentError(f"indices must lie in [-1, {len(v0)}) (at {list(index)})",
                            argument="plane_seq", value=int(seq[index]))
    rt = _runtime(runtime)
    n_paths, k = seq.shape
    out = _run(rt, mode, "bounce_lengths", n_paths,
               [split_pairs(org), split_pairs(dirs), split_pairs(v0), split_pairs(nrm),
                seq.astype(np.int32)], (k,),
               {"hits": ((n_paths, k, 3, 2), np.float32),
                "lengths": ((n_paths, 2), np.float32)}, (n_paths,))
    return join_pairs(out["lengths"]), join_pairs(out["hits"])
