"""The paper's Tables 2, 4 and 5 next to the model (reducer_twin.core.paper)."""

import math

import numpy as np
import pytest
from reducer_twin.core import paper
from reducer_twin.core.params import ReducerParams

PARAMS = ReducerParams()

# Paper Table 2: wear [mm] at working hours.
PAPER_TABLE2_MM = {1000: 0.004732318, 2000: 0.009463114, 3000: 0.013549828,
                   4000: 0.018062679, 5000: 0.021986972, 6000: 0.026377444}
# Paper Table 4: quantity -> (theoretical, simulation, printed relative error %).
PAPER_TABLE4 = {'sun_speed_deg_s': (7290.0, 7290.0, 0.0),
                'planet_speed_deg_s': (3645.0, 3708.8, 1.8),
                'output_speed_deg_s': (90.0, 93.4, 3.8),
                'ratio': (81.0, 78.1, 3.6)}
# Paper Table 5: hours -> (maximum, minimum); arc minutes (the text quotes -0.1684' to 0.181').
PAPER_TABLE5 = {1000: (0.1810, -0.1684), 2000: (0.2016, -0.1639), 3000: (0.2389, -0.1326),
                4000: (0.3164, -0.1529), 5000: (0.4006, -0.1652), 6000: (0.4351, -0.1652)}


@pytest.fixture(scope='module')
def table2():
    return paper.table2(PARAMS)


@pytest.fixture(scope='module')
def table5():
    return paper.table5(PARAMS)


def test_table2_rows_quote_the_paper_and_stay_within_1_percent(table2):
    assert [row['hours'] for row in table2] == [float(h) for h in PAPER_TABLE2_MM]
    for row in table2:
        assert row['paper_mm'] == pytest.approx(PAPER_TABLE2_MM[int(row['hours'])], rel=1e-12)
        assert row['rel_error'] == pytest.approx(row['model_mm'] / row['paper_mm'] - 1.0,
                                                 abs=1e-12)
        assert abs(row['rel_error']) < 0.01


def test_table2_is_reproduced_with_the_one_fitted_multiplier(table2):
    # The defaults are the fit: refitting the multiplier alone moves nothing, and every row
    # is met within 0.03 %.
    from reducer_twin.core.wear import calibrate_to_paper
    refit = calibrate_to_paper(PARAMS).wear.rate_multiplier
    assert refit == pytest.approx(PARAMS.wear.rate_multiplier, rel=1e-3)
    assert max(abs(row['rel_error']) for row in table2) < 3e-4


def test_table2_says_plainly_that_it_is_a_fit_not_a_validation():
    fit = paper.table2_fit(PARAMS)
    assert fit['rate_multiplier'] == PARAMS.wear.rate_multiplier
    assert fit['run_in_fraction'] == PARAMS.wear.run_in_fraction
    assert fit['run_in_depth_um'] == pytest.approx(PARAMS.wear.run_in_depth * 1e6, rel=1e-12)
    for text in (fit['note'], paper.EXPLANATIONS['table2']):
        assert 'fit, not a validation' in text.lower()
    assert 'hypothesis' in fit['note'] and 'hypothesis' in paper.EXPLANATIONS['table2']
    assert f'{PARAMS.wear.rate_multiplier:.4g}' in fit['note']


def test_table2_continuous_integration_is_close_to_the_staged_procedure(table2):
    # The twin integrates the rate continuously; the paper multiplies a stage rate by the
    # whole elapsed time. Same rate law, so within a few percent, and monotone.
    integrated = [row['integrated_mm'] for row in table2]
    assert np.all(np.diff(integrated) > 0.0)
    for row in table2:
        assert row['integrated_mm'] == pytest.approx(row['paper_mm'], rel=0.03)


def test_table4_model_is_the_papers_theory_and_rates_its_simulation():
    t4 = paper.table4(PARAMS)
    assert t4['ratio'] == 81.0
    assert t4['output_speed_deg_s'] == pytest.approx(90.0, rel=1e-12)
    assert t4['planet_speed_deg_s'] == pytest.approx(3645.0, rel=1e-12)
    assert t4['crank_speed_relative_deg_s'] == pytest.approx(3600.0, rel=1e-12)
    assert t4['mesh_frequency_hz'] == pytest.approx(10.0, rel=1e-12)
    rows = {row['quantity']: row for row in t4['rows']}
    assert set(rows) == set(PAPER_TABLE4)
    for name, (theory, simulation, printed_percent) in PAPER_TABLE4.items():
        assert rows[name]['model'] == pytest.approx(theory, rel=1e-12)
        assert rows[name]['paper_theory'] == theory
        assert rows[name]['paper_simulation'] == simulation
        # The paper's own "Relative error/%" column, rounded to 0.1 %.
        percent = abs(rows[name]['simulation_rel_error']) * 100
        assert percent == pytest.approx(printed_percent, abs=0.051)


def test_table5_quotes_the_paper_in_arc_minutes(table5):
    assert [row['hours'] for row in table5] == [float(h) for h in PAPER_TABLE5]
    for row in table5:
        pmax, pmin = PAPER_TABLE5[int(row['hours'])]
        assert (row['paper_max_arcmin'], row['paper_min_arcmin']) == (pmax, pmin)


def test_table5_model_range_is_the_manufacturing_errors_plus_a_small_mesh_ripple(table5):
    m = PARAMS.manufacturing
    out = np.linspace(0.0, 2.0 * math.pi, 200_000, endpoint=False)
    mfg = (m.order1_amplitude * np.sin(out + m.order1_phase)
           + m.order2_amplitude * np.sin(2 * out + m.order2_phase)
           + m.crank_amplitude * np.sin(40 * out + m.crank_phase))
    mfg_ptp = (mfg.max() - mfg.min()) / (math.pi / 180 / 60)
    mfg_mid = 0.5 * (mfg.max() + mfg.min()) / (math.pi / 180 / 60)
    for row in table5:
        assert row['mfg_peak_to_peak_arcmin'] == pytest.approx(mfg_ptp, abs=1e-3)
        model_ptp = row['model_max_arcmin'] - row['model_min_arcmin']
        # Mesh ripple < 0.3 arcsec = 0.005 arcmin (physics notes 4) on top of the harmonics.
        assert abs(model_ptp - mfg_ptp) < 0.3 / 60
        # Lag (-TE) relative to the new reducer: the mean shift minus the harmonics.
        centre = 0.5 * (row['model_max_arcmin'] + row['model_min_arcmin'])
        expected = row['model_mean_shift_arcmin'] - mfg_mid
        assert centre == pytest.approx(expected, abs=0.3 / 60)


def test_table5_mean_shift_and_lost_motion_follow_the_physics_notes(table5):
    # Physics notes 4, at the Table-2 wears: mean shift and lost motion [arcmin].
    notes_shift = [0.29, 0.53, 0.71, 0.91, 1.07, 1.25]
    notes_lm = [1.36, 1.93, 2.34, 2.75, 3.08, 3.43]
    for row, shift, lm in zip(table5, notes_shift, notes_lm):
        assert row['wear_um'] == pytest.approx(PAPER_TABLE2_MM[int(row['hours'])] * 1e3,
                                               rel=0.01)
        assert row['model_mean_shift_arcmin'] == pytest.approx(shift, abs=0.02)
        assert row['model_lost_motion_arcmin'] == pytest.approx(lm, abs=0.02)


def test_every_table_has_an_explanation():
    assert set(paper.EXPLANATIONS) == {'table2', 'table4', 'table5'}
    assert all(len(text) > 40 for text in paper.EXPLANATIONS.values())
