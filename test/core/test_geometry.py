"""Cycloid profile (eq 16), clearances, curvature and lever arms."""

from dataclasses import replace
import math

import numpy as np
import pytest
from reducer_twin.core import geometry as geo
from reducer_twin.core.kinematics import effective_lever_radius
from reducer_twin.core.params import ReducerParams
from scipy.optimize import minimize_scalar

DENSE = 200_000   # profile samples over the whole disc (0 .. 2*pi*Zc)


@pytest.fixture(scope='module')
def params():
    return ReducerParams()


@pytest.fixture(scope='module')
def ideal(params):
    """Unmodified geometry: no shift, no equidistant modification."""
    return replace(params.geometry, equidistant_modification=0.0, shift_modification=0.0)


def _pin_distances(centres, curve, theta_max):
    """
    Distance from each pin centre to a parametric closed curve.

    A dense sampling finds the nearest sample; a bounded Brent search between
    its neighbours refines it, so each distance is exact to rounding (the
    distance, not its argmin, which is flat where the flank hugs the pin).
    """
    theta = np.linspace(0.0, theta_max, DENSE, endpoint=False)
    step = theta[1] - theta[0]
    x, y = curve(theta)
    out = []
    for cx, cy in centres:
        k = int(np.argmin(np.hypot(x - cx, y - cy)))

        def dist(t, cx=cx, cy=cy):
            px, py = curve(np.array([t]))
            return float(np.hypot(px[0] - cx, py[0] - cy))

        best = minimize_scalar(dist, bounds=(theta[k] - step, theta[k] + step),
                               method='bounded', options={'xatol': 1e-13})
        out.append(min(best.fun, float(np.hypot(x[k] - cx, y[k] - cy))))
    return np.array(out)


def _first_derivative(f, h):
    """Five-point central first derivative at the middle sample."""
    return (f[0] - 8.0 * f[1] + 8.0 * f[3] - f[4]) / (12.0 * h)


def _second_derivative(f, h):
    """Five-point central second derivative at the middle sample."""
    return (-f[0] + 16.0 * f[1] - 30.0 * f[2] + 16.0 * f[3] - f[4]) / (12.0 * h * h)


def _printed_profile(theta, g):
    """
    Eq 16 exactly as printed: S = 1 + K1^2 - 2*K1*cos(Zc*theta) (here, not in the core).

    Parameters
    ----------
    theta : ndarray
        Profile parameter [rad].
    g : Geometry
        Geometry (modifications ignored).

    Returns
    -------
    tuple of ndarray
        x, y [m].

    """
    i_h = g.z_pins / g.z_cycloid
    k1 = g.eccentricity * g.z_pins / g.pin_circle_radius
    s = 1.0 + k1 ** 2 - 2.0 * k1 * np.cos(g.z_cycloid * theta)
    rp, rr, a = g.pin_circle_radius, g.pin_radius, g.eccentricity
    x = (rp * np.cos((1 - i_h) * theta) - a * np.cos(i_h * theta)
         + rr * s ** -0.5 * (k1 * np.cos(i_h * theta) - np.cos((1 - i_h) * theta)))
    y = (rp * np.sin((1 - i_h) * theta) + a * np.sin(i_h * theta)
         - rr * s ** -0.5 * (k1 * np.sin(i_h * theta) + np.sin((1 - i_h) * theta)))
    return x, y


def test_unmodified_profile_touches_all_40_pins(ideal):
    theta_max = 2.0 * math.pi * ideal.z_cycloid
    centres = geo.pin_centres(ideal)
    assert centres.shape == (40, 2)
    gaps = _pin_distances(centres, lambda t: geo.profile(t, ideal, modified=False),
                          theta_max) - ideal.pin_radius
    # Physics notes 2: the consistent eq 16 touches every pin (~1e-12 m).
    np.testing.assert_allclose(gaps, 0.0, atol=1e-9)


def test_modified_flag_false_ignores_the_modifications(params, ideal):
    theta = np.linspace(0.0, 2.0 * math.pi, 101)
    np.testing.assert_array_equal(geo.profile(theta, params.geometry, modified=False),
                                  geo.profile(theta, ideal))


