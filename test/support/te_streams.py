"""Simulated joint streams and their window analysis, shared by the TE and window tests."""

from functools import lru_cache
import math

import numpy as np
from reducer_twin.core.kinematics import total_ratio
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.te_extraction import compute_te
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN
from reducer_twin.core.window_analysis import WindowAnalyzer

PARAMS = ReducerParams()
RATIO = total_ratio(PARAMS.geometry)   # 81, paper Table 4
TWO_PI = 2.0 * math.pi


@lru_cache(maxsize=None)
def simulated(profile='robot', load='gravity', wear=8e-6, samples=40000, exact=True, seed=5,
              aging=0.0, scale=1.0):
    """Simulate one joint (cached: several tests read the same stream)."""
    cfg = SimConfig(profile=profile, load=load, initial_wear_m=wear, aging_factor=aging,
                    wear_rate_scale=scale, exact_mesh=exact, seed=seed, link_zero_offset_rad=0.4)
    sim = JointSimulator(PARAMS, cfg)
    return sim, sim.step(samples)


def analyse(batch, **kw):
    """Extract TE (stamps taken as exact) and return all window features."""
    stream = compute_te(batch.t, batch.motor_angle, batch.t, batch.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS, **kw)
    return analyzer.update(stream, batch.effort, batch.link_velocity) + analyzer.flush()


def analyzed(batch, **kw):
    """Return the analyzer after a whole simulated batch (stamps taken as exact)."""
    stream = compute_te(batch.t, batch.motor_angle, batch.t, batch.link_angle, RATIO)
    analyzer = WindowAnalyzer(PARAMS, **kw)
    analyzer.update(stream, batch.effort, batch.link_velocity)
    analyzer.flush()
    return analyzer


def rms_without_offset(err):
    """RMS after removing the constant (the encoders' unknown zero offset)."""
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean((err - err.mean()) ** 2)))


def soft_zone_swing(zone_arcmin, knee_fraction, seed=0, period_s=6.0, rate_hz=1000.0):
    """
    Return a joint swinging through the vertical, its curve a soft zone to a knee.

    Under 200 N*m of gravity and a 6-s swing its load passes the lost-motion test torque
    at about 250 N*m/s: at 1 kHz the bin there gets some 25 samples a crossing, and loads
    reach 180 N*m; a shorter swing or a lower rate gives it fewer. Returns 60 s: stamps
    [s], link angle [rad], its rate [rad/s], TE [rad] and effort [N*m] (the load with
    2 N*m of noise; no friction in it).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(60.0 * rate_hz))) / rate_hz
    theta = 0.5 * math.pi + 1.2 * np.sin(TWO_PI * t / period_s)
    omega = 1.2 * TWO_PI / period_s * np.cos(TWO_PI * t / period_s)
    torque = 200.0 * np.cos(theta)
    knee = knee_fraction * PARAMS.rating.rated_torque
    stiffness = model_tables(PARAMS).series_stiffness
    te = (-0.5 * zone_arcmin * ARCMIN * np.clip(torque / knee, -1.0, 1.0) - torque / stiffness
          + rng.normal(0.0, 0.5 * ARCMIN / 60.0, t.size))
    return t, theta, omega, te, torque + rng.normal(0.0, 2.0, t.size)


def within_zone_swing(play_arcmin, zone_arcmin, knee_nm, seed=0, rate_hz=1000.0):
    """
    Return a joint swinging through the vertical whose loads never leave its soft zone.

    Under 60 N*m of gravity and a 6-s swing, every load lies below the knee at ``knee_nm``:
    the curve has ``play_arcmin`` of play and a soft zone ``zone_arcmin`` wide at the knee,
    taken up in proportion to the load, so its width at the lost-motion test torque is
    ``play + zone * 23.5 / knee`` less nothing but the windup, and the flanks' extrapolation
    to no load reads about the play. Returns 60 s as :func:`soft_zone_swing`.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(60.0 * rate_hz))) / rate_hz
    theta = 0.5 * math.pi + 1.2 * np.sin(TWO_PI * t / 6.0)
    omega = 1.2 * TWO_PI / 6.0 * np.cos(TWO_PI * t / 6.0)
    torque = 60.0 * np.cos(theta)
    stiffness = model_tables(PARAMS).series_stiffness
    te = (-0.5 * play_arcmin * ARCMIN * np.tanh(torque / 0.5)
          - 0.5 * zone_arcmin * ARCMIN * np.clip(torque / knee_nm, -1.0, 1.0)
          - torque / stiffness + rng.normal(0.0, 0.5 * ARCMIN / 60.0, t.size))
    return t, theta, omega, te, torque + rng.normal(0.0, 2.0, t.size)
