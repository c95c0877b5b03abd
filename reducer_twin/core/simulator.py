"""
Deterministic model of one robot joint driven by an RV reducer.

The ground truth of the twin. A motion profile (constant speed as in the
paper, or a robot-like cycle between waypoints) and a load (constant, or
gravity plus inertia) give the output torque ``T(t)`` and speed; wear grows
by the Archard rate of :mod:`.wear` (physics notes section 5) times a hidden
``wear_rate_scale`` and ``aging_factor``; the wear feeds back into the
transmission error of :mod:`.transmission_error` (physics notes sections 3-4),
which the link encoder sees.

Sampling model, for sample ``k`` stamped ``t_k = k/rate_hz``:

* ``motor_angle``: ``i·q(t_k)`` plus white noise, quantised to whole motor
  encoder counts; multi-turn (never wrapped), as ros2_control reports it;
* ``link_angle``: the true output angle ``q + TE(i·q, T, w)`` at the instant
  the link encoder really sampled, ``t_k + time_offset_s``, plus the zero
  offset of the link encoder and white noise, quantised to link counts;
* ``link_velocity``: the nominal output speed ``dq/dt`` at that instant plus
  white noise (a drive's filtered velocity estimate; the rate of change of
  the TE itself, < 1e-4 of the speed, is left out);
* ``effort``: the transmitted output torque at ``t_k`` plus white noise (a
  joint torque estimate).

Noise is added before the quantiser, so positions are whole counts, as a
real encoder reports them.

Determinism: everything is computed on fixed blocks of
:data:`BLOCK_SAMPLES` samples aligned to the sample index, and each noise
stream draws exactly one block's worth per block, in block order. Whatever
the sizes passed to :meth:`JointSimulator.step`, the same seed gives
bit-identical samples.
"""

from dataclasses import dataclass
import math

import numpy as np
from scipy.integrate import quad
from scipy.optimize import brentq

from .errors import InvalidParameter, out_of_range
from .kinematics import total_ratio
from .params import _Validated, spec
from .transmission_error import lost_motion, manufacturing_te, model_tables, transmission_error
from .units import ARCMIN
from .wear import integrate_wear, run_in_factor, wear_rate

PROFILES = ('paper', 'robot')
"""Motion profiles: constant output speed (paper), or a robot-like cycle."""

LOADS = ('constant', 'gravity')
"""Loads: constant torque, or gravity ``T_g·cos(q)``; both plus ``J·dq²/dt²``."""

BLOCK_SAMPLES = 2048
"""Samples per computation block (the unit of determinism)."""

_MAX_BLOCKS_PER_PASS = 64

ROBOT_CYCLE = (
    (math.radians(150.0), 1.0, 0.30),
    (math.radians(20.0), 0.8, 0.20),
    (math.radians(170.0), 1.0, 0.40),
    (math.radians(-30.0), 0.9, 0.25),
    (math.radians(120.0), 0.7, 0.35),
    (0.0, 1.0, 0.50),
)
"""
Robot cycle from ``q = 0``: (waypoint [rad], fraction of the peak speed, dwell [s]).

Every move crosses the vertical (``q = 90 deg``), so the gravity torque
changes sign within a move, and the moves alternate in direction. The cycle
ends where it starts, so it repeats.
"""

_NOISE_STREAMS = ('motor', 'link', 'velocity', 'effort')


