"""The snapshot reader refuses, before unpacking anything, an archive that would take
more memory than allowed or whose members promise more data than they hold."""

import json
import subprocess
import sys
import textwrap
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


#: Measured in a process of its own: ru_maxrss is a high-water mark, so in the test
#: process an earlier peak (another test's 700 MB) would hide the bomb's 256 MiB.
REFUSE_IN_A_FRESH_PROCESS = textwrap.dedent("""
    import json, resource, sys, time
    from clradcom.errors import SnapshotError
    from clradcom.snapshot import load_snapshot
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.perf_counter()
    try:
        load_snapshot(sys.argv[1], max_bytes=2**26)
        error = None
    except SnapshotError as exc:
        error = str(exc)
    seconds = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print(json.dumps({"error": error, "seconds": seconds, "grown_kib": after - before}))
""")


def test_a_deflate_bomb_is_refused_quickly_and_small(tmp_path):
    path = bomb(tmp_path / "bomb.npz", (2**24,))  # 256 MiB unpacked, about 0.3 MB on disk
    assert path.stat().st_size < 2**20
    run = subprocess.run([sys.executable, "-c", REFUSE_IN_A_FRESH_PROCESS, str(path)],
                         capture_output=True, text=True, timeout=120, check=False)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["error"] is not None and "link0/gain" in got["error"]
    assert "more than 67108864 bytes" in got["error"], got["error"]
    # refused from the zip's directory: nothing inflated (a mutant reading the member
    # first grows by the whole 256 MiB and takes a few tenths of a second more)
    assert got["grown_kib"] < 32 * 1024, got
    assert got["seconds"] < 1.0, got


def test_a_header_promising_more_than_the_member_holds_is_refused(tmp_path):
    path = bomb(tmp_path / "liar.npz", (2**30,), declared_only=True)
    with pytest.raises(SnapshotError, match="promises .* bytes but the member holds"):
        load_snapshot(path)
