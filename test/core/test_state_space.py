"""Specification of the wear estimator's state-space model: process and observation maps."""

import numpy as np
import pytest
from reducer_twin.core import wear
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.state_space import lost_motion_curve, run_in_free_wear
from reducer_twin.core.state_space import wear_from_run_in_free


@pytest.fixture(scope='module')
def params():
    return ReducerParams()


def test_run_in_maps_are_inverse_and_extend_with_slope_one_below_zero(params):
    w = np.array([-2e-6, 0.0, 1e-6, 20e-6, 400e-6, 1e-3])
    free = run_in_free_wear(w, params.wear)
    np.testing.assert_allclose(wear_from_run_in_free(free, params.wear), w, rtol=1e-12, atol=1e-18)
    assert free[0] == -2e-6
    assert np.all(np.diff(free) > 0.0)


def test_run_in_free_wear_interpolates_its_table_linearly_as_np_interp_does(params):
    # The table's wear grid is uniform (wear._run_in_map): the interval is found by division.
    grid_w, grid_s = wear._run_in_map(params.wear)
    rng = np.random.default_rng(4)
    w = np.concatenate([rng.uniform(0.0, grid_w[-1], 5000), grid_w[::997], grid_w[-1:]])
    for few_or_many in (w[:50], w):
        np.testing.assert_allclose(run_in_free_wear(few_or_many, params.wear),
                                   np.interp(few_or_many, grid_w, grid_s), rtol=1e-12, atol=1e-22)
    assert np.isnan(run_in_free_wear(np.nan, params.wear))
    assert np.isnan(run_in_free_wear(np.full(5000, np.nan), params.wear)).all()


def test_the_lost_motion_curve_and_its_inverse_agree_beyond_both_ends_of_the_table(params):
    curve = lost_motion_curve(params)
    w = np.array([-3e-6, 0.0, 0.35e-6, 5e-6, 100e-6, 200e-6])
    np.testing.assert_allclose(curve.inverse(curve(w)), w, rtol=1e-9, atol=1e-15)