@dataclass(frozen=True)
class SimConfig(_Validated):
    """
    Configuration of one simulated joint (SI units; defaults: a 1 kHz robot joint).

    Attributes
    ----------
    name : str
        Joint name.
    profile : str
        ``'paper'``: constant output speed ``peak_speed_rad_s`` (the paper's
        90 deg/s); ``'robot'``: the :data:`ROBOT_CYCLE` of moves with
        S-curve (sinusoidal-ramp) velocity, dwells and reversals.
    load : str
        ``'constant'``: ``load_torque_nm``; ``'gravity'``:
        ``load_torque_nm·cos(q)``, changing sign. Both add ``J·dq²/dt²``.
    exact_mesh : bool
        True: TE by the exact loaded mesh,
        :func:`.transmission_error.transmission_error` (about 0.3 M
        samples/s; enough for live joints). False: period-mean mesh from
        :func:`.transmission_error.model_tables` plus the manufacturing
        harmonics (mesh ripple below 0.3 arcsec left out, interpolation
        error below 0.4 arcsec; several M samples/s, for offline
        generation). A field, not chosen per batch, so that the output does
        not depend on how :meth:`JointSimulator.step` is chunked.

    """

    _prefix = 'sim'
    name: str = 'joint_1'
    profile: str = 'robot'
    load: str = 'gravity'
    exact_mesh: bool = True
    rate_hz: float = spec(1000.0, 'Hz', 0.0, 1e5, 'sample rate of the encoder stream',
                          lo_open=True)
    load_torque_nm: float = spec(0.6 * 784.0, 'N*m', 0.0, 1e5,
                                 'constant load torque, or amplitude of the gravity torque')
    inertia_kg_m2: float = spec(30.0, 'kg*m^2', 0.0, 1e5, 'link inertia about the joint axis')
    peak_speed_rad_s: float = spec(math.radians(90.0), 'rad/s', 0.0, 20.0,
                                   'peak (paper: constant) output speed', lo_open=True)
    peak_accel_rad_s2: float = spec(6.0, 'rad/s^2', 0.0, 1000.0,
                                    'peak output acceleration of the robot moves', lo_open=True)
    motor_counts_per_rev: int = spec(2 ** 17, '', 1, 2 ** 40,
                                     'motor (input) encoder counts per motor revolution',
                                     integer=True)
    link_counts_per_rev: int = spec(2 ** 23, '', 1, 2 ** 40,
                                    'link (output) encoder counts per revolution', integer=True)
    motor_noise_rad: float = spec(1e-5, 'rad', 0.0, 1.0, 'motor encoder noise std (motor side)')
    link_noise_rad: float = spec(1e-6, 'rad', 0.0, 0.01, 'link encoder noise std')
    velocity_noise_rad_s: float = spec(2e-3, 'rad/s', 0.0, 10.0, 'link velocity noise std')
    effort_noise_nm: float = spec(2.0, 'N*m', 0.0, 1e4, 'effort (torque estimate) noise std')
    time_offset_s: float = spec(50e-6, 's', -0.01, 0.01,
                                'link encoder samples this much later than its stamp')
    link_zero_offset_rad: float = spec(0.0, 'rad', -7.0, 7.0, 'zero offset of the link encoder')
    wear_rate_scale: float = spec(1.0, '', 0.0, 1e4, 'hidden multiplier on the Archard rate')
    aging_factor: float = spec(1.0, '', 0.0, 1e9,
                               'seconds of wear exposure per second of stream')
    initial_wear_m: float = spec(0.0, 'm', 0.0, 100e-6, 'combined wear at the stream start')
    seed: int = spec(0, '', 0, 2 ** 63 - 1, 'seed of the noise streams', integer=True)

    def _check(self):
        if not isinstance(self.name, str) or not self.name:
            raise InvalidParameter(out_of_range('sim.name', self.name, '', 'a non-empty string'))
        for name, allowed in (('profile', PROFILES), ('load', LOADS)):
            value = getattr(self, name)
            if value not in allowed:
                raise InvalidParameter(out_of_range(
                    f'sim.{name}', value, '', 'one of ' + ', '.join(repr(a) for a in allowed)))
        if not isinstance(self.exact_mesh, bool):
            raise InvalidParameter(out_of_range('sim.exact_mesh', self.exact_mesh, '',
                                                'True or False'))


