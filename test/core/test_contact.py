"""Loaded mesh (load sharing of all pins) and Hertz line contact."""

from dataclasses import replace
import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core import contact
from reducer_twin.core.geometry import flank_phases, lever_arms_cs, normal_clearance_cs
from reducer_twin.core.params import ReducerParams

PARAMS = ReducerParams()
T0 = 784.0                       # rated torque [N*m], paper Table 3
R_EFF = 2.2e-3 * 81 * 18 / 36    # a*i*Zs/Zpl [m], physics notes 3
PHASES_PER_DISC = 40 // 2 + 1    # contacts per disc that can push a positive torque


def _no_clearance_params():
    g = replace(PARAMS.geometry, equidistant_modification=0.0, shift_modification=0.0)
    return replace(PARAMS, geometry=g)


def _levers_by_hand(phases, geometry):
    """Lever arms r_eff*sin(phi)/sqrt(S) (physics notes 3), written out here."""
    k1 = geometry.eccentricity * geometry.z_pins / geometry.pin_circle_radius
    return R_EFF * np.sin(phases) / np.sqrt(1.0 + k1 ** 2 - 2.0 * k1 * np.cos(phases))


def _one_period(n=64):
    return np.linspace(0.0, 2.0 * math.pi / 40, n, endpoint=False)


def test_without_clearance_half_the_pins_carry_load_and_the_peak_is_classical():
    mesh = contact.solve_mesh(_one_period(), T0, _no_clearance_params())
    per_disc = [np.count_nonzero(mesh.forces[:, k * PHASES_PER_DISC:(k + 1) * PHASES_PER_DISC]
                                 > 0.0, axis=1) for k in range(2)]
    # Classical result: about half of the Zp = 40 pins are loaded, 20 per disc.
    for counts in per_disc:
        assert np.all((counts >= 19) & (counts <= 21))
        assert np.median(counts) == 20
    # Textbook (e.g. Blanche & Yang; physics notes 3): with force proportional to lever,
    # T_c = sum F_max*l_i^2/r over the loaded half, and sum sin^2/S over it is Zp/4, so
    # F_max = 4*T_c/(Zp*r) with T_c = T/2 per disc and r the longest lever arm. For a simple
    # cycloid drive r = a*Zc, i.e. 4*T_c/(K1*Zc*Rp); referred to the RV output the lever
    # radius is r_eff = a*i*Zs/Zpl = 89.1 mm, so the oracle is 4*T_c/(Zp*r_eff).
    f_classical = 4.0 * (T0 / 2.0) / (40 * R_EFF)
    np.testing.assert_allclose(mesh.max_force, f_classical, rtol=0.01)


@settings(max_examples=60)
@given(psi=st.floats(0.0, 2.0 * math.pi),
       torque=st.floats(-5.0 * T0, 5.0 * T0).filter(lambda t: abs(t) > 1e-3),
       wear=st.floats(0.0, 100e-6))
def test_torque_balance_holds_and_forces_are_non_negative(psi, torque, wear):
    mesh = contact.solve_mesh(np.array([psi]), torque, PARAMS, wear)
    assert np.all(mesh.forces >= 0.0)
    levers = _levers_by_hand(mesh.phases, PARAMS.geometry)
    # A negative torque loads the mirrored flanks: their lever arms are negative.
    balance = float(np.sum(mesh.forces * levers))
    assert balance == pytest.approx(torque, rel=1e-9)
    assert np.sign(mesh.beta[0]) == np.sign(torque)


def test_forces_follow_the_contact_law():
    psi = _one_period(16)
    mesh = contact.solve_mesh(psi, T0, PARAMS, 5e-6)
    g = PARAMS.geometry
    k1 = g.k1
    c = np.cos(mesh.phases)
    clearance = (g.equidistant_modification
                 - g.shift_modification * (1 - k1 * c) / np.sqrt(1 + k1 ** 2 - 2 * k1 * c)
                 + 5e-6)
    levers = _levers_by_hand(mesh.phases, g)
    expected = 4e8 * np.maximum(mesh.beta[:, None] * levers - clearance, 0.0)
    np.testing.assert_allclose(mesh.forces, np.where(levers > 0, expected, 0.0),
                               rtol=1e-9, atol=1e-9)


