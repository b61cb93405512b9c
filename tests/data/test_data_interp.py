"""data.interp: the one linear interpolation of a sampled (N, k) signal, bit for bit np.interp; zero-order hold."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from skincal.data.interp import hold_rows, interp_rows
from skincal.errors import DatasetError


def per_column(t, grid, values):
    """The reference: np.interp on every column."""
    flat = values.reshape(values.shape[0], -1)
    cols = [np.interp(np.ravel(t), grid, flat[:, j]) for j in range(flat.shape[1])]
    return np.stack(cols, axis=-1).reshape(np.shape(t) + values.shape[1:])


def test_matches_np_interp_bit_for_bit_on_seeded_signals():
    rng = np.random.default_rng(7)
    for trial in range(60):
        S = int(rng.integers(1, 40))
        grid = np.unique(np.cumsum(rng.uniform(1e-4, 1.0, S)) - rng.uniform(0, 5))
        values = rng.normal(size=(grid.size, 3, 2)) * 10.0 ** rng.uniform(-6, 6)
        if trial % 3 == 0:
            values[rng.integers(0, grid.size)] = [[np.inf], [-np.inf], [np.nan]]  # np.interp's non-finite fallbacks
        t = np.concatenate([rng.uniform(grid[0] - 1, grid[-1] + 1, 200), grid, [np.nan, np.inf, -np.inf]])
        got = interp_rows(t, grid, values)
        assert got.shape == (t.size, 3, 2)
        np.testing.assert_array_equal(got, per_column(t, grid, values))


@settings(max_examples=150, deadline=None, derandomize=True)
@given(
    grid=hnp.arrays(float, st.integers(1, 12), elements=st.floats(-1e6, 1e6), unique=True).map(np.sort),
    columns=st.integers(1, 4),
    data=st.data(),
)
def test_matches_np_interp_on_any_grid(grid, columns, data):
    values = data.draw(hnp.arrays(float, (grid.size, columns), elements=st.floats(-1e9, 1e9)))
    t = data.draw(hnp.arrays(float, st.integers(0, 20), elements=st.floats(-2e6, 2e6)))
    np.testing.assert_array_equal(interp_rows(t, grid, values), per_column(t, grid, values))


def test_scalar_time_gives_one_row_and_grid_instants_give_rows_exactly():
    grid = np.array([0.0, 0.1, 0.3])
    q = np.array([[0.0, 1.0], [1.0, 3.0], [3.0, -1.0]])
    np.testing.assert_array_equal(interp_rows(0.2, grid, q), [2.0, 1.0])
    np.testing.assert_array_equal(interp_rows(grid, grid, q), q)
    np.testing.assert_array_equal(interp_rows([-5.0, 9.0], grid, q), q[[0, -1]])  # held at the ends
    np.testing.assert_array_equal(interp_rows([[0.05]], grid, q), [[[0.5, 2.0]]])


def test_hold_takes_the_latest_row_at_or_before():
    grid = np.array([0.0, 1.0, 2.0])
    v = np.array([[10.0], [20.0], [30.0]])
    np.testing.assert_array_equal(hold_rows([-1.0, 0.0, 0.999, 1.0 - 1e-13, 1.5, 2.0, 7.0], grid, v)[:, 0],
                                  [10, 10, 10, 20, 20, 30, 30])  # fmt: skip


@pytest.mark.adversarial
@pytest.mark.parametrize(
    "grid, values",
    [(np.zeros(0), np.zeros((0, 2))), (np.zeros((2, 2)), np.zeros((2, 2))), (np.arange(3.0), np.zeros((4, 2)))],
)
def test_bad_grids_are_one_dataset_error(grid, values):
    with pytest.raises(DatasetError, match="time grid"):
        interp_rows([0.5], grid, values)
    with pytest.raises(DatasetError, match="time grid"):
        hold_rows([0.5], grid, values)
