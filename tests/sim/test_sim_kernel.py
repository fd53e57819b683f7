"""The compiled kernels draw from the trial's own generator (``kernel.generator``): the same
numbers, in the same order, as the numpy ``Generator`` would give, and the generator's state
moves on with them, so draws in Python and in kernels interleave as one stream. This holds
only as long as numba represents a Generator as the kernel assumes; a numba that does not
fails here."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ktbt_sim.kernel import generator, generator_pointers, jit


@jit
def _draws(pointers: np.ndarray, n: int) -> np.ndarray:
    rng = generator(pointers)
    out = np.empty(3 * n)
    for i in range(n):
        out[3 * i] = rng.random()
        out[3 * i + 1] = rng.uniform(-2.0, 5.0)
        out[3 * i + 2] = rng.normal(0.0, 1.0)
    return out


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 50), before=st.integers(0, 5))
def test_kernel_draws_are_the_generators_own_and_advance_it(seed: int, n: int, before: int) -> None:
    ours, numpys = np.random.default_rng(seed), np.random.default_rng(seed)
    ours.random(before), numpys.random(before)  # Python draws first: one stream
    got = _draws(generator_pointers(ours), n)
    expected = np.empty(3 * n)
    for i in range(n):
        expected[3 * i] = numpys.random()
        expected[3 * i + 1] = numpys.uniform(-2.0, 5.0)
        expected[3 * i + 2] = numpys.normal(0.0, 1.0)
    assert np.array_equal(got, expected)
    assert ours.random() == numpys.random()  # and Python goes on where the kernel stopped