def test_zero_torque_gives_zero_forces():
    mesh = contact.solve_mesh(_one_period(8), 0.0, PARAMS, 10e-6)
    # Rounding of beta*l - d at the first contact leaves ~1e-12 N (k_n = 4e8 N/m).
    np.testing.assert_allclose(mesh.forces, 0.0, atol=1e-9)


def test_zero_torque_leaves_no_pin_loaded():
    mesh = contact.solve_mesh(_one_period(8), 0.0, PARAMS, 10e-6)
    assert np.all(mesh.loaded_pins == 0)


def test_reference_results_at_rated_torque_with_the_papers_modifications():
    mesh = contact.solve_mesh(_one_period(), T0, PARAMS)
    for k in range(2):
        counts = np.count_nonzero(
            mesh.forces[:, k * PHASES_PER_DISC:(k + 1) * PHASES_PER_DISC] > 0.0, axis=1)
        # Physics notes 3 (checked): 11-13 loaded pins per disc.
        assert counts.min() >= 11 and counts.max() <= 13
    summary = contact.contact_summary(mesh, PARAMS)
    # Physics notes 3 (checked): F_max ~ 1240 N, Hertz p_max ~ 1.06 GPa.
    assert mesh.max_force.max() == pytest.approx(1240.0, rel=0.05)
    assert summary['peak_pressure'].max() == pytest.approx(1.06e9, rel=0.05)


def test_peak_pin_force_grows_as_about_the_square_root_of_torque():
    # Load sharing with clearance: more pins engage as the torque grows, so the peak force is
    # far from proportional to T (issue 12: F_max ~ T^0.5-0.63) between 100 and 800 N*m.
    torque = np.geomspace(100.0, 800.0, 8)
    peak = np.array([contact.solve_mesh(_one_period(), t, PARAMS).max_force.mean()
                     for t in torque])
    local = np.diff(np.log(peak)) / np.diff(np.log(torque))
    assert np.all((local > 0.45) & (local < 0.65))


def test_effective_modulus_is_113_gpa():
    # 1/E* = (1-mu1^2)/E1 + (1-mu2^2)/E2 (paper eq 5); physics notes 2: E* = 113.2 GPa.
    assert PARAMS.materials.effective_modulus == pytest.approx(206e9 / (2 * (1 - 0.3 ** 2)))
    assert PARAMS.materials.effective_modulus == pytest.approx(113.2e9, rel=1e-3)


@pytest.mark.parametrize('force, radius', [(1240.0, 4.65e-3), (100.0, 2e-3), (5000.0, 0.05)])
def test_hertz_half_width_is_johnsons_line_contact(force, radius):
    width, e_star = 15e-3, 113.2e9
    p = force / width   # load per unit length
    # Johnson, Contact Mechanics (1985), eq 4.43: a^2 = 4*P*R/(pi*E*).
    johnson = math.sqrt(4.0 * p * radius / (math.pi * e_star))
    assert float(contact.hertz_half_width(force, width, radius, e_star)) == pytest.approx(
        johnson, rel=1e-12)
    # Paper eq 5 in its consistent form: 1.128*sqrt(F*R*/(b*E*)) (physics notes 2).
    assert johnson == pytest.approx(1.128 * math.sqrt(force * radius / (width * e_star)),
                                    rel=1e-3)


@given(force=st.floats(1e-3, 1e5), factor=st.floats(1e-3, 1e3))
def test_hertz_half_width_grows_as_the_square_root_of_the_load(force, factor):
    a1 = float(contact.hertz_half_width(force, 15e-3, 4.65e-3, 113.2e9))
    a2 = float(contact.hertz_half_width(force * factor, 15e-3, 4.65e-3, 113.2e9))
    assert a2 / a1 == pytest.approx(math.sqrt(factor), rel=1e-12)


@pytest.mark.parametrize('force, radius', [(1240.0, 4.65e-3), (100.0, 2e-3)])
def test_peak_pressure_is_johnsons_and_four_over_pi_times_the_mean(force, radius):
    width, e_star = 15e-3, 113.2e9
    half = contact.hertz_half_width(force, width, radius, e_star)
    mean = float(contact.hertz_mean_pressure(force, width, half))
    peak = float(contact.hertz_peak_pressure(force, width, half))
    assert mean == pytest.approx(force / (2.0 * float(half) * width), rel=1e-12)   # eq 6
    assert peak == pytest.approx(4.0 / math.pi * mean, rel=1e-12)
    # Johnson eq 4.45 written without the half-width: p0 = sqrt(P*E*/(pi*R)).
    assert peak == pytest.approx(math.sqrt(force / width * e_star / (math.pi * radius)),
                                 rel=1e-12)


