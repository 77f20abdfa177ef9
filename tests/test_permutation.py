"""The prime permutation: numpy reference exact and bijective, GLSL equal to it."""

import numpy as np
import pytest
import sympy

from progressive.permutation import BATCH_POINTS, BATCH_SLOTS, SLICE_POINTS, FillOrder, Permutation, prime_for


def paper_permute(i: int, p: int) -> int:
    """Equation 1 of the paper with Python integers (independent of the numpy code)."""
    if i >= p:
        return i
    r = i * i % p
    return r if i <= p // 2 else p - r


@pytest.mark.parametrize("n", list(range(0, 200)) + [1000, 4096, 65537, 2**31 + 11, 2**32 - 1])
def test_prime_is_largest_3_mod_4(n):
    p = prime_for(n)
    if n < 3:
        assert p == 0
        return
    assert sympy.isprime(p) and p % 4 == 3 and p <= n
    if n < 100_000:
        assert not any(sympy.isprime(q) and q % 4 == 3 for q in range(p + 1, n + 1))


def test_bijection_exhaustive_up_to_4096():
    for n in range(0, 4097):
        for rotate in (False, True):
            perm = Permutation.for_count(n, rotate=rotate)
            i = np.arange(n, dtype=np.uint64)
            slots = perm.forward(i)
            assert np.array_equal(np.sort(slots), i), (n, rotate)
            assert np.array_equal(perm.inverse(slots), i), (n, rotate)


