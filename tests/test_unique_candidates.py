"""De-duplicating the rays' face sequences: the exact int64 row keys against a plain
reference (every prefix of every row, cut at a repeated face, in a set), and against the
hashed path taken when the face ids are too many for one key."""

import numpy as np

from clradcom.mechanisms.specular import unique_candidates


def reference(seq):
    out = {k: set() for k in range(1, seq.shape[1] + 1)}
    for row in seq.tolist():
        faces = []
        for f in row:
            if f < 0 or (faces and f == faces[-1]):
                break
            faces.append(f)
            out[len(faces)].add(tuple(faces))
    return {k: np.array(sorted(v), dtype=np.int32).reshape(-1, k) for k, v in out.items()}


def random_sequences(rng, n, k, n_faces):
    seq = rng.integers(0, n_faces, size=(n, k)).astype(np.int32)
    # rays repeat each other, escape after some bounces, and re-hit the face they left
    seq = seq[rng.integers(0, n // 20, size=n)]
    stop = rng.integers(0, k + 1, size=n)
    seq[np.arange(k)[None, :] >= stop[:, None]] = -1
    again = rng.random(n) < 0.1
    col = rng.integers(1, k, size=n)
    seq[again, col[again]] = seq[again, col[again] - 1]
    return seq


def test_keys_give_every_distinct_prefix_in_lexicographic_order():
    rng = np.random.default_rng(11)
    seq = random_sequences(rng, 20_000, 5, 5000)   # 5002**5 < 2**63: exact keys
    got, want = unique_candidates(seq), reference(seq)
    assert list(got) == [1, 2, 3, 4, 5]
    for k in want:
        assert got[k].dtype == np.int32 and len(want[k]) > 10
        np.testing.assert_array_equal(got[k], want[k])


def test_too_many_faces_for_one_key_take_the_hashed_path_to_the_same_result():
    rng = np.random.default_rng(12)
    seq = random_sequences(rng, 5_000, 6, 2_000_000)   # 2e6**6 > 2**63
    got, want = unique_candidates(seq), reference(seq)
    for k in want:
        np.testing.assert_array_equal(got[k], want[k])
    small = seq % 50
    small[seq < 0] = -1
    for k, rows in unique_candidates(small).items():
        np.testing.assert_array_equal(rows, reference(small)[k])


def test_no_rays_and_rays_that_hit_nothing():
    for seq in (np.zeros((0, 3), np.int32), np.full((4, 3), -1, np.int32)):
        got = unique_candidates(seq)
        assert {k: (v.shape, v.dtype) for k, v in got.items()} == {
            k: ((0, k), np.dtype(np.int32)) for k in (1, 2, 3)}
