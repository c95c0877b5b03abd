"""Archard wear of the loaded mesh with the Janakiraman coefficient: Table 2, laws, integration."""

from dataclasses import replace
import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core import contact, wear
from reducer_twin.core.geometry import equivalent_radius
from reducer_twin.core.params import ReducerParams
from scipy.integrate import solve_ivp

PARAMS = ReducerParams()
T0 = 784.0                               # rated torque [N*m], paper Table 3
N0 = 15.0 * 2.0 * math.pi / 60.0         # rated output speed [rad/s], physics notes 1
HOUR = 3600.0

# Paper Table 2: "Amount of wear and tear/mm" at "Working hours/h".
PAPER_TABLE2 = {1000: 0.004732318, 2000: 0.009463114, 3000: 0.013549828,
                4000: 0.018062679, 5000: 0.021986972, 6000: 0.026377444}


def test_the_modules_copy_of_table_2_is_the_papers():
    assert wear.PAPER_TABLE2_HOURS == tuple(float(h) for h in PAPER_TABLE2)
    np.testing.assert_allclose(np.array(wear.PAPER_TABLE2_WEAR) * 1e3,
                               list(PAPER_TABLE2.values()), rtol=1e-12)


@pytest.mark.parametrize('hours', sorted(PAPER_TABLE2))
def test_paper_procedure_reproduces_table_2_within_1_percent(hours):
    model_mm = float(wear.paper_wear_table([hours], PARAMS)[0]) * 1e3
    assert model_mm == pytest.approx(PAPER_TABLE2[hours], rel=0.01)


def test_table_2_is_rate_times_time_with_the_rate_updated_every_2000_h():
    # Physics notes 2: h(t)/t is constant in pairs, i.e. one rate per 2000 h stage.
    h = wear.paper_wear_table(sorted(PAPER_TABLE2), PARAMS)
    per_hour = h / np.array(sorted(PAPER_TABLE2), dtype=float)
    np.testing.assert_allclose(per_hour[1::2], per_hour[0::2], rtol=1e-12)
    assert per_hour[0] > per_hour[2] > per_hour[4]   # run-in slows the rate


def test_one_multiplier_fitted_to_table_2_is_the_default():
    # The level is one stated number fitted to the table (a fit, not a validation).
    fitted = wear.calibrate_to_paper(PARAMS.with_overrides({'wear.rate_multiplier': 1.0}))
    assert fitted.wear.rate_multiplier == pytest.approx(PARAMS.wear.rate_multiplier, rel=1e-3)
    assert fitted.wear.run_in_fraction == PARAMS.wear.run_in_fraction
    assert fitted.wear.composite_roughness == PARAMS.wear.composite_roughness
    model = wear.paper_wear_table(wear.PAPER_TABLE2_HOURS, fitted)
    np.testing.assert_allclose(model, wear.PAPER_TABLE2_WEAR, rtol=3e-4)


def test_the_run_in_hypothesis_is_what_fits_table_2s_two_rate_steps():
    # Its only evidence: three fitted parameters for the table's three numbers.
    start = PARAMS.with_overrides({'wear.rate_multiplier': 0.5,
                                   'wear.run_in_fraction': 0.2,
                                   'wear.run_in_depth': 40e-6})
    fitted = wear.fit_run_in_to_paper(start).wear
    assert fitted.rate_multiplier == pytest.approx(PARAMS.wear.rate_multiplier, rel=1e-3)
    assert fitted.run_in_fraction == pytest.approx(PARAMS.wear.run_in_fraction, rel=0.01)
    assert fitted.run_in_depth == pytest.approx(PARAMS.wear.run_in_depth, rel=0.01)


def test_without_the_run_in_one_multiplier_meets_table_2_within_4_percent():
    # A constant rate cannot follow the table's two re-evaluation steps (4.5 % and 7.1 %).
    fitted = wear.calibrate_to_paper(PARAMS.with_overrides({'wear.run_in_fraction': 0.0}))
    error = wear.paper_wear_table(wear.PAPER_TABLE2_HOURS, fitted) / wear.PAPER_TABLE2_WEAR - 1
    assert 0.03 < np.max(np.abs(error)) < 0.04


