"""The compiled neighbour search gives exactly what a distance matrix gives (property tests),
for small groups (every pair) and large ones (nearby cells): collision weights, comms
neighbours, order of entry, new pairs and every teacher's requester."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ktbt_sim.sensing import DENSE_UP_TO, Proximity


class Matrix:
    """The rules of spec/simulator.md, "Robot-to-robot sensing", from the full distance matrix."""

    def __init__(self, n: int, sensor: float, body: float, radius: float) -> None:
        self.touch2, self.body2, self.radius2 = (2 * sensor) ** 2, (sensor + body) ** 2, radius**2
        self.in_range = np.zeros((n, n), dtype=bool)
        self.entered = np.zeros((n, n), dtype=np.int64)
        self.weight = np.zeros((n, n))
        self.newly = np.zeros((0, 2), dtype=np.int64)

    def update(self, pos: np.ndarray, iteration: int) -> None:
        d = pos[:, None, :] - pos[None, :, :]
        d2 = (d**2).sum(axis=2)
        np.fill_diagonal(d2, np.inf)
        self.weight = (d2 < self.touch2) + (d2 < self.body2).astype(np.float64)
        now = d2 <= self.radius2
        new = now & ~self.in_range
        self.entered[new] = iteration
        self.newly = np.argwhere(new)
        self.in_range = now

    def requesters(
        self, open_: np.ndarray, knows: np.ndarray | None = None, asked: np.ndarray | None = None
    ) -> list[int]:
        out = []
        for i in range(len(open_)):
            best = -1
            for j in np.flatnonzero(self.in_range[i] & open_).tolist():
                if knows is not None and asked is not None and not knows[i, asked[j] - 1]:
                    continue
                if best < 0 or self.entered[i, j] < self.entered[i, best]:
                    best = j
            out.append(best)
        return out


@settings(max_examples=40, deadline=None)
@given(
    n=st.one_of(st.integers(2, 30), st.integers(DENSE_UP_TO + 1, DENSE_UP_TO + 40)),
    seed=st.integers(0, 2**32 - 1),
    radius=st.sampled_from([111.0, 336.0, 636.0, 1536.0]),
    spread=st.sampled_from([300.0, 1500.0, 4000.0]),
)
def test_compiled_search_agrees_with_the_distance_matrix(
    n: int, seed: int, radius: float, spread: float
) -> None:
    rng = np.random.default_rng(seed)
    matrix = Matrix(n, 75.0, 36.0, radius)
    prox = Proximity(n, 75.0, 36.0, radius, comms=True)
    pos = rng.uniform(-spread, spread, (n, 2))
    for iteration in range(1, 6):
        pos = pos + rng.normal(0.0, spread / 6, (n, 2))
        matrix.update(pos, iteration)
        prox.update(pos, iteration)
        assert prox.count.tolist() == (matrix.weight > 0).sum(axis=1).tolist()
        assert prox.has_neighbours.tolist() == matrix.in_range.any(axis=1).tolist()
        assert prox.newly.tolist() == matrix.newly.tolist()
        for i in range(n):
            assert prox.weight(i).tolist() == matrix.weight[i].tolist()
            assert prox.neighbours(i).tolist() == np.flatnonzero(matrix.in_range[i]).tolist()
        for i, j in rng.integers(0, n, (5, 2)).tolist():
            assert prox.in_range(i, j) == bool(matrix.in_range[i, j])
        open_ = rng.random(n) < 0.4
        assert prox.requesters(open_).tolist() == matrix.requesters(open_)
        knows = rng.random((n, 4)) < 0.5
        asked = rng.integers(1, 5, n)
        assert prox.requesters(open_, knows, asked).tolist() == matrix.requesters(
            open_, knows, asked
        )


def test_a_group_spread_far_beyond_its_grid_gets_wider_cells_and_the_same_pairs() -> None:
    """One robot very far from the others would make the grid of cells huge
    (``GRID_CELLS_PER_ROBOT``): the search widens its cells instead and finds the same pairs."""
    rng = np.random.default_rng(3)
    n = DENSE_UP_TO + 20
    pos = rng.uniform(-1500.0, 1500.0, (n, 2))
    pos[7] = (4.0e7, -4.0e7)
    pos[8] = pos[7] + (100.0, 0.0)  # and it has a neighbour out there
    matrix = Matrix(n, 75.0, 36.0, 336.0)
    prox = Proximity(n, 75.0, 36.0, 336.0, comms=True)
    matrix.update(pos, 1)
    prox.update(pos, 1)
    assert prox.count.tolist() == (matrix.weight > 0).sum(axis=1).tolist()
    assert prox.neighbours(7).tolist() == [8]
    for i in range(n):
        assert prox.weight(i).tolist() == matrix.weight[i].tolist()
        assert prox.neighbours(i).tolist() == np.flatnonzero(matrix.in_range[i]).tolist()