@dataclass(frozen=True)
class SimBatch:
    """
    Samples of one :meth:`JointSimulator.step` call (arrays of equal length N).

    Attributes
    ----------
    t : ndarray
        Stamps [s], ``k/rate_hz``.
    motor_angle : ndarray
        Motor (input) encoder angle [rad], multi-turn.
    link_angle : ndarray
        Link (output) encoder angle [rad], multi-turn.
    link_velocity : ndarray
        Reported link velocity [rad/s].
    effort : ndarray
        Reported output torque [N·m].
    true_wear : ndarray
        Combined wear at ``t`` [m].
    true_torque : ndarray
        Transmitted output torque at ``t`` [N·m].
    true_output_angle : ndarray
        Output angle when the link encoder sampled (``t + time_offset_s``),
        without encoder zero offset, noise or quantisation [rad].
    true_te : ndarray
        TE ``theta_out - theta_in/i`` at that instant [rad]: what
        :func:`.te_extraction.compute_te` returns from perfect encoders
        when given ``link_time_offset_s = time_offset_s`` (and, modulo
        ``2·pi/i``, the link zero offset).
    exposure_s : ndarray
        Operating seconds of wear exposure since the stream start,
        ``t·aging_factor`` [s].

    """

    t: np.ndarray
    motor_angle: np.ndarray
    link_angle: np.ndarray
    link_velocity: np.ndarray
    effort: np.ndarray
    true_wear: np.ndarray
    true_torque: np.ndarray
    true_output_angle: np.ndarray
    true_te: np.ndarray
    exposure_s: np.ndarray

    def __len__(self):
        """Return the number of samples."""
        return self.t.shape[0]


@dataclass(frozen=True)
class SimTruth:
    """
    Hidden state of the simulated joint at the next sample to be produced.

    Attributes
    ----------
    time_s : float
        Stream time [s].
    exposure_s : float
        Operating seconds of wear exposure since the stream start [s].
    wear : float
        Combined wear [m].
    lost_motion : float
        Lost motion at the catalogue test torque [rad]
        (:func:`.transmission_error.lost_motion`).
    wear_rate_scale : float
        Hidden multiplier on the Archard rate.
    lost_motion_limit : float
        Accuracy limit on lost motion [rad].
    wear_limit : float
        Wear at which lost motion reaches the limit [m].
    duty_wear_rate : float
        Run-in-free wear rate averaged over one duty cycle, scale included,
        per second of exposure [m/s].
    limit_time_s : float
        Exposure since the stream start at which lost motion reaches the
        limit under this duty [s] (negative if it was reached before the
        start, ``inf`` if the joint does not wear).

    """

    time_s: float
    exposure_s: float
    wear: float
    lost_motion: float
    wear_rate_scale: float
    lost_motion_limit: float
    wear_limit: float
    duty_wear_rate: float
    limit_time_s: float