def test_mean_pressure_of_an_unloaded_contact_is_zero():
    assert float(contact.hertz_mean_pressure(0.0, 15e-3, 0.0)) == 0.0


def _engagement_by_scanning(lever, clear, target):
    """
    Solve by brute force: sort the thresholds, scan the piecewise-linear segments.

    f(beta) = sum over engaged contacts of (beta*l - d)*l. With the first k contacts
    (by threshold d/l) engaged, f is linear and equals the target at
    beta_k = (target + sum d*l)/(sum l^2); that beta_k is the root if it lies in
    [t_k, t_k+1]. A zero target returns the first threshold (no play taken up).
    """
    out = np.empty(lever.shape[0])
    for row in range(lever.shape[0]):
        ok = lever[row] > 0.0
        l_row, d_row = lever[row][ok], clear[row][ok]
        order = np.argsort(d_row / l_row)
        l_row, d_row = l_row[order], d_row[order]
        thresholds = np.append(d_row / l_row, np.inf)
        if target[row] == 0.0:
            out[row] = thresholds[0]
            continue
        for k in range(1, l_row.size + 1):
            beta = (target[row] + np.sum(d_row[:k] * l_row[:k])) / np.sum(l_row[:k] ** 2)
            if thresholds[k - 1] <= beta <= thresholds[k]:
                out[row] = beta
                break
        else:
            raise AssertionError('no segment holds the root')
    return out


def test_newton_engagement_rotation_matches_a_brute_force_scan_on_the_real_mesh():
    rng = np.random.default_rng(20240611)
    n = 300
    psi = rng.uniform(0.0, 2.0 * math.pi, n)
    wear = rng.uniform(0.0, 60e-6, n)
    torque = np.concatenate([rng.uniform(0.0, 0.1 * T0, n // 2),
                             rng.uniform(0.0, 5.0 * T0, n - n // 2)])
    torque[:5] = 0.0
    g = PARAMS.geometry
    _, cos_phi, sin_phi = flank_phases(psi, g)
    lever = np.where(sin_phi > 0.0, lever_arms_cs(cos_phi, sin_phi, g), 0.0)
    clear = normal_clearance_cs(cos_phi, g, wear[:, None])
    target = torque / PARAMS.rating.contact_stiffness
    newton = contact._engagement_rotation(lever, clear, target)
    np.testing.assert_allclose(newton, _engagement_by_scanning(lever, clear, target),
                               rtol=0.0, atol=1e-12)


def test_newton_engagement_rotation_matches_a_brute_force_scan_on_random_contacts():
    # Random lever arms (some zero: cannot engage), clearances of either sign
    # (interference) and targets spanning a few contacts to all engaged.
    rng = np.random.default_rng(7)
    n, m = 400, 25
    lever = np.where(rng.random((n, m)) < 0.2, 0.0, rng.uniform(1e-3, 0.1, (n, m)))
    clear = rng.uniform(-5e-6, 50e-6, (n, m))
    target = 10.0 ** rng.uniform(-14.0, -4.0, n)
    newton = contact._engagement_rotation(lever, clear, target)
    np.testing.assert_allclose(newton, _engagement_by_scanning(lever, clear, target),
                               rtol=0.0, atol=1e-12)


def test_negative_torque_mirrors_the_positive_solution():
    psi = _one_period(32)
    plus = contact.solve_mesh(psi, T0, PARAMS, 8e-6)
    minus = contact.solve_mesh(-psi, -T0, PARAMS, 8e-6)
    # The mesh is symmetric under phi -> -phi: -T at -psi is the mirror of +T at +psi.
    np.testing.assert_allclose(minus.beta, -plus.beta, rtol=1e-12)
    np.testing.assert_allclose(np.sort(minus.forces, axis=1), np.sort(plus.forces, axis=1),
                               rtol=1e-9, atol=1e-9)