def _rate_by_hand_from_each_pin(torque, speed, params, n_phase=64):
    """Eqs 3, 5-11 for every engaged pin of the loaded mesh, written out here."""
    g, wp = params.geometry, params.wear
    e_star = 1.0 / (2.0 * (1.0 - 0.3 ** 2) / 206e9)                  # eq 5, both GCr15/20CrMo
    psi = np.linspace(0.0, 2.0 * math.pi / 40, n_phase, endpoint=False)
    mesh = contact.solve_mesh(psi, torque, params)
    total = 0.0
    for forces, phases in zip(mesh.forces, mesh.phases):
        for f, phi in zip(forces, phases):
            if f <= 1e-6:
                continue
            r_star = float(equivalent_radius(phi, g))
            a = 1.128 * math.sqrt(f / 0.015 * r_star / e_star)        # eq 5, consistent form
            p = f / (2.0 * a * 0.015)                                   # eq 6
            k = (3.981e29 / e_star * (f / 0.015 / (e_star * r_star)) ** 1.219
                 * (2.0e-8 * e_star) ** -7.377 * (0.5e-6 / r_star) ** 1.589)   # eq 7
            total += k * p * 2.0 * a * 1.0                  # eqs 3, 8, 10: K*p*2a*lambda
    per_pass = total / n_phase / (2 * 40)       # period mean, spread over 2 discs x 40 pitches
    passes = 40 * abs(speed) / (2.0 * math.pi)                         # mesh passes per second
    return wp.rate_multiplier * per_pass * passes * 1.0                 # eq 9, epsilon = 1


@pytest.mark.parametrize('torque', [30.0, 100.0, 784.0, 2000.0])
def test_rate_is_the_depth_summed_over_the_engaged_pins(torque):
    # The tabulated fast path against a direct per-pin computation (interpolation and phase
    # sampling <= 2e-3; the half-width cancels in 2a*p = F/b, whatever its constant).
    expected = _rate_by_hand_from_each_pin(torque, N0, PARAMS)
    assert float(wear.wear_rate(torque, N0, 0.0, PARAMS)) == pytest.approx(expected, rel=2e-3)


def test_contact_depths_are_hertz_pressure_times_sliding_distance_per_pin():
    mesh = contact.solve_mesh(np.linspace(0.0, 0.1, 5), T0, PARAMS)
    r_star = equivalent_radius(mesh.phases, PARAMS.geometry)
    by_force = np.where(mesh.forces > 1e-6, wear.depth_per_pass(mesh.forces, r_star, PARAMS), 0)
    np.testing.assert_allclose(wear.contact_depths_per_pass(mesh, PARAMS), by_force,
                               rtol=1e-12, atol=1e-30)
    assert np.all(wear.contact_depths_per_pass(mesh, PARAMS)[mesh.forces <= 1e-6] == 0.0)


def test_rate_torque_exponent_follows_the_loaded_mesh_between_1_1_and_1_5():
    # Load sharing: more pins engage as the torque grows, F_max ~ T^0.5, so the rate grows
    # far slower than T^2.219 of one contact under a proportional load.
    torque = np.geomspace(100.0, 800.0, 8)
    rate = wear.wear_rate(torque, N0, 0.0, PARAMS)
    local = np.diff(np.log(rate)) / np.diff(np.log(torque))
    assert np.all((local > 1.1) & (local < 1.5))
    whole = math.log(rate[-1] / rate[0]) / math.log(8.0)
    assert 1.3 < whole < 1.5


def test_at_100_nm_the_mesh_wears_5_to_9_times_more_than_a_proportional_load_predicts():
    # Relative to rated torque (issue 12, item 4).
    ratio = float(wear.wear_rate(100.0, N0, 0.0, PARAMS) / wear.wear_rate(T0, N0, 0.0, PARAMS))
    assert 5.0 < ratio / (100.0 / T0) ** 2.219 < 9.0


