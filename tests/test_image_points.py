"""The image method on the device (kernels/images.cl) against the host's numpy
reference (clradcom.mechanisms.specular.image_points): the same points bit for bit (in
double-float without fp64: the paths' points within tests/mode_helpers.py's
POINT_TOL_REL), the same path mask and the same warnings."""

import warnings

import numpy as np
import pytest
from mode_helpers import assert_points

from clradcom.device import engines
from clradcom.device import images as device_images
from clradcom.errors import ArgumentError, DeviceFallbackWarning, SurfaceContactWarning
from clradcom.mechanisms.specular import image_points


def on_device(runtime, tx, rx, normals, offsets, seqs):
    """specular.image_points with ``runtime``, held to have run on the device: were the
    device refused (device_images.available False) the host would place the points and
    every comparison below would hold the host against itself."""
    assert device_images.available(runtime), device_images.device_refusal(runtime)
    with engines.engine_log() as log, warnings.catch_warnings():
        warnings.simplefilter("error", DeviceFallbackWarning)
        out = image_points(tx, rx, normals, offsets, seqs, runtime=runtime)
    assert log.engine_of("specular.image_points") == "device", log.uses
    return out


def _planes(rng, n):
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return normals, rng.uniform(-30.0, 30.0, n)


@pytest.mark.parametrize("k", [1, 2, 5, 16])
def test_device_image_points_are_the_hosts_bit_for_bit(runtime, k):
    rng = np.random.default_rng(k)
    normals, offsets = _planes(rng, 40)
    # far from the origin, where float64 rounding shows in the last digits
    tx = np.array([812.3, -455.1, 1.7])
    rx = np.array([790.9, -430.4, 2.2])
    offsets = offsets + normals @ tx
    seqs = rng.integers(0, len(normals), (3000, k)).astype(np.int32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SurfaceContactWarning)
        want_pts, want_ok = image_points(tx, rx, normals, offsets, seqs)
        got_pts, got_ok = on_device(runtime, tx, rx, normals, offsets, seqs)
    np.testing.assert_array_equal(got_ok, want_ok)
    if runtime.has_double:
        np.testing.assert_array_equal(got_pts, want_pts)   # NaN-free: every step goes on
    else:
        # double-float: the paths' points within POINT_TOL_REL (1 + |p|) of the host's; a
        # candidate that is no path may be as ill-conditioned as its random planes make
        # it (16 random mirrors: images metres apart), its points are never used
        assert_points(runtime, got_pts[want_ok], want_pts[want_ok])
        assert np.isfinite(got_pts).all()
    # random planes: some candidates are paths, some are not (at 16 random reflections
    # none is; with fp64 the points must still agree)
    assert want_ok.sum() < len(seqs) and (k > 5 or want_ok.sum() > 0)


def test_device_image_points_warn_as_the_host_where_an_antenna_is_on_a_face(runtime):
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    offsets = np.array([0.0, 10.0])
    tx = np.array([0.0, 0.0, 0.0])   # on the ground plane z = 0
    rx = np.array([5.0, 0.0, 0.0])   # on it too
    seqs = np.array([[0], [1]], dtype=np.int32)
    caught = {}
    for name, rt in (("host", None), ("device", runtime)):
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            if rt is None:
                pts, ok = image_points(tx, rx, normals, offsets, seqs)
            else:
                pts, ok = on_device(rt, tx, rx, normals, offsets, seqs)
        caught[name] = ([str(x.message) for x in w if x.category is SurfaceContactWarning],
                        ok, pts)
    assert caught["device"][0] == caught["host"][0]
    assert len(caught["host"][0]) == 2   # the receiver's and the transmitter's
    np.testing.assert_array_equal(caught["device"][1], [False, True])
    np.testing.assert_array_equal(caught["device"][1], caught["host"][1])
    np.testing.assert_array_equal(caught["device"][2], caught["host"][2])


def test_device_image_points_refuse_bad_sequences(runtime):
    normals = np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(ArgumentError, match="face ids"):
        device_images.image_points(runtime, np.zeros(3), np.ones(3), normals, [0.0],
                                   np.array([[1]]))
    with pytest.raises(ArgumentError, match="seqs"):
        device_images.image_points(runtime, np.zeros(3), np.ones(3), normals, [0.0],
                                   np.zeros((2, device_images.MAX_ORDER + 1), np.int32))


def test_points_left_to_the_host_are_recorded_and_said(runtime, monkeypatch):
    """Where the device cannot repeat the host bit for bit (fp64 and numpy's dot order
    unknown) the host places the points: recorded with the reason, said once."""
    normals = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    offsets = np.array([0.0, 10.0])
    tx, rx = np.array([0.0, 0.0, 1.0]), np.array([5.0, 1.0, 2.0])
    seqs = np.array([[0], [1]], dtype=np.int32)
    want = image_points(tx, rx, normals, offsets, seqs)
    with engines.engine_log() as log:
        got = image_points(tx, rx, normals, offsets, seqs, runtime=runtime)
        assert log.engine_of("specular.image_points") == "device"
        monkeypatch.setattr(device_images, "dot3_order", lambda: None)
        if runtime.has_double:
            with pytest.warns(DeviceFallbackWarning, match="specular.image_points.*dot"):
                got = image_points(tx, rx, normals, offsets, seqs, runtime=runtime)
            assert log.engine_of("specular.image_points") == "device+host"
            np.testing.assert_array_equal(got[0], want[0])
        else:   # double-float needs no particular order
            assert device_images.available(runtime)
