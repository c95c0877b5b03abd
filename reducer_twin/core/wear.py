"""
Archard wear of the cycloid/pin contacts with the Janakiraman coefficient.

The rate comes from the loaded mesh (:mod:`.contact`): every pin engaged at
once wears at its own load and phase, the depth per pass of each from its
Hertz pressure and sliding distance (eqs 3, 5-8, 10-11, ``K`` of eq 7),
summed over the engaged pins and averaged over the mesh period
(:func:`mesh_depth_per_pass`). Load sharing makes this grow as about
``T^1.4`` between 10 and 1000 N·m (local slopes 1.37-1.43), where one
contact under a proportional load would give ``T^2.219``. The law is tabulated once per
parameter set over torque and interpolated (:func:`depth_per_mesh_pass`),
so :func:`wear_rate` stays as cheap as a closed form for the estimator and
the simulator.

Calibration, stated plainly: eq 7 is far too sensitive to predict a level
(physics notes section 2), so one multiplier, ``wear.rate_multiplier``, sets
the level; :func:`calibrate_to_paper` fits it to the paper's Table 2. That
is a fit, not a validation: the table has three independent numbers (one
rate per 2000 h stage, ``h(t)/t`` constant in pairs) and the paper gives no
measured wear. The two later stage rates are 4.5 % and 7.1 % below the first;
the run-in law of the roughness (:func:`run_in_factor`) is a hypothesis that
reproduces them, fitted to those same two numbers (:func:`fit_run_in_to_paper`)
and checked by nothing else.

* :func:`paper_wear_table` follows the paper's procedure for Table 2, ``rate
  × t`` with the rate re-evaluated every 2000 h on the worn surface.
* :func:`integrate_wear` integrates the same rate over an arbitrary
  torque/speed history; the simulator and the estimator use it.
"""

from dataclasses import dataclass, replace
from functools import lru_cache
import math

import numpy as np

from .contact import hertz_half_width, hertz_mean_pressure, LOADED_FORCE, solve_mesh
from .geometry import equivalent_radius
from .kinematics import mesh_pass_rate, total_ratio
from .table_store import digest, stored_table

MESH_PHASE_SAMPLES = 64
"""Samples of the eccentric angle over one mesh period (the period average is within 1e-4)."""

TABLE_TORQUE_RANGE = (1e-3, 100.0)
"""Torques of the rate table, as fractions of the rated torque."""

TABLE_POINTS = 321
"""Points of the rate table (log-spaced in torque, 3.7 % apart)."""

TABLE_PHASE_SAMPLES = 32
"""Eccentric-angle samples per torque of the table (the period average is within 5e-4)."""

DEPTH_TABLE_VERSION = 1
"""Bump when the depth table's content changes for the same parameters (it is stored)."""

PAPER_TABLE2_HOURS = (1000.0, 2000.0, 3000.0, 4000.0, 5000.0, 6000.0)
"""Operating hours of the paper's Table 2."""

PAPER_TABLE2_WEAR = (0.004732318e-3, 0.009463114e-3, 0.013549828e-3,
                     0.018062679e-3, 0.021986972e-3, 0.026377444e-3)
"""Wear depths of the paper's Table 2 [m]."""