def test_bijection_random_n_up_to_2_22():
    rng = np.random.default_rng(7)
    ns = np.unique(np.exp(rng.uniform(np.log(4097), np.log(2**22), 200)).astype(np.int64))
    for n in ns:
        perm = Permutation.for_count(int(n))
        i = np.arange(n, dtype=np.uint64)
        slots = perm.forward(i)
        seen = np.zeros(n, dtype=bool)
        seen[slots] = True
        assert seen.all(), n
        sample = i[:: max(1, n // 5000)]
        assert np.array_equal(perm.inverse(perm.forward(sample)), sample)


def test_paper_formula_without_rotation():
    n = 1_000_003
    perm = Permutation.for_count(n, rotate=False)
    idx = [0, 1, 2, 3, 12345, perm.prime // 2, perm.prime // 2 + 1, perm.prime - 1, perm.prime, n - 1]
    expect = [paper_permute(paper_permute(i, perm.prime), perm.prime) for i in idx]
    assert perm.forward(np.array(idx)).tolist() == expect


@pytest.mark.parametrize("n", [2**24 - 3, 2**24 + 1, 2**31 - 1, 2**31, 2**31 + 5, 2**32 - 1])
def test_large_n_sampled(n):
    perm = Permutation.for_count(n)
    rng = np.random.default_rng(n % 1000)
    edges = np.array([0, 1, 2, perm.prime // 2, perm.prime // 2 + 1, perm.prime - 1, min(perm.prime, n - 1), n - 1],
                     dtype=np.uint64)
    sample = np.unique(np.concatenate([rng.integers(0, n, 200_000, dtype=np.uint64), edges]))
    slots = perm.forward(sample)
    assert slots.max() < n
    assert np.unique(slots).size == sample.size
    assert np.array_equal(perm.inverse(slots), sample)
    tail = sample[sample >= perm.prime]
    assert np.array_equal(perm.forward(tail), tail)


def test_rotation_breaks_fixed_start():
    """The paper's formula keeps file indices 0, 1 at slots 0, 1 (and 2 -> 16):
    the rotation moves the start of the file away from the start of the buffer."""
    plain = Permutation.for_count(1_000_000, rotate=False)
    rotated = Permutation.for_count(1_000_000)
    assert plain.forward(np.arange(3)).tolist() == [0, 1, 16]
    first_slots = rotated.forward(np.arange(1000))
    assert np.median(first_slots) > 100_000


@pytest.mark.parametrize("int64", [True, False], ids=["int64", "umulExtended"])
@pytest.mark.parametrize("n", [4096, 2**24 + 1, 2**31 - 1, 2**31 + 5, 2**32 - 1])
def test_gpu_matches_numpy(gl, n, int64):
    from progressive.passes.permute import gpu_permute

    if int64 and not gl.caps.shader_int64:
        pytest.skip("no GL_ARB_gpu_shader_int64")
    perm = Permutation.for_count(n)
    rng = np.random.default_rng(3)
    idx = np.concatenate([rng.integers(0, n, 100_000, dtype=np.uint64),
                          np.array([0, 1, perm.prime // 2, perm.prime // 2 + 1, perm.prime - 1, n - 1], dtype=np.uint64)])
    gpu = gpu_permute(gl, perm, idx, int64=int64)
    gl.check()
    assert np.array_equal(gpu.astype(np.uint64), perm.forward(idx))


BATCHED_COUNTS = [1, 7, BATCH_POINTS - 1, BATCH_POINTS, BATCH_POINTS + 1, 3 * BATCH_POINTS + 17, 1_000_003]


@pytest.mark.parametrize("n", BATCHED_COUNTS)
def test_batched_layout_is_a_local_bijection(n):
    """Every batch's points stay in its slices, each slice holds points of one batch,
    and a prefix of the slots holds the same share of every batch."""
    perm = Permutation.for_count(n, order=FillOrder.BATCHED)
    i = np.arange(n, dtype=np.uint64)
    slots = perm.forward(i)
    assert slots.max() < perm.slots == perm.batches * BATCH_SLOTS and np.unique(slots).size == n
    assert np.array_equal(perm.inverse(slots), i)
    batch = i // BATCH_POINTS
    slot_batch = (slots % (perm.batches * SLICE_POINTS)) // SLICE_POINTS
    assert np.array_equal(slot_batch, batch)
    full = n // BATCH_POINTS
    if full >= 2:
        prefix = slots < perm.slots // 4
        shares = np.bincount(batch[prefix].astype(np.int64), minlength=full)[:full]
        assert shares.min() == shares.max() == BATCH_SLOTS // 4


def test_a_batch_is_the_largest_prime_that_fits_its_slots():
    """Every point of a batch is shuffled: none sits at an index >= P."""
    assert BATCH_POINTS == prime_for(BATCH_SLOTS) and Permutation.for_count(10**6, order=FillOrder.BATCHED).prime == BATCH_POINTS


def test_batched_shuffle_inside_a_batch_is_the_paper_formula_rotated_per_batch():
    perm = Permutation.for_count(5 * BATCH_POINTS, order=FillOrder.BATCHED)
    p = perm.prime
    for b in range(5):
        rotation = (b + 1) % p * perm.offset % p
        local = np.arange(0, p, 97)
        expect = [paper_permute((paper_permute(int(j), p) + rotation) % p, p) for j in local]
        got = perm.forward(b * BATCH_POINTS + local)
        shuffled = (got // (perm.batches * SLICE_POINTS)) * SLICE_POINTS + got % SLICE_POINTS
        assert shuffled.tolist() == expect


@pytest.mark.parametrize("int64", [True, False], ids=["int64", "umulExtended"])
@pytest.mark.parametrize("n", [*BATCHED_COUNTS, (2**32 // BATCH_SLOTS) * BATCH_POINTS - 1])
def test_gpu_batched_matches_numpy(gl, n, int64):
    from progressive.passes.permute import gpu_permute

    if int64 and not gl.caps.shader_int64:
        pytest.skip("no GL_ARB_gpu_shader_int64")
    perm = Permutation.for_count(n, order=FillOrder.BATCHED)
    rng = np.random.default_rng(5)
    idx = np.concatenate([rng.integers(0, n, 100_000, dtype=np.uint64), np.array([0, n - 1], dtype=np.uint64)])
    gpu = gpu_permute(gl, perm, idx, int64=int64)
    gl.check()
    assert np.array_equal(gpu.astype(np.uint64), perm.forward(idx))


@pytest.mark.parametrize("n", [1, 300, BATCH_POINTS, 3 * BATCH_POINTS + 17, 110_000])
def test_kept_counts_the_points_below_a_capacity(n):
    perm = Permutation.for_count(n, order=FillOrder.BATCHED)
    slots = perm.forward(np.arange(n, dtype=np.uint64))
    for capacity in sorted({0, 1, 255, 256, 257, n // 3, n - 1, n, perm.slots - 1, perm.slots, perm.slots + 5}):
        assert perm.kept(max(0, capacity)) == int(np.count_nonzero(slots < max(0, capacity))), capacity