def test_printed_form_of_eq_16_misses_the_pins_by_millimetres(ideal):
    theta_max = 2.0 * math.pi * ideal.z_cycloid
    gaps = _pin_distances(geo.pin_centres(ideal), lambda t: _printed_profile(t, ideal),
                          theta_max) - ideal.pin_radius
    # Physics notes 2: with cos(Zc*theta) the profile misses 39 of 40 pins, by up to 4.3 mm.
    assert np.count_nonzero(np.abs(gaps) > 10e-6) == 39
    assert np.max(np.abs(gaps)) == pytest.approx(4.3e-3, abs=0.05e-3)


def test_clearance_formula_agrees_with_the_exact_modified_profile(params):
    g = params.geometry
    theta_max = 2.0 * math.pi * g.z_cycloid
    exact = _pin_distances(geo.pin_centres(g), lambda t: geo.profile(t, g),
                           theta_max) - g.pin_radius
    phi = 2.0 * math.pi * np.arange(g.z_pins) / g.z_pins   # pin i at phase 2*pi*i/Zp
    formula = geo.normal_clearance(phi, g)
    # Physics notes 3: the approximation is within 0.8 um of eq 16; the brief asks 1 um.
    np.testing.assert_allclose(formula, exact, atol=1e-6)
    # +/+ modifications: 0 .. 17.9 um of flank clearance (physics notes 1).
    assert exact.min() > -1e-9
    assert exact.max() == pytest.approx(17.9e-6, abs=0.1e-6)


def test_clearance_formula_has_its_extremes_where_the_algebra_says():
    g = ReducerParams().geometry
    k1 = g.k1
    # At phi = 0 and pi the shift term is -dRp*(1 -+ K1)/(1 -+ K1) = -dRp: clearance 0.
    np.testing.assert_allclose(geo.normal_clearance(np.array([0.0, math.pi]), g), 0.0,
                               atol=1e-15)
    # At phi0 = arccos K1: drrp - dRp*sqrt(1 - K1^2) = 17.9 um.
    expected = 0.05e-3 - 0.05e-3 * math.sqrt(1.0 - k1 ** 2)
    assert geo.normal_clearance(math.acos(k1), g) == pytest.approx(expected, rel=1e-12)
    assert geo.normal_clearance(math.acos(k1), g, wear=3e-6) == pytest.approx(
        expected + 3e-6, rel=1e-12)


def test_equivalent_radius_at_the_pitch_point_is_4_65_mm():
    g = ReducerParams().geometry
    # Physics notes 2: R* = 4.65 mm at phi0 = arccos K1 = 39.8 deg.
    assert math.degrees(math.acos(g.k1)) == pytest.approx(39.8, abs=0.05)
    assert float(geo.equivalent_radius(math.acos(g.k1), g)) == pytest.approx(4.65e-3, abs=0.01e-3)


@pytest.mark.parametrize('phi', [0.1, 0.5, 0.69421, 1.0, 1.5, 2.0, 2.5, 3.0])
def test_flank_curvature_radius_matches_finite_differences(ideal, phi):
    # The point of the profile with parameter theta meets the pin of meshing phase
    # theta (mod 2*pi): pin i sits at theta = -Zc*phi_i, and -Zc*phi_i = phi_i (mod 2*pi).
    # Five-point stencils, h = 3e-3: truncation and rounding both below 1e-7 relative.
    h = 3e-3
    x, y = geo.profile(phi + h * np.arange(-2, 3), ideal, modified=False)
    dx, dy = _first_derivative(x, h), _first_derivative(y, h)
    ddx, ddy = _second_derivative(x, h), _second_derivative(y, h)
    kappa = (dx * ddy - dy * ddx) / (dx * dx + dy * dy) ** 1.5
    normal = np.array([-dy, dx]) / math.hypot(dx, dy)
    centre = np.array([x[2], y[2]]) + normal / kappa
    # Convex where the centre of curvature lies toward the disc centre (origin).
    sign = 1.0 if np.hypot(*centre) < math.hypot(x[2], y[2]) else -1.0
    expected = sign * abs(1.0 / kappa)
    assert float(geo.flank_curvature_radius(phi, ideal)) == pytest.approx(expected, rel=1e-6)


