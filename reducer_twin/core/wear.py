"""
Archard wear of the cycloid/pin contact with the Janakiraman coefficient.

Two uses share one rate law:

* :func:`paper_wear_table` follows the paper's procedure for Table 2: the
  depth of eq 11, ``h = K·(F/b)·λ·n·t·ε`` (eqs 5-6 make ``2·a·p = F/b``),
  evaluated as ``rate × t`` with the rate re-evaluated every 2000 h on the
  worn surface. The table's structure shows that procedure: ``h(t)/t`` is
  constant in pairs (physics notes section 2).
* :func:`integrate_wear` integrates the same rate over an arbitrary
  torque/speed history; the simulator and the estimator use it.

The representative contact is the pitch point ``phi0 = arccos K1`` (longest
lever arm) under the peak pin force of the classical no-clearance load
distribution. The rate scales as ``(n/n0)·(T/T0)^(1+1.219)`` (physics notes
section 5) and slows as the composite roughness runs in:
``Rrms(w) = Rrms0·(1 - f·(1 - exp(-w/d)))``. ``Rrms0`` sets the level; ``f``
and ``d`` are fitted to the two re-evaluations in Table 2
(:func:`calibrate_to_paper` recovers the defaults).
"""

from functools import lru_cache
import math

import numpy as np

from .contact import solve_mesh
from .geometry import equivalent_radius
from .kinematics import mesh_pass_rate, total_ratio

PAPER_TABLE2_HOURS = (1000.0, 2000.0, 3000.0, 4000.0, 5000.0, 6000.0)
"""Operating hours of the paper's Table 2."""

PAPER_TABLE2_WEAR = (0.004732318e-3, 0.009463114e-3, 0.013549828e-3,
                     0.018062679e-3, 0.021986972e-3, 0.026377444e-3)
"""Wear depths of the paper's Table 2 [m]."""


def run_in_factor(wear, wear_params):
    """
    Ratio of the run-in composite roughness to the new one, ``Rrms(w)/Rrms0``.

    Parameters
    ----------
    wear : array_like
        Accumulated combined wear depth [m].
    wear_params : Wear
        Wear parameters.

    Returns
    -------
    ndarray
        Factor in ``(1 - f, 1]``.

    """
    w = np.maximum(np.asarray(wear, dtype=float), 0.0)
    return 1.0 - wear_params.run_in_fraction * (1.0 - np.exp(-w / wear_params.run_in_depth))


def janakiraman_coefficient(force, r_star, params, wear=0.0):
    """
    Dimensional Archard coefficient of Janakiraman (eq 7) [1/Pa].

    ``K = C/E*·L^1.219·G^-7.377·S^1.589`` with ``L = (F/b)/(E*·R*)``,
    ``G = alpha0·E*``, ``S = Rrms/R*``. The prefactor already makes ``K`` a
    coefficient in 1/Pa, so it is not divided by a hardness again (physics
    notes section 2). ``L`` uses the load per unit width, which makes it
    dimensionless.

    Parameters
    ----------
    force : array_like
        Normal contact force F [N].
    r_star : array_like
        Equivalent radius R* [m].
    params : ReducerParams
        Reducer parameters.
    wear : array_like
        Accumulated wear [m] (sets the run-in roughness).

    Returns
    -------
    ndarray
        K [1/Pa].

    """
    wp = params.wear
    e_star = params.materials.effective_modulus
    force = np.maximum(np.asarray(force, dtype=float), 0.0)
    load = force / params.geometry.disc_width / (e_star * r_star)
    visc = wp.pressure_viscosity * e_star
    rough = wp.composite_roughness * run_in_factor(wear, wp) / r_star
    return (wp.janakiraman_constant / e_star * load ** wp.load_exponent
            * visc ** wp.viscosity_exponent * rough ** wp.roughness_exponent)


def depth_per_pass(force, r_star, params, wear=0.0):
    """
    Wear depth added by one meshing pass, ``K·p·2a·λ = K·(F/b)·λ`` (eqs 3, 8, 10).

    Parameters
    ----------
    force : array_like
        Normal contact force [N].
    r_star : array_like
        Equivalent radius [m].
    params : ReducerParams
        Reducer parameters.
    wear : array_like
        Accumulated wear [m].

    Returns
    -------
    ndarray
        Depth per pass [m].

    """
    k = janakiraman_coefficient(force, r_star, params, wear)
    return k * np.maximum(force, 0.0) / params.geometry.disc_width * params.wear.slide_coefficient