def run_in_factor(wear, wear_params):
    """
    Ratio of the run-in composite roughness to the new one, ``Rrms(w)/Rrms0``.

    ``Rrms(w) = Rrms0·(1 - f·(1 - exp(-w/d)))``, entering the rate through
    ``S^1.589`` of eq 7. A hypothesis: its only evidence is the paper's
    Table 2, whose rate falls by 4.5 % and 7.1 % at the 2000 h and 4000 h
    re-evaluations without the paper saying why; ``f = 7.3 %`` and
    ``d = 19 µm`` are fitted to those two numbers (:func:`fit_run_in_to_paper`)
    and no measurement checks them. Set ``wear.run_in_fraction`` to 0 to
    drop it (the paper's table is then met within 4 % instead of 0.03 %).

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


def contact_depths_per_pass(mesh, params, wear=0.0):
    """
    Archard depth per meshing pass of every contact of a loaded mesh.

    Each contact at its own load and phase: Hertz half-width ``a`` (eq 5)
    and mean pressure ``p = F/(2·a·b)`` (eq 6) at the equivalent radius of
    its phase, wear rate ``I_h = K·p`` (eq 3, ``K`` of eq 7 in 1/Pa),
    sliding distance ``S = 2·a·λ`` (eq 8), depth ``h = S·I_h`` (eqs 10-11
    for one pass). ``2·a·p = F/b``, so this equals
    :func:`depth_per_pass` at the contact's force and radius.

    Parameters
    ----------
    mesh : LoadedMesh
        Output of :func:`.contact.solve_mesh`, shape (N, M).
    params : ReducerParams
        Reducer parameters.
    wear : array_like
        Accumulated wear [m] (sets the run-in roughness of eq 7).

    Returns
    -------
    ndarray, shape (N, M)
        Depth per pass [m]; 0 where a contact carries no load.

    """
    g = params.geometry
    e_star = params.materials.effective_modulus
    force = np.where(mesh.forces > LOADED_FORCE, mesh.forces, 0.0)
    r_star = equivalent_radius(mesh.phases, g)
    half = hertz_half_width(force, g.disc_width, r_star, e_star)
    pressure = hertz_mean_pressure(force, g.disc_width, half)
    k = janakiraman_coefficient(force, r_star, params, wear)
    return k * pressure * 2.0 * half * params.wear.slide_coefficient


def mesh_depth_per_pass(torque, params, n_phase=MESH_PHASE_SAMPLES):
    """
    Uniform wear depth per meshing pass from the loaded mesh (exact, slow path).

    The depths of :func:`contact_depths_per_pass` summed over the contacts
    engaged at once (both discs), averaged over one mesh period of the
    eccentric angle (``2·pi/Zp``, ``n_phase`` samples), and spread over the
    ``n_discs·Zp`` pin pitches of the flanks: the worn volume of one pass
    (Archard, eq 1) as a uniform depth. In one pass every point of a flank
    meets a pin once, at its own phase, so this is the flank average of the
    depth of eq 11. The load sharing (engaged pins, their forces, clearance
    and modification) is that of the as-built mesh: the twin's wear is a
    uniform clearance, and under a uniform clearance the load would move to
    the pins of longest lever (the sum falls about 5-fold by 20 µm), while
    real wear removes most where the load is; how the load spreads as the
    flanks wear is not modelled.

    Parameters
    ----------
    torque : array_like
        Output torque [N·m] (sign ignored: the mesh is mirror-symmetric).
    params : ReducerParams
        Reducer parameters.
    n_phase : int
        Samples of the eccentric angle over one mesh period.

    Returns
    -------
    ndarray
        Depth per pass [m], shape of ``torque``, without the run-in and the
        rate multiplier.

    """
    torque = np.abs(np.asarray(torque, dtype=float))
    g = params.geometry
    flat = torque.reshape(-1)
    psi = np.linspace(0.0, 2.0 * np.pi / g.z_pins, n_phase, endpoint=False)
    mesh = solve_mesh(np.tile(psi, flat.size), np.repeat(flat, n_phase), params)
    per_sample = contact_depths_per_pass(mesh, params).sum(axis=1)
    per_torque = per_sample.reshape(flat.size, n_phase).mean(axis=1)
    return (per_torque / (g.n_discs * g.z_pins)).reshape(torque.shape)


@dataclass(frozen=True)
class DepthTable:
    """
    Depth per pass of the loaded mesh at torques evenly spaced in ``ln |T|``.

    Attributes
    ----------
    torque : ndarray
        Torques [N·m].
    depth : ndarray
        Depth per pass at each torque [m].
    step : ndarray
        ``diff(depth)`` [m].
    ln_first : float
        ``ln`` of the first torque.
    per_ln : float
        Intervals per unit of ``ln |T|``.
    slope : float
        Log-log slope beyond the table, ``1 + 1.219`` (eq 7).

    """

    torque: np.ndarray
    depth: np.ndarray
    step: np.ndarray
    ln_first: float
    per_ln: float
    slope: float


@lru_cache(maxsize=16)
def _depth_table(geometry, materials, rating, wear_params):
    """
    Tabulate the depth per pass at torques evenly spaced in ``ln |T|``.

    Parameters
    ----------
    geometry, materials, rating : Geometry, Materials, Rating
        Reducer parameters (cache key).
    wear_params : Wear
        Wear parameters with the multiplier and run-in neutralised (cache key).

    Returns
    -------
    DepthTable
        The table, read-only.

    """
    from .params import ReducerParams
    params = ReducerParams(geometry=geometry, materials=materials, rating=rating,
                           wear=wear_params)
    lo, hi = (math.log(rating.rated_torque * f) for f in TABLE_TORQUE_RANGE)
    torque = np.exp(np.linspace(lo, hi, TABLE_POINTS))
    key = digest('depth per mesh pass', params, TABLE_PHASE_SAMPLES, torque.tobytes(),
                 DEPTH_TABLE_VERSION)
    depth = stored_table(key, torque.shape,
                         lambda: mesh_depth_per_pass(torque, params, TABLE_PHASE_SAMPLES))
    step = np.diff(depth)
    for a in (torque, depth, step):
        a.setflags(write=False)
    return DepthTable(torque=torque, depth=depth, step=step, ln_first=lo,
                      per_ln=(TABLE_POINTS - 1) / (hi - lo),
                      slope=1.0 + wear_params.load_exponent)


@lru_cache(maxsize=16)
def _table_for(params):
    """Return the depth table of ``params`` (the multiplier and run-in act outside it)."""
    neutral = replace(params.wear, rate_multiplier=1.0, run_in_fraction=0.0)
    return _depth_table(params.geometry, params.materials, params.rating, neutral)


def depth_per_mesh_pass(torque, params):
    """
    Uniform wear depth per meshing pass at a torque, from the tabulated mesh.

    :func:`mesh_depth_per_pass` tabulated once per parameter set at torques
    3.7 % apart from 1e-3 to 100 times the rated torque and interpolated
    linearly between them (the interval found by arithmetic, no search):
    within 2e-3 of the exact period average from 0.01 to 100 times the rated
    torque (tested). Beyond the table the law continues with the slope of a
    fixed load-sharing shape, ``h ∝ F^(1+1.219)`` (eq 7): the mesh's own
    slope once every pin carries load (within 2 % up to 1e4 times the rated
    torque); below 1e-3·T0, where the rate is under 1e-4 of the rated one,
    an order of magnitude only.

    Parameters
    ----------
    torque : array_like
        Output torque [N·m] (sign ignored).
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    ndarray
        Depth per pass [m], 0 at zero torque; without the run-in and the
        rate multiplier.

    """
    tab = _table_for(params)
    if isinstance(torque, (float, int)) and tab.torque[0] <= abs(torque) <= tab.torque[-1]:
        u = (math.log(abs(torque)) - tab.ln_first) * tab.per_ln
        k = min(int(u), tab.step.size - 1)
        return np.float64(tab.depth[k] + (u - k) * tab.step[k])
    t = np.abs(np.asarray(torque, dtype=float))
    with np.errstate(divide='ignore', invalid='ignore'):
        u = (np.log(t) - tab.ln_first) * tab.per_ln
    # fmax/fmin map -inf, inf and NaN into the table; those values are replaced below.
    u = np.fmin(np.fmax(u, 0.0), tab.depth.size - 1.000001)
    k = u.astype(np.intp)
    out = tab.depth[k] + (u - k) * tab.step[k]
    beyond = ~((t >= tab.torque[0]) & (t <= tab.torque[-1]))
    if np.any(beyond):
        tb = t[beyond] if t.ndim else t
        end = np.where(tb < tab.torque[0], 0, -1)
        if out.ndim:
            out[beyond] = tab.depth[end] * (tb / tab.torque[end]) ** tab.slope
        else:
            out = tab.depth[end] * (tb / tab.torque[end]) ** tab.slope
    return out


def wear_rate(torque, output_speed, wear, params):
    """
    Compute the combined wear rate from the loaded mesh, ``dw/dt`` [m/s].

    ``dw/dt = m·h(|T|)·n·ε·(Rrms(w)/Rrms0)^1.589``: ``h`` the uniform depth
    per pass of the as-built loaded mesh summed over the engaged pins
    (:func:`depth_per_mesh_pass`; eqs 3, 5-8, 10-11 per pin), ``n`` the
    meshing passes per second at the output speed and ``ε`` the overlap
    ratio (eq 9), the run-in of the roughness through ``S^1.589`` of eq 7
    (a hypothesis, see :func:`run_in_factor`), and ``m`` the one multiplier
    fitted to the paper's Table 2 (``wear.rate_multiplier``).

    The torque law follows the load sharing: as more pins engage, the peak
    force grows as about ``T^0.5`` and the rate as about ``T^1.4`` between
    10 and 1000 N·m, not as ``T^2.219`` of a fixed load-sharing shape. It
    also follows the clearance pattern: eq 7 makes ``K ∝ R*^-2.81``, so the
    strongly curved flank phases that carry the load in the as-built mesh
    dominate, and a unit built 3 µm looser (load moved towards the flatter
    phases) wears 0.39-0.66 times as fast at 100-784 N·m, one 2 µm tighter
    1.5-3.5 times.

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
    wp = params.wear
    passes = mesh_pass_rate(np.asarray(output_speed, dtype=float), params.geometry)
    run_in = run_in_factor(wear, wp) ** wp.roughness_exponent
    return (wp.rate_multiplier * depth_per_mesh_pass(torque, params) * passes
            * wp.overlap_ratio * run_in)


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
    Fit the one rate multiplier to the paper's Table 2 (a fit, not a validation).

    Least squares on ``ln h`` over the six points of the paper's procedure
    (:func:`paper_wear_table`) with every other parameter, the run-in
    hypothesis included, as given.

    Parameters
    ----------
    params : ReducerParams
        Starting parameters.

    Returns
    -------
    ReducerParams
        Copy with ``wear.rate_multiplier`` fitted.

    """
    def trial(x):
        return params.with_overrides({'wear.rate_multiplier': math.exp(x[0])})

    return _fit_table2(trial, [math.log(params.wear.rate_multiplier)], xtol=1e-14)


def fit_run_in_to_paper(params):
    """
    Fit the run-in hypothesis and the multiplier to Table 2 together.

    This is how the defaults of ``wear.run_in_fraction`` and
    ``wear.run_in_depth`` were found: three parameters for the table's three
    independent numbers (the level and the two re-evaluation steps), so the
    table is met by construction and is no evidence for the law's form.

    Parameters
    ----------
    params : ReducerParams
        Starting parameters.

    Returns
    -------
    ReducerParams
        Copy with ``wear.rate_multiplier``, ``wear.run_in_fraction`` and
        ``wear.run_in_depth`` fitted (least squares on ``ln h``).

    """
    def trial(x):
        return params.with_overrides({'wear.rate_multiplier': math.exp(x[0]),
                                      'wear.run_in_fraction': x[1],
                                      'wear.run_in_depth': math.exp(x[2]) * 1e-6})

    w = params.wear
    x0 = [math.log(w.rate_multiplier), w.run_in_fraction, math.log(w.run_in_depth * 1e6)]
    return _fit_table2(trial, x0, bounds=([-20, 0.0, -3], [20, 0.9, 8]), xtol=1e-12)


def _fit_table2(trial, x0, **options):
    """
    Least squares on ``ln h`` against Table 2 of the parameters ``trial(x)`` makes.

    Parameters
    ----------
    trial : callable
        ``x -> ReducerParams``.
    x0 : list of float
        Start.
    **options
        For ``scipy.optimize.least_squares`` (bounds, tolerances).

    Returns
    -------
    ReducerParams
        ``trial`` of the fitted ``x``.

    """
    from scipy.optimize import least_squares
    target = np.log(np.asarray(PAPER_TABLE2_WEAR))

    def residual(x):
        return np.log(paper_wear_table(PAPER_TABLE2_HOURS, trial(x))) - target

    return trial(least_squares(residual, x0, **options).x)