class JointTrajectory:
    """
    Nominal output motion ``q(t)`` of a profile, evaluated vectorised.

    Robot moves use a sinusoidal velocity ramp (an S-curve: the
    acceleration rises and falls smoothly), ``v = vp·(1 - cos(pi·u/Ta))/2``
    over ``Ta = pi·vp/(2·a_max)``, a cruise at ``vp`` and the mirrored
    ramp down; a move too short to reach ``vp`` peaks lower.

    Parameters
    ----------
    config : SimConfig
        Profile, peak speed [rad/s] and peak acceleration [rad/s²].

    """

    def __init__(self, config):
        self.profile = config.profile
        self.speed = config.peak_speed_rad_s
        if self.profile == 'paper':
            self.period = 2.0 * math.pi / self.speed
            return
        a_max = config.peak_accel_rad_s2
        rows = []
        start, clock = 0.0, 0.0
        for target, fraction, dwell in ROBOT_CYCLE:
            dist = abs(target - start)
            vp = fraction * self.speed
            ramp = math.pi * vp / (2.0 * a_max)
            if dist < vp * ramp:
                vp = math.sqrt(2.0 * a_max * dist / math.pi)
                ramp = math.pi * vp / (2.0 * a_max)
            cruise = dist / vp - ramp
            rows.append((clock, start, math.copysign(1.0, target - start), dist, vp, ramp,
                         max(cruise, 0.0)))
            clock += 2.0 * ramp + max(cruise, 0.0) + dwell
            start = target
        self._seg = np.array(rows).T
        self.period = clock

    def __call__(self, t):
        """
        Evaluate position, speed and acceleration of the output.

        Parameters
        ----------
        t : ndarray
            Times [s].

        Returns
        -------
        tuple of ndarray
            ``q`` [rad], ``dq/dt`` [rad/s], ``d²q/dt²`` [rad/s²].

        """
        if self.profile == 'paper':
            return self.speed * t, np.full_like(t, self.speed), np.zeros_like(t)
        tau = np.mod(t, self.period)
        starts, q0, sgn, dist, vp, ramp, cruise = self._seg
        j = np.clip(np.searchsorted(starts, tau, side='right') - 1, 0, starts.size - 1)
        u = tau - starts[j]
        q0, sgn, dist, vp, ramp, cruise = q0[j], sgn[j], dist[j], vp[j], ramp[j], cruise[j]
        # Ramp up on [0, Ta), cruise on [Ta, Ta+Tc), ramp down (mirrored), then dwell.
        down = np.clip(2.0 * ramp + cruise - u, 0.0, None)
        r = np.where(u < ramp, u, np.minimum(down, ramp))
        phase = np.pi * r / ramp
        x_ramp = 0.5 * vp * (r - ramp / np.pi * np.sin(phase))
        v = 0.5 * vp * (1.0 - np.cos(phase))
        a = 0.5 * vp * np.pi / ramp * np.sin(phase)
        in_cruise = (u >= ramp) & (u < ramp + cruise)
        x = np.where(u < ramp, x_ramp,
                     np.where(in_cruise, 0.5 * vp * ramp + vp * (u - ramp), dist - x_ramp))
        v = np.where(in_cruise, vp, v)
        a = np.where(in_cruise, 0.0, np.where(u < ramp, a, -a))
        return q0 + sgn * x, sgn * v, sgn * a


def load_torque(q, accel, config):
    """
    Output torque the reducer transmits to the link [N·m].

    ``T = T_L + J·dq²/dt²`` (constant load) or ``T = T_g·cos(q) + J·dq²/dt²``
    (gravity, ``q = 0`` horizontal); positive drives the output forward.

    Parameters
    ----------
    q : ndarray
        Output angle [rad].
    accel : ndarray
        Output acceleration [rad/s²].
    config : SimConfig
        Load kind, ``load_torque_nm`` [N·m] and ``inertia_kg_m2`` [kg·m²].

    Returns
    -------
    ndarray
        Torque [N·m].

    """
    inertial = config.inertia_kg_m2 * accel
    if config.load == 'gravity':
        return config.load_torque_nm * np.cos(q) + inertial
    return config.load_torque_nm + inertial