@pytest.mark.parametrize('offset, low, high', [(3e-6, 0.35, 0.7), (-2e-6, 1.4, 3.6)])
def test_a_looser_unit_wears_slower_and_a_tighter_one_faster(offset, low, high):
    # K ~ R*^-2.81 (eq 7): the load moves between flank phases of very different curvature.
    g = PARAMS.geometry
    unit = PARAMS.with_overrides({'geometry.equidistant_modification':
                                  g.equidistant_modification + offset})
    torque = np.array([100.0, 400.0, T0])
    ratio = wear.wear_rate(torque, N0, 0.0, unit) / wear.wear_rate(torque, N0, 0.0, PARAMS)
    assert np.all((ratio > low) & (ratio < high))


@settings(max_examples=60)
@given(t1=st.floats(0.0, 5 * T0), t2=st.floats(0.0, 5 * T0))
def test_wear_rate_never_falls_as_the_torque_grows(t1, t2):
    lo, hi = sorted((t1, t2))
    assert float(wear.wear_rate(lo, N0, 0.0, PARAMS)) <= float(wear.wear_rate(hi, N0, 0.0, PARAMS))


def test_the_table_matches_the_exact_mesh_average_from_1_to_100_times_rated_torque():
    rng = np.random.default_rng(3)
    torque = T0 * np.exp(rng.uniform(math.log(0.01), math.log(100.0), 200))
    exact = wear.mesh_depth_per_pass(torque, PARAMS, n_phase=256)
    np.testing.assert_allclose(wear.depth_per_mesh_pass(torque, PARAMS), exact, rtol=2e-3)


def test_beyond_the_table_the_rate_continues_as_one_contact_under_a_proportional_load():
    # Every pin engaged: a fixed load-sharing shape, h ~ F^(1 + 1.219).
    torque = np.array([200.0, 1000.0]) * T0
    np.testing.assert_allclose(wear.depth_per_mesh_pass(torque, PARAMS),
                               wear.mesh_depth_per_pass(torque, PARAMS), rtol=0.02)
    d = wear.depth_per_mesh_pass(torque, PARAMS)
    assert math.log(d[1] / d[0]) / math.log(5.0) == pytest.approx(2.219, rel=1e-9)


@pytest.mark.parametrize('torque', [0.0, 0.3, 7.84, 100.0, 784.0, -784.0, 1e5, 1e7])
def test_scalar_and_array_torques_give_the_same_depth(torque):
    one = wear.depth_per_mesh_pass(torque, PARAMS)
    many = wear.depth_per_mesh_pass(np.array([torque, torque]), PARAMS)
    assert np.ndim(one) == 0
    np.testing.assert_allclose(many, [one, one], rtol=1e-12)
    assert float(wear.depth_per_mesh_pass(np.float64(torque), PARAMS)) == float(one)


def test_a_torque_that_is_not_a_number_gives_no_rate():
    rate = wear.wear_rate(np.array([math.nan, T0, math.inf]), N0, 0.0, PARAMS)
    assert math.isnan(rate[0]) and rate[1] > 0.0 and rate[2] == math.inf


def test_wear_multiplies_the_rate_by_the_run_in_of_eq_7s_roughness_term():
    for w in (5e-6, 20e-6, 60e-6):
        ratio = float(wear.wear_rate(T0, N0, w, PARAMS) / wear.wear_rate(T0, N0, 0.0, PARAMS))
        assert ratio == pytest.approx(float(wear.run_in_factor(w, PARAMS.wear)) ** 1.589,
                                      rel=1e-12)


def test_rate_multiplier_scales_the_rate():
    double = PARAMS.with_overrides({'wear.rate_multiplier': 2 * PARAMS.wear.rate_multiplier})
    assert float(wear.wear_rate(T0, N0, 3e-6, double)) == pytest.approx(
        2.0 * float(wear.wear_rate(T0, N0, 3e-6, PARAMS)), rel=1e-12)


@pytest.mark.parametrize('ratio', [0.01, 0.5, 2.0, 7.0])
def test_wear_rate_is_proportional_to_speed(ratio):
    r0 = float(wear.wear_rate(T0, N0, 5e-6, PARAMS))
    assert float(wear.wear_rate(T0, ratio * N0, 5e-6, PARAMS)) == pytest.approx(ratio * r0,
                                                                                rel=1e-12)