@lru_cache(maxsize=64)
def representative_contact(geometry, materials, rating):
    """
    Find force and equivalent radius of the contact that governs wear.

    The pitch-point contact ``phi0 = arccos K1`` under the peak pin force of
    the unmodified mesh at rated torque (the classical
    ``F_max = 4·T_c/(Zp·r)`` load, computed with the loaded-mesh model).

    Parameters
    ----------
    geometry : Geometry
        Reducer geometry.
    materials : Materials
        Materials (part of the cache key only).
    rating : Rating
        Ratings: rated torque and contact stiffness.

    Returns
    -------
    tuple of float
        ``(force [N], r_star [m])`` at rated torque.

    """
    from .params import ReducerParams
    from dataclasses import replace
    ideal = replace(geometry, equidistant_modification=0.0, shift_modification=0.0)
    params = ReducerParams(geometry=ideal, materials=materials, rating=rating)
    psi = np.linspace(0.0, 2.0 * np.pi / geometry.z_pins, 32, endpoint=False)
    mesh = solve_mesh(psi, rating.rated_torque, params)
    force = float(mesh.max_force.mean())
    r_star = float(equivalent_radius(math.acos(geometry.k1), geometry))
    return force, r_star


def wear_rate(torque, output_speed, wear, params):
    """
    Compute the combined wear rate of the governing contact, ``dw/dt`` [m/s].

    ``dw/dt = K(F)·(F/b)·λ·n·ε`` (eqs 7-11 per unit time) with
    ``F = F_ref·|T|/T0`` (fixed load-sharing shape) and ``n`` the meshing
    passes per second at the output speed.

    Parameters
    ----------
    torque : array_like
        Output torque [N·m] (sign ignored).
    output_speed : array_like
        Output speed [rad/s] (sign ignored).
    wear : array_like
        Accumulated wear [m].
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    ndarray
        Wear rate [m/s].

    """
    f_ref, r_star = representative_contact(params.geometry, params.materials, params.rating)
    force = f_ref * np.abs(np.asarray(torque, dtype=float)) / params.rating.rated_torque
    passes = mesh_pass_rate(np.asarray(output_speed, dtype=float), params.geometry)
    return (depth_per_pass(force, r_star, params, wear) * passes
            * params.wear.overlap_ratio)


def reference_speed(params):
    """
    Output speed of the paper's wear scenario: 7290 deg/s input (Table 3) [rad/s].

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    float
        Output speed [rad/s] (90 deg/s for the RV-80E).

    """
    return math.radians(7290.0) / total_ratio(params.geometry)


def paper_wear_table(hours, params):
    """
    Wear depth after ``hours`` by the paper's procedure (Table 2).

    ``h(t) = rate(w_s)·t`` at rated torque and the Table-3 speed, where the
    rate is re-evaluated at the start of every ``paper_stage_hours`` stage on
    the surface worn by then.

    Parameters
    ----------
    hours : array_like
        Operating hours [h] (edge unit, as the table).
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    ndarray
        Wear depth [m].

    """
    hours = np.atleast_1d(np.asarray(hours, dtype=float))
    stage = params.wear.paper_stage_hours
    torque, speed = params.rating.rated_torque, reference_speed(params)
    out = np.empty_like(hours)
    for k, t_h in enumerate(hours):
        n_stage = int(math.ceil(t_h / stage - 1e-9)) if t_h > 0 else 1
        w_start = 0.0
        for s in range(1, n_stage):
            w_start = float(wear_rate(torque, speed, w_start, params)) * s * stage * 3600.0
        out[k] = float(wear_rate(torque, speed, w_start, params)) * t_h * 3600.0
    return out


