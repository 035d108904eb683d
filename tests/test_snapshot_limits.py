"""The snapshot reader refuses, before unpacking anything, an archive that would take
more memory than allowed or whose members promise more data than they hold."""

import resource
import time
import zipfile

import numpy as np
import pytest

from clradcom.errors import SnapshotError
from clradcom.snapshot import load_snapshot


def bomb(path, shape, declared_only=False):
    """A snapshot-looking npz whose link0/gain member is a deflated run of zeros of the
    given shape (a few MB on disk); declared_only writes the header and no data."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        with zf.open("meta/format.npy", "w") as m:
            np.lib.format.write_array(m, np.array("clradcom-snapshot"))
        with zf.open("link0/gain.npy", "w", force_zip64=True) as m:
            np.lib.format.write_array_header_1_0(
                m, {"descr": "<c16", "fortran_order": False, "shape": shape})
            if not declared_only:
                chunk = bytes(2**24)
                left = int(np.prod(shape)) * 16
                while left:
                    m.write(chunk[:min(left, len(chunk))])
                    left -= min(left, len(chunk))
    return path


def test_a_deflate_bomb_is_refused_quickly_and_small(tmp_path):
    path = bomb(tmp_path / "bomb.npz", (2**24,))  # 256 MiB unpacked, about 0.3 MB on disk
    assert path.stat().st_size < 2**20
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    with pytest.raises(SnapshotError, match=r"link0/gain: .*more than 67108864 bytes"):
        load_snapshot(path, max_bytes=2**26)
    assert time.perf_counter() - t0 < 1.0
    grown_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before
    assert grown_kib < 100 * 1024


def test_a_header_promising_more_than_the_member_holds_is_refused(tmp_path):
    path = bomb(tmp_path / "liar.npz", (2**30,), declared_only=True)
    with pytest.raises(SnapshotError, match="promises .* bytes but the member holds"):
        load_snapshot(path)