def test_wear_rate_ignores_the_signs_of_torque_and_speed():
    r = float(wear.wear_rate(T0, N0, 0.0, PARAMS))
    assert float(wear.wear_rate(-T0, -N0, 0.0, PARAMS)) == pytest.approx(r, rel=1e-12)


def test_wear_rate_of_the_papers_scenario_is_4_73_um_per_1000_h():
    # Physics notes 5: r_ref = 4.73 um per 1000 h at T0, n0 (the first Table-2 point).
    rate = float(wear.wear_rate(T0, wear.reference_speed(PARAMS), 0.0, PARAMS))
    assert rate * 1000 * HOUR == pytest.approx(4.732318e-6, rel=0.01)
    assert wear.reference_speed(PARAMS) == pytest.approx(N0, rel=1e-12)   # 90 deg/s


def test_zero_torque_or_zero_speed_gives_zero_wear():
    assert float(wear.wear_rate(0.0, N0, 0.0, PARAMS)) == 0.0
    assert float(wear.wear_rate(T0, 0.0, 0.0, PARAMS)) == 0.0
    dt = np.full(10, 1000 * HOUR)
    np.testing.assert_array_equal(wear.integrate_wear(dt, 0.0, N0, PARAMS), 0.0)
    np.testing.assert_array_equal(wear.integrate_wear(dt, T0, 0.0, PARAMS), 0.0)
    np.testing.assert_array_equal(wear.integrate_wear(dt, 0.0, N0, PARAMS, wear0=7e-6), 7e-6)


def _histories(max_steps=12):
    step = st.tuples(st.floats(0.0, 500 * HOUR), st.floats(0.0, 1.5 * T0),
                     st.floats(0.0, 2.0 * N0))
    return st.lists(step, min_size=1, max_size=max_steps)


@settings(max_examples=60)
@given(history=_histories())
def test_integrated_wear_is_monotone_in_time(history):
    dt, torque, speed = (np.array(x) for x in zip(*history))
    w = wear.integrate_wear(dt, torque, speed, PARAMS)
    assert w[0] >= 0.0
    assert np.all(np.diff(w) >= 0.0)
    # Steps of real operation add wear that shows in the sum (tiny ones round away).
    grows = (dt[1:] >= HOUR) & (torque[1:] >= 0.1 * T0) & (speed[1:] >= 0.1 * N0)
    assert np.all(np.diff(w)[grows] > 0.0)


@settings(max_examples=60)
@given(history=_histories(), cut=st.integers(1, 11))
def test_integrated_wear_is_additive_over_split_histories(history, cut):
    dt, torque, speed = (np.array(x) for x in zip(*history))
    cut = min(cut, dt.size)
    whole = wear.integrate_wear(dt, torque, speed, PARAMS)
    first = wear.integrate_wear(dt[:cut], torque[:cut], speed[:cut], PARAMS)
    then = wear.integrate_wear(dt[cut:], torque[cut:], speed[cut:], PARAMS, wear0=first[-1])
    np.testing.assert_allclose(np.concatenate([first, then]), whole, rtol=1e-9, atol=1e-15)


def test_integrated_wear_solves_the_rate_equation():
    # Independent path: integrate dw/dt = wear_rate(T, n, w) with an ODE solver. The rate
    # slows as the roughness runs in, so this checks the run-in map of integrate_wear.
    t_end = 30000 * HOUR
    sol = solve_ivp(lambda t, w: [float(wear.wear_rate(1.2 * T0, N0, w[0], PARAMS))],
                    (0.0, t_end), [2e-6], rtol=1e-10, atol=1e-16,
                    t_eval=np.linspace(t_end / 30, t_end, 30))
    dt = np.full(30, t_end / 30)
    w = wear.integrate_wear(dt, 1.2 * T0, N0, PARAMS, wear0=2e-6)
    np.testing.assert_allclose(w, sol.y[0], rtol=1e-5)


def test_integrated_wear_without_run_in_is_rate_times_time():
    params = PARAMS.with_overrides({'wear.run_in_fraction': 0.0})
    rate = float(wear.wear_rate(T0, N0, 0.0, params))
    dt = np.full(6, 1000 * HOUR)
    np.testing.assert_allclose(wear.integrate_wear(dt, T0, N0, params),
                               rate * np.cumsum(dt), rtol=1e-12)


