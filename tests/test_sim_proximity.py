"""The sparse neighbour search gives exactly what the distance matrix gives (property tests):
collision weights, comms neighbours, order of entry, new pairs and every teacher's requester."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ktbt_sim.sensing import Proximity, SparseProximity


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(2, 30),
    seed=st.integers(0, 2**32 - 1),
    radius=st.sampled_from([111.0, 336.0, 636.0, 1536.0]),
    spread=st.sampled_from([300.0, 1500.0, 4000.0]),
)
def test_sparse_and_dense_agree(n: int, seed: int, radius: float, spread: float) -> None:
    rng = np.random.default_rng(seed)
    dense = Proximity(n, 75.0, 36.0, radius, comms=True)
    sparse = SparseProximity(n, 75.0, 36.0, radius, comms=True)
    pos = rng.uniform(-spread, spread, (n, 2))
    for iteration in range(1, 8):
        pos = pos + rng.normal(0.0, spread / 6, (n, 2))
        dense.update(pos, iteration)
        sparse.update(pos, iteration)
        assert dense.count.tolist() == sparse.count.tolist()
        assert dense.has_neighbours.tolist() == sparse.has_neighbours.tolist()
        assert sorted(map(tuple, dense.newly.tolist())) == sorted(map(tuple, sparse.newly.tolist()))
        rows = np.flatnonzero(dense.count > 0)
        assert np.allclose(dense.away(pos, rows), sparse.away(pos, rows))
        for i in range(n):
            assert dense.neighbours(i).tolist() == sparse.neighbours(i).tolist()
        open_ = rng.random(n) < 0.4
        assert dense.requesters(open_).tolist() == sparse.requesters(open_).tolist()
        knows = rng.random((n, 4)) < 0.5
        asked = rng.integers(1, 5, n)
        assert (
            dense.requesters(open_, knows, asked).tolist()
            == sparse.requesters(open_, knows, asked).tolist()
        )