def test_flank_is_concave_at_the_tooth_root_and_convex_at_the_tip(ideal):
    # At phi = 0 the flank wraps around the pin (radius rrp + pin-curve radius); at pi convex.
    assert float(geo.flank_curvature_radius(0.0, ideal)) < -ideal.pin_radius
    assert float(geo.flank_curvature_radius(math.pi, ideal)) > 0.0


def test_lever_arms_peak_at_r_eff_at_the_pitch_point():
    g = ReducerParams().geometry
    phi = np.linspace(0.0, math.pi, 200_001)
    arms = geo.lever_arms(phi, g)
    r_eff = 2.2e-3 * 81 * 18 / 36   # physics notes 3: 89.1 mm
    assert arms.max() == pytest.approx(r_eff, rel=1e-9)
    assert phi[np.argmax(arms)] == pytest.approx(math.acos(g.k1), abs=2e-5)
    assert float(geo.lever_arms(math.acos(g.k1), g)) == pytest.approx(r_eff, rel=1e-12)
    assert np.all(arms >= 0.0)
    assert np.all(geo.lever_arms(-phi[1:-1], g) < 0.0)


def test_lines_of_action_pass_through_the_pitch_point(ideal):
    # Classical cycloid geometry: the normal at each contact passes through the pitch
    # point, so its distance from the disc centre is a*Zc*sin(phi)/sqrt(S). The lever arm of
    # the RV output is the same shape scaled to r_eff (physics notes 3).
    # The contact point is not found by a distance search: near the tooth root the flank
    # hugs the pin (radii 5.26 vs 5 mm), the distance is flat and its argmin ill-posed.
    # Instead the pin-centre curve (eq 16 with the pin radius removed) is checked to pass
    # through pin i at theta_i = -Zc*phi_i, and the normal is taken there.
    phi = 2.0 * math.pi * np.arange(1, 20) / ideal.z_pins
    theta = np.mod(-ideal.z_cycloid * phi, 2.0 * math.pi * ideal.z_cycloid)
    centres = geo.pin_centres(ideal)[1:20]
    cx, cy = geo.profile(theta, ideal, wear=-ideal.pin_radius, modified=False)
    np.testing.assert_allclose(np.stack([cx, cy], axis=1), centres, atol=1e-15)
    h = 1e-3
    stencil = theta[:, None] + h * np.arange(-2, 3)[None, :]
    x, y = geo.profile(stencil, ideal, modified=False)
    tx, ty = _first_derivative(x.T, h), _first_derivative(y.T, h)
    nx, ny = -ty / np.hypot(tx, ty), tx / np.hypot(tx, ty)
    distances = np.abs(centres[:, 0] * ny - centres[:, 1] * nx)
    scale = effective_lever_radius(ideal) / (ideal.eccentricity * ideal.z_cycloid)
    np.testing.assert_allclose(geo.lever_arms(phi, ideal), scale * distances, rtol=1e-9)


def test_pin_phases_cover_every_pin_once_per_disc():
    g = ReducerParams().geometry
    phases = geo.pin_phases(np.array([0.3]), g)
    assert phases.shape == (1, 80)
    per_disc = np.sort(phases[0, :40])
    np.testing.assert_allclose(np.diff(per_disc), 2.0 * math.pi / 40, atol=1e-12)


def test_flank_phases_are_the_positive_half_of_the_pin_phases():
    g = ReducerParams().geometry
    psi = np.array([0.0, 0.01, 1.234, 5.0])
    phi, cos_phi, sin_phi = geo.flank_phases(psi, g)
    np.testing.assert_allclose(cos_phi, np.cos(phi), atol=1e-12)
    np.testing.assert_allclose(sin_phi, np.sin(phi), atol=1e-12)
    full = geo.pin_phases(psi, g)
    for row in range(psi.size):
        want = np.sort(full[row][np.sin(full[row]) > 1e-9])
        got = np.sort(phi[row][sin_phi[row] > 1e-9])
        np.testing.assert_allclose(got, want, atol=1e-12)