def test_rate_scale_and_aging_multiply_the_first_step():
    base = wear.integrate_wear([HOUR], T0, N0, PARAMS)[0]
    scaled = wear.integrate_wear([HOUR], T0, N0, PARAMS, rate_scale=0.1, aging=20.0)[0]
    assert scaled == pytest.approx(2.0 * base, rel=1e-6)


@pytest.mark.parametrize('wear0', [380e-6, 500e-6])
def test_integration_from_a_large_initial_wear_never_loses_wear(wear0):
    w = wear.integrate_wear([0.0, HOUR], T0, N0, PARAMS, wear0=wear0)
    assert w[0] == pytest.approx(wear0, rel=1e-9)
    assert w[1] > wear0


def test_janakiraman_coefficient_is_dimensionally_consistent():
    f, r_star = 500.0, 4.65e-3
    k = float(wear.janakiraman_coefficient(f, r_star, PARAMS))
    # Same load per unit width (L uses F/b): K unchanged.
    wide = PARAMS.with_overrides({'geometry.disc_width': 0.03})
    k_wide = float(wear.janakiraman_coefficient(2 * f, r_star, wide))
    assert k_wide == pytest.approx(k, rel=1e-12)
    # All lengths times s, forces times s^2 (pressures unchanged): L, G, S and K unchanged.
    s = 1.7
    scaled = PARAMS.with_overrides({'geometry.disc_width': 0.015 * s,
                                    'wear.composite_roughness': 0.5e-6 * s})
    k_scaled = float(wear.janakiraman_coefficient(f * s * s, r_star * s, scaled))
    assert k_scaled == pytest.approx(k, rel=1e-12)
    # Pressure unit 4x smaller: E* and F (same lengths) x4, alpha0 /4. L, G, S are
    # dimensionless so unchanged, and K [1/Pa] = C/E* * ... becomes K/4.
    m = PARAMS.materials
    stiff = replace(m, pin_youngs_modulus=4 * m.pin_youngs_modulus,
                    disc_youngs_modulus=4 * m.disc_youngs_modulus)
    thin = replace(PARAMS.wear, pressure_viscosity=PARAMS.wear.pressure_viscosity / 4)
    other_units = replace(PARAMS, materials=stiff, wear=thin)
    k_units = float(wear.janakiraman_coefficient(4 * f, r_star, other_units))
    assert k_units == pytest.approx(k / 4, rel=1e-12)


def test_janakiraman_coefficient_follows_eq_7():
    # Paper eq 7 evaluated by hand at one point: K = 3.981e29/E* L^1.219 G^-7.377 S^1.589.
    f, r_star = 500.0, 4.65e-3
    e_star = 206e9 / (2 * (1 - 0.3 ** 2))
    load = f / 0.015 / (e_star * r_star)
    g = 2.0e-8 * e_star
    rough = 0.5e-6 / r_star
    k = 3.981e29 / e_star * load ** 1.219 * g ** -7.377 * rough ** 1.589
    assert float(wear.janakiraman_coefficient(f, r_star, PARAMS)) == pytest.approx(k, rel=1e-9)


def test_depth_per_pass_is_k_times_load_per_width():
    # Eqs 3, 8, 10: h = K*p*2a*lambda and 2a*p = F/b (eq 6), so the half-width cancels.
    f, r_star = 500.0, 4.65e-3
    k = float(wear.janakiraman_coefficient(f, r_star, PARAMS))
    depth = float(wear.depth_per_pass(f, r_star, PARAMS))
    assert depth == pytest.approx(k * f / 0.015, rel=1e-12)


def test_run_in_factor_falls_from_one_to_one_minus_f():
    wp = PARAMS.wear
    assert float(wear.run_in_factor(0.0, wp)) == 1.0
    assert float(wear.run_in_factor(1.0, wp)) == pytest.approx(1.0 - wp.run_in_fraction)
    assert float(wear.run_in_factor(wp.run_in_depth, wp)) == pytest.approx(
        1.0 - wp.run_in_fraction * (1.0 - math.exp(-1.0)), rel=1e-12)