def integrate_wear(dt, torque, output_speed, params, wear0=0.0, rate_scale=1.0, aging=1.0):
    """
    Integrate the wear rate over a sampled torque/speed history.

    Exact for piecewise-constant torque and speed as far as the run-in
    factor is concerned to first order (the rate changes by < 1e-6 relative
    within one step at any realistic step).

    Parameters
    ----------
    dt : array_like, shape (N,)
        Duration of each step of the stream [s].
    torque, output_speed : array_like, shape (N,)
        Torque [N·m] and output speed [rad/s] during each step.
    params : ReducerParams
        Reducer parameters.
    wear0 : float
        Wear at the start [m].
    rate_scale : float
        Multiplier on the Archard rate (the field/lab mismatch).
    aging : float
        Seconds of wear exposure per second of stream.

    Returns
    -------
    ndarray, shape (N,)
        Wear after each step [m].

    """
    dt = np.asarray(dt, dtype=float)
    base = wear_rate(torque, output_speed, 0.0, params) * rate_scale * aging * dt
    # d w / d s = g(w) with s the run-in-free wear: g = run_in_factor^roughness_exponent.
    # Integrate w(s) on a fine grid of s and map back: keeps the history step exact.
    s = np.cumsum(base) + _run_in_free_equivalent(wear0, params)
    return _worn_from_free(s, params)


def _run_in_free_equivalent(wear, params, n=4096):
    """Invert :func:`_worn_from_free`: the run-in-free wear that yields ``wear``."""
    if wear <= 0.0:
        return 0.0
    grid_w, grid_s = _run_in_map(params.wear)
    if wear > grid_w[-1]:
        # Beyond the run-in the roughness is settled: ds/dw = 1/g is constant.
        g_end = run_in_factor(grid_w[-1], params.wear) ** params.wear.roughness_exponent
        return float(grid_s[-1] + (wear - grid_w[-1]) / g_end)
    return float(np.interp(wear, grid_w, grid_s))


def _worn_from_free(s, params):
    """Map run-in-free wear ``s`` (rate g = 1) to actual wear ``w`` (rate g(w))."""
    grid_w, grid_s = _run_in_map(params.wear)
    s = np.asarray(s, dtype=float)
    w = np.interp(s, grid_s, grid_w)
    beyond = s > grid_s[-1]
    if np.any(beyond):
        g_end = run_in_factor(grid_w[-1], params.wear) ** params.wear.roughness_exponent
        w = np.where(beyond, grid_w[-1] + (s - grid_s[-1]) * g_end, w)
    return w


@lru_cache(maxsize=16)
def _run_in_map(wear_params):
    """
    Tabulate ``s(w) = ∫ dw / g(w)`` with ``g = (Rrms(w)/Rrms0)^1.589``.

    Parameters
    ----------
    wear_params : Wear
        Wear parameters.

    Returns
    -------
    tuple of ndarray
        ``(w, s)`` grids [m], ``w`` up to 20 run-in depths.

    """
    w = np.linspace(0.0, 20.0 * wear_params.run_in_depth, 20001)
    inv_g = 1.0 / run_in_factor(w, wear_params) ** wear_params.roughness_exponent
    s = np.concatenate([[0.0], np.cumsum(0.5 * (inv_g[1:] + inv_g[:-1]) * np.diff(w))])
    return w, s


def calibrate_to_paper(params):
    """
    Fit roughness level and run-in law to the paper's Table 2.

    Parameters
    ----------
    params : ReducerParams
        Starting parameters (geometry, materials, lubricant).

    Returns
    -------
    ReducerParams
        Copy with ``wear.composite_roughness``, ``wear.run_in_fraction`` and
        ``wear.run_in_depth`` fitted (least squares on log wear).

    """
    from scipy.optimize import least_squares
    target = np.log(np.asarray(PAPER_TABLE2_WEAR))

    def residual(x):
        trial = params.with_overrides({'wear.composite_roughness': math.exp(x[0]) * 1e-6,
                                       'wear.run_in_fraction': x[1],
                                       'wear.run_in_depth': math.exp(x[2]) * 1e-6})
        return np.log(paper_wear_table(PAPER_TABLE2_HOURS, trial)) - target

    w = params.wear
    x0 = [math.log(w.composite_roughness * 1e6), w.run_in_fraction,
          math.log(w.run_in_depth * 1e6)]
    fit = least_squares(residual, x0, bounds=([-5, 0.0, -3], [3, 0.9, 8]), xtol=1e-12)
    return params.with_overrides({'wear.composite_roughness': math.exp(fit.x[0]) * 1e-6,
                                  'wear.run_in_fraction': fit.x[1],
                                  'wear.run_in_depth': math.exp(fit.x[2]) * 1e-6})