class JointSimulator:
    """
    Seeded simulation of one joint: encoder streams and their hidden truth.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters (the model the truth follows).
    config : SimConfig, optional
        Joint configuration (defaults if omitted).
    lost_motion_limit : float
        Accuracy limit on lost motion [rad] (default 3 arcmin) that defines
        the end of life for :meth:`truth` and :meth:`true_rul_s`.

    Raises
    ------
    InvalidParameter
        If ``lost_motion_limit`` is not a positive finite angle.

    """

    def __init__(self, params, config=None, lost_motion_limit=3.0 * ARCMIN):
        if isinstance(lost_motion_limit, bool) or not (
                isinstance(lost_motion_limit, (int, float)) and math.isfinite(lost_motion_limit)
                and 0.0 < lost_motion_limit < 0.1):
            raise InvalidParameter(out_of_range('lost_motion_limit', lost_motion_limit, 'rad',
                                                'in (0, 0.1)'))
        self.params = params
        self.config = config if config is not None else SimConfig()
        self.lost_motion_limit = float(lost_motion_limit)
        self.ratio = total_ratio(params.geometry)
        self.trajectory = JointTrajectory(self.config)
        seeds = np.random.SeedSequence(self.config.seed).spawn(len(_NOISE_STREAMS))
        self._rngs = [np.random.default_rng(s) for s in seeds]
        self._next = 0
        self._next_block = 0
        self._block_start_wear = self.config.initial_wear_m
        self._cache_block = 0
        self._cache = None
        self.duty_wear_rate = self._cycle_mean_rate()
        self.wear_limit = self._wear_at_limit()
        self.limit_time_s = self._limit_time()

    @property
    def time_s(self):
        """Stream time of the next sample [s]."""
        return self._next / self.config.rate_hz

    def step(self, n):
        """
        Produce the next ``n`` samples.

        Parameters
        ----------
        n : int
            Number of samples (>= 0).

        Returns
        -------
        SimBatch
            The samples and their truth.

        Raises
        ------
        InvalidParameter
            If ``n`` is not a non-negative whole number.

        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise InvalidParameter(out_of_range('n', n, 'samples', 'a whole number >= 0'))
        k, stop = self._next, self._next + int(n)
        parts = []
        while k < stop:
            lo, arrays = self._arrays_for(k, stop)
            hi = min(stop, lo + arrays['t'].size)
            parts.append({name: a[k - lo:hi - lo] for name, a in arrays.items()})
            k = hi
        self._next = stop
        if not parts:
            return SimBatch(**{name: np.empty(0) for name in SimBatch.__dataclass_fields__})
        if len(parts) == 1:
            return SimBatch(**{name: a.copy() for name, a in parts[0].items()})
        return SimBatch(**{name: np.concatenate([p[name] for p in parts]) for name in parts[0]})

    def advance(self, n):
        """
        Move on ``n`` samples without producing them (a later segment of the same life).

        The wear and the noise streams advance exactly as :meth:`step` would advance
        them, so the samples that follow are bit-identical to those of one continuous
        run; whole blocks cost only the wear integration and the noise draws.

        Parameters
        ----------
        n : int
            Number of samples to pass over (>= 0).

        Raises
        ------
        InvalidParameter
            If ``n`` is not a non-negative whole number.

        """
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
            raise InvalidParameter(out_of_range('n', n, 'samples', 'a whole number >= 0'))
        stop = self._next + int(n)
        lo = self._cache_block * BLOCK_SAMPLES
        cached_end = lo + (self._cache['t'].size if self._cache is not None else 0)
        if self._cache is not None and stop <= cached_end:
            self._next = stop
            return
        # Whole blocks not computed yet, below the block that holds ``stop``.
        block, target = self._next_block, stop // BLOCK_SAMPLES
        if target > block:
            while block < target:
                m = min(target - block, _MAX_BLOCKS_PER_PASS)
                self._advance_blocks(block, m)
                block += m
            self._cache = None
            self._next = target * BLOCK_SAMPLES
        if stop > self._next:
            self.step(stop - self._next)

    def _advance_blocks(self, first, m):
        """Wear and noise draws of ``m`` whole blocks from ``first``, as in a real pass."""
        cfg, size = self.config, BLOCK_SAMPLES
        t = np.arange(first * size, (first + m) * size, dtype=float) / cfg.rate_hz
        q, speed, accel = self.trajectory(t)
        torque = load_torque(q, accel, cfg)
        dt = np.full(size, 1.0 / cfg.rate_hz)
        w = self._block_start_wear
        for j in range(m):
            sl = slice(j * size, (j + 1) * size)
            after = integrate_wear(dt, torque[sl], speed[sl], self.params, wear0=w,
                                   rate_scale=cfg.wear_rate_scale, aging=cfg.aging_factor)
            w = float(max(after[-1], w))
        scratch = np.empty(size)
        for _ in range(m):
            for rng in self._rngs:
                rng.standard_normal(out=scratch)
        self._block_start_wear = w
        self._next_block = first + m

    def truth(self):
        """
        Return the hidden state at the next sample.

        Returns
        -------
        SimTruth
            Wear, lost motion, exposure and the true time to the limit.

        """
        lo, arrays = self._arrays_for(self._next, self._next + 1)
        wear = float(arrays['true_wear'][self._next - lo])
        return SimTruth(
            time_s=self.time_s, exposure_s=self.time_s * self.config.aging_factor, wear=wear,
            lost_motion=float(lost_motion(wear, self.params)),
            wear_rate_scale=self.config.wear_rate_scale,
            lost_motion_limit=self.lost_motion_limit, wear_limit=self.wear_limit,
            duty_wear_rate=self.duty_wear_rate, limit_time_s=self.limit_time_s)

    def true_rul_s(self, now_s=None):
        """
        Return the true remaining exposure until lost motion reaches the limit [s].

        Parameters
        ----------
        now_s : float, optional
            Stream time [s]; default the time of the next sample.

        Returns
        -------
        float
            ``limit_time_s - now_s·aging_factor`` [s] (negative once crossed).

        """
        now_s = self.time_s if now_s is None else float(now_s)
        return self.limit_time_s - now_s * self.config.aging_factor

    # -- blocks ---------------------------------------------------------------------------

    def _arrays_for(self, k, stop):
        """Return ``(first index, arrays)`` of cached blocks holding sample ``k``."""
        lo = self._cache_block * BLOCK_SAMPLES
        if self._cache is None or not lo <= k < lo + self._cache['t'].size:
            first = k // BLOCK_SAMPLES
            if first != self._next_block:
                raise RuntimeError('samples are produced in order')  # unreachable by the API
            m = -(-(stop - first * BLOCK_SAMPLES) // BLOCK_SAMPLES)
            m = min(max(m, 1), _MAX_BLOCKS_PER_PASS)
            self._cache = self._compute_blocks(first, m)
            self._cache_block = first
            self._next_block = first + m
            lo = first * BLOCK_SAMPLES
        return lo, self._cache

    def _compute_blocks(self, first, m):
        """Compute ``m`` whole blocks from block ``first``; only elementwise work spans blocks."""
        cfg, params = self.config, self.params
        size = BLOCK_SAMPLES
        t = np.arange(first * size, (first + m) * size, dtype=float) / cfg.rate_hz
        q, speed, accel = self.trajectory(t)
        torque = load_torque(q, accel, cfg)
        wear = np.empty_like(t)
        dt = np.full(size, 1.0 / cfg.rate_hz)
        w = self._block_start_wear
        for j in range(m):
            sl = slice(j * size, (j + 1) * size)
            after = integrate_wear(dt, torque[sl], speed[sl], params, wear0=w,
                                   rate_scale=cfg.wear_rate_scale, aging=cfg.aging_factor)
            # The run-in map's round trip w -> s -> w may lose an ulp; wear never shrinks.
            after = np.maximum(after, w)
            wear[sl.start] = w
            wear[sl.start + 1:sl.stop] = after[:-1]
            w = float(after[-1])
        self._block_start_wear = w
        # The link encoder samples time_offset_s after its stamp.
        q_l, speed_l, accel_l = self.trajectory(t + cfg.time_offset_s)
        torque_l = load_torque(q_l, accel_l, cfg)
        if cfg.exact_mesh:
            te = np.empty_like(t)
            for j in range(m):
                sl = slice(j * size, (j + 1) * size)
                te[sl] = transmission_error(self.ratio * q_l[sl], torque_l[sl], wear[sl], params)
        else:
            te = model_tables(params).mean_te(torque_l, wear) + manufacturing_te(q_l, params)
        noise = np.empty((len(_NOISE_STREAMS), t.size))
        for j in range(m):
            for rng, row in zip(self._rngs, noise):
                rng.standard_normal(out=row[j * size:(j + 1) * size])
        out_true = q_l + te
        motor_count = 2.0 * math.pi / cfg.motor_counts_per_rev
        link_count = 2.0 * math.pi / cfg.link_counts_per_rev
        motor = self.ratio * q + cfg.motor_noise_rad * noise[0]
        link = out_true + cfg.link_zero_offset_rad + cfg.link_noise_rad * noise[1]
        return {
            't': t,
            'motor_angle': np.round(motor / motor_count) * motor_count,
            'link_angle': np.round(link / link_count) * link_count,
            'link_velocity': speed_l + cfg.velocity_noise_rad_s * noise[2],
            'effort': torque + cfg.effort_noise_nm * noise[3],
            'true_wear': wear,
            'true_torque': torque,
            'true_output_angle': out_true,
            'true_te': te,
            'exposure_s': t * cfg.aging_factor,
        }

    # -- truth ----------------------------------------------------------------------------

    def _cycle_mean_rate(self, samples=200_000):
        """Run-in-free Archard rate averaged over one duty cycle, scale included [m/s]."""
        period = self.trajectory.period
        t = (np.arange(samples) + 0.5) * (period / samples)
        q, speed, accel = self.trajectory(t)
        torque = load_torque(q, accel, self.config)
        rate = wear_rate(torque, speed, 0.0, self.params)
        return float(np.mean(rate)) * self.config.wear_rate_scale

    def _wear_at_limit(self):
        """Wear at which the exact lost motion reaches the limit [m]."""
        def excess(w):
            return lost_motion(w, self.params) - self.lost_motion_limit

        if excess(0.0) >= 0.0:
            return 0.0
        hi = 10e-6
        while excess(hi) < 0.0:
            hi *= 2.0
            if hi > 1e-2:
                return math.inf
        return brentq(excess, 0.0, hi, xtol=1e-12)

    def _run_in_free(self, w):
        """``s(w) = ∫ dw/g(w)``, ``g = (Rrms(w)/Rrms0)^1.589``: wear at the unworn rate [m]."""
        wp = self.params.wear
        value, _ = quad(lambda x: run_in_factor(x, wp) ** -wp.roughness_exponent, 0.0, w,
                        epsabs=1e-15, epsrel=1e-10, limit=200)
        return value

    def _limit_time(self):
        """Exposure from the stream start to the wear limit under the cycle-mean rate [s]."""
        if not math.isfinite(self.wear_limit):
            return math.inf
        ds = self._run_in_free(self.wear_limit) - self._run_in_free(self.config.initial_wear_m)
        if self.duty_wear_rate <= 0.0:
            return math.inf if ds > 0.0 else -math.inf
        return ds / self.duty_wear_rate


def joint_state_columns(batches, split=False):
    """
    Arrange per-joint sample blocks as the JointState columns a robot controller publishes.

    Parameters
    ----------
    batches : list
        One block per joint (``link_angle``, ``motor_angle``, ``link_velocity``,
        ``effort`` arrays of equal length).
    split : bool
        Link and motor sides on two topics (else one message with ``<joint>`` and
        ``<joint>_motor``, see :func:`joint_state_names`).

    Returns
    -------
    tuple of ndarray
        ``(position, velocity, effort, motor)``: combined, columns ``link_1, motor_1,
        link_2, ...`` with velocity and effort on the link entries only (NaN on the
        motor ones) and ``motor`` None; split, the link side per joint and the motor
        angles per joint.

    """
    if split:
        return (np.stack([b.link_angle for b in batches], axis=1),
                np.stack([b.link_velocity for b in batches], axis=1),
                np.stack([b.effort for b in batches], axis=1),
                np.stack([b.motor_angle for b in batches], axis=1))
    n, k = batches[0].link_angle.size, len(batches)
    pos = np.empty((n, 2 * k))
    vel = np.full((n, 2 * k), np.nan)
    eff = np.full((n, 2 * k), np.nan)
    for j, b in enumerate(batches):
        pos[:, 2 * j], pos[:, 2 * j + 1] = b.link_angle, b.motor_angle
        vel[:, 2 * j], eff[:, 2 * j] = b.link_velocity, b.effort
    return pos, vel, eff, None


def joint_state_names(names, split=False, motor_suffix='_motor'):
    """Return the entry names of the link-side message: ``<joint>`` and ``<joint>_motor``."""
    if split:
        return tuple(names)
    return tuple(x for name in names for x in (name, name + motor_suffix))
