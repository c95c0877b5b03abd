#!/usr/bin/env python3
"""
Third joint generator: RV-80E recordings from catalogue-style physics and a real controller.

A third source of truth, unlike both the twin's model and
``bench/independent_generator.py`` (it imports nothing from ``reducer_twin``;
it borrows the second generator's constants, recording fields, sample clock,
quantiser, bag writer and command line). Every range below was fixed before
the twin was run on it.

* **Torsional curve, catalogue style.** The twist under output torque ``T``
  is a soft zone plus a straight line: ``(W/2)*min(|T|/T1, 1)*sign(T) + T/k2``
  (stiffness ``k1`` below the knee torque ``T1``, ``k2`` above it, as
  reducer catalogues give them): ``T1`` drawn in 2-6 % of rated, so at the
  +-3 % test torque the zone may be only partly taken up; ``k2`` within
  +-20 % of the RV-80E catalogue 196 N*m/arcmin. No play operator, no Hertz
  tables.
* **Hysteresis loss** (friction in the bearings and pins): a Dahl loop in
  torque, ``-(H/2)*z``, ``z -> sign(dT)`` with e-folding torque ``Th``
  (``H`` drawn 0.1-0.4 arcmin, ``Th`` 2-8 % of rated), constant over life.
* **Lost motion truth** is the catalogue's: the width of the torsional curve
  at +-3 % rated torque at the middle of the hysteresis loop, without the
  elastic windup ``2*T/k2``: ``LM = W*min(0.03*T_rated/T1, 1)``; available
  at every sample.
* **Wear exposure**: sliding distance times load at the pins,
  ``E = integral |w|*(|T| + P0)/T_rated dt`` (pin preload ``P0`` drawn 5-20 %
  of rated), not a power of the torque.
* **Growth law**: run-in exponential plus linear wear, with for 30 % of the
  units a rate step (contamination) at a random point:
  ``LM = LM_new + A*(1 - exp(-x/x_r)) + b*(min(x, x_c) + m*max(x - x_c, 0))``,
  ``x = E/E_life``; ``LM_new`` 0.3-1.0 arcmin, ``A`` 0.05-0.3 arcmin,
  ``x_r`` 0.01-0.08, ``x_c`` 0.2-0.7, ``m`` 2-4 (1 without contamination);
  ``b`` makes ``LM = 3`` arcmin at ``x = 1``. ``E_life`` is the exposure of a
  drawn life of 3 000-30 000 h (log-uniform) at the duty's mean exposure rate
  (from a separate long draw of the same duty), so under the recording's own
  random duty the limit comes near, not exactly at, the drawn life.
* **Duty, not periodic.** Cycles of 2-6 moves between random waypoints in
  each kind's range (a joint holds still in 15 % of the moves), trapezoidal
  velocity profiles (acceleration share 15-45 %, speed override 30-100 %),
  the robot's moves synchronised on the slowest joint, dwells of
  0.1 s + exponential(0.6 s) (at most 4 s) and a 0.5-3 s part exchange
  at the end of every cycle; a payload drawn 0-1 per cycle adds gravity
  (10-40 %) and inertia (20-80 %). Torque
  ``T = (G + Gp*u)*cos(q - qg) + (J + Jp*u)*a + c*w``.
* **Effort** (what the drive reports as torque): a direction-dependent
  efficiency ``eta`` (0.70-0.90): the motor gives ``T/eta`` when it drives
  the load and ``T*eta`` when the load back-drives it; plus a no-load
  running torque 0.5-1.5 % of rated, a motor torque ripple at 24 per motor
  turn (0.5-2 % of rated), noise 0.5-3 % of rated, all scaled by the
  torque-constant error 0.95-1.05.
* **Encoders.** Link encoder eccentricity: a 1x error of 10-40 arcsec on
  the link reading; the reducer's mesh error at the pin count (40x) of
  1-5 arcsec; the motor encoder's per-revolution error (60-180 arcsec at the
  motor shaft) seen at the ratio; link latched 0-1 ms before the motor;
  quantisation 19-23 bits (link) and 17-23 bits (motor), link noise
  0.05-0.5 arcsec. Velocity: the controller's backward difference of the
  motor encoder over the ratio.
* **Timing.** 100-1000 Hz; stamps with 5-40 us jitter per topic; 0-1 % of
  the messages dropped on each topic (combined layout: one message, one
  drop); log times after the stamps by a random delivery delay.

Layouts, bag format and options as the independent generator's
(``--layout split|combined``, ``--motor-angles``, ``--effort-on``,
``--no-velocity``, truths on ``/truth/<joint>``); ``remaining_life_h`` in
the truth is at the duty's mean exposure rate.

Usage::

    python bench/third_generator.py --out BAG --seed 3 [--kinds base,shoulder,forearm]
        [--hours 0.05] [--aging-factor 1] [--start-fraction 0.4] [--rate-hz 125]
        [--layout split|combined] [--json]
"""

from dataclasses import dataclass, replace
import math
from pathlib import Path
import sys

sys.path.insert(0, str(Path(__file__).resolve().parent))
import independent_generator as indep  # noqa: E402
import numpy as np  # noqa: E402

RATIO = indep.RATIO
RATED_TORQUE_NM = indep.RATED_TORQUE_NM
LIMIT_ARCMIN = indep.LIMIT_ARCMIN
TEST_TORQUE_FRACTION = indep.TEST_TORQUE_FRACTION
ARCMIN, ARCSEC, HOUR = indep.ARCMIN, indep.ARCSEC, indep.HOUR
START_S = indep.START_S
AGING_KEY = indep.AGING_KEY
TRUTH_FIELDS = indep.TRUTH_FIELDS
KINDS = indep.KINDS
LAYOUTS = indep.LAYOUTS
RATES_HZ = indep.RATES_HZ
GeneratorError = indep.GeneratorError

VERSION = 1
"""Bump when the physics or a draw changes (cached windows keyed on it)."""

CATALOGUE_STIFFNESS_NM_PER_ARCMIN = 196.0
"""RV-80E torsional rigidity [N*m/arcmin] (catalogue), the centre of ``k2``."""

PIN_COUNT = 40
"""Pins of the RV-80E cycloid stage: the order of the mesh error per output turn."""

RIPPLE_ORDER = 24
"""Motor torque ripple per motor turn (4 pole pairs, 6 per electrical period)."""

CONTAMINATED_SHARE = 0.3
"""Share of units whose wear rate steps up at a random point of life."""

MAX_MESSAGES = indep.MAX_MESSAGES

# Per kind: gravity and peak inertial torque over rated, the waypoint range [deg],
# speed and acceleration limits [rad/s, rad/s^2].
_KIND = {
    'base': {'gravity': (0.0, 0.0), 'inertial': (0.10, 0.40), 'range': (-170.0, 170.0),
             'v_max': 1.6, 'a_max': 3.5},
    'shoulder': {'gravity': (0.30, 0.80), 'inertial': (0.05, 0.20), 'range': (20.0, 160.0),
                 'v_max': 1.3, 'a_max': 3.0},
    'forearm': {'gravity': (0.15, 0.50), 'inertial': (0.05, 0.20), 'range': (-20.0, 180.0),
                'v_max': 1.6, 'a_max': 4.0},
    'wrist': {'gravity': (0.02, 0.10), 'inertial': (0.02, 0.10), 'range': (-150.0, 150.0),
              'v_max': 2.5, 'a_max': 7.0},
}


def _rng(seed, *key):
    return np.random.default_rng([int(seed), 3, *key])


# --------------------------------------------------------------------------- truth


@dataclass(frozen=True)
class JointTruth:
    """
    One drawn reducer, its load and its sensors (SI inside; the unit in every name).

    Attributes
    ----------
    name, kind : str
        Joint name and kind (one of :data:`KINDS`).
    lost_motion_new_rad : float
        Catalogue lost motion of the new unit [rad].
    stiffness_nm_per_rad : float
        ``k2``, the stiffness above the knee torque [N*m/rad].
    knee_torque_nm : float
        ``T1``, the torque that takes the soft zone up [N*m].
    hysteresis_rad, hysteresis_torque_nm : float
        Hysteresis loss ``H`` and the Dahl loop's e-folding torque ``Th``.
    run_in_rad, run_in_fraction : float
        ``A`` and ``x_r`` of the run-in term.
    contamination_fraction, contamination_factor : float
        ``x_c`` and ``m`` of the rate step (``m`` = 1: none).
    pin_preload_fraction : float
        ``P0`` over rated torque in the exposure.
    life_h : float
        Operating hours from new to the limit at the duty's mean exposure rate [h].
    efficiency : float
        ``eta`` of the drive and back-drive directions.
    no_load_nm, ripple_nm, ripple_phase, effort_noise_nm, torque_constant_scale : float
        Effort: no-load running torque, motor ripple, noise, torque-constant error.
    gravity_nm, payload_gravity_nm, gravity_angle_rad : float
        Gravity torque amplitude, its payload share at full payload, its zero.
    inertia_kg_m2, payload_inertia_kg_m2, drag_nm_s : float
        Link inertia (set by :func:`draw_robot`), its payload share, link drag.
    inertial_fraction : float
        Drawn peak inertial torque over rated (gives ``inertia_kg_m2``).
    range_rad : tuple of float
        Waypoint range.
    eccentricity_rad, eccentricity_phase : float
        Link encoder's 1x error.
    mesh_error_rad, mesh_phase : float
        Reducer's error at the pin count.
    motor_error_rad, motor_error_phase : float
        Motor encoder's per-revolution error, at the motor shaft.
    link_offset_rad, motor_offset_rad : float
        Encoder zeros.
    link_bits, motor_bits : int
        Counts per turn as powers of two.
    link_noise_rad : float
        Link encoder noise.
    link_latency_s : float
        How long before the motor the link encoder latches.

    """

    name: str
    kind: str
    lost_motion_new_rad: float
    stiffness_nm_per_rad: float
    knee_torque_nm: float
    hysteresis_rad: float
    hysteresis_torque_nm: float
    run_in_rad: float
    run_in_fraction: float
    contamination_fraction: float
    contamination_factor: float
    pin_preload_fraction: float
    life_h: float
    efficiency: float
    no_load_nm: float
    ripple_nm: float
    ripple_phase: float
    effort_noise_nm: float
    torque_constant_scale: float
    gravity_nm: float
    payload_gravity_nm: float
    gravity_angle_rad: float
    inertia_kg_m2: float
    payload_inertia_kg_m2: float
    drag_nm_s: float
    inertial_fraction: float
    range_rad: tuple
    eccentricity_rad: float
    eccentricity_phase: float
    mesh_error_rad: float
    mesh_phase: float
    motor_error_rad: float
    motor_error_phase: float
    link_offset_rad: float
    motor_offset_rad: float
    link_bits: int
    motor_bits: int
    link_noise_rad: float
    link_latency_s: float

    @property
    def test_share(self):
        """Return the share of the soft zone taken up at the test torque (<= 1)."""
        return min(TEST_TORQUE_FRACTION * RATED_TORQUE_NM / self.knee_torque_nm, 1.0)

    def lost_motion(self, fraction_of_life):
        """
        Catalogue lost motion at a fraction ``x = E/E_life`` of the life's exposure [rad].

        Parameters
        ----------
        fraction_of_life : float or array_like
            ``x`` (>= 0; 1 at the limit).

        Returns
        -------
        float or ndarray
            ``LM_new + A*(1 - exp(-x/x_r)) + b*(min(x, x_c) + m*max(x - x_c, 0))``.

        """
        x = np.maximum(np.asarray(fraction_of_life, dtype=float), 0.0)
        lm = self.lost_motion_new_rad + self._run_in(x) + self._linear_rate() * self._linear(x)
        return float(lm) if lm.ndim == 0 else lm

    def _run_in(self, x):
        return self.run_in_rad * (1.0 - np.exp(-x / self.run_in_fraction))

    def _linear(self, x):
        xc = self.contamination_fraction
        return np.minimum(x, xc) + self.contamination_factor * np.maximum(x - xc, 0.0)

    def _linear_rate(self):
        rest = LIMIT_ARCMIN * ARCMIN - self.lost_motion_new_rad - float(self._run_in(1.0))
        return rest / float(self._linear(1.0))

    def twist(self, torque, lost_motion, loop):
        """
        Twist of the output against the input under a torque [rad].

        Parameters
        ----------
        torque : ndarray
            Transmitted torque [N*m].
        lost_motion : ndarray
            Catalogue lost motion at each sample [rad].
        loop : ndarray
            Dahl state ``z`` in [-1, 1] (:func:`dahl_state`).

        Returns
        -------
        ndarray
            ``(W/2)*min(|T|/T1, 1)*sign(T) + T/k2 - (H/2)*z``, ``W = LM/test_share``.

        """
        width = lost_motion / self.test_share
        zone = np.clip(torque / self.knee_torque_nm, -1.0, 1.0)
        return (0.5 * width * zone + torque / self.stiffness_nm_per_rad
                - 0.5 * self.hysteresis_rad * loop)


def draw_joint(seed, index, kind):
    """
    Draw one joint's unit, load and sensors from its own random stream.

    Parameters
    ----------
    seed : int
        Recording seed.
    index : int
        Joint index (0-based); names are ``joint_<index+1>``.
    kind : str
        One of :data:`KINDS`.

    Returns
    -------
    JointTruth
        The joint, its inertia still 0 (:func:`draw_robot` sets it).

    """
    rng = _rng(seed, 1, index)
    k = _KIND[kind]
    rated = RATED_TORQUE_NM
    contaminated = rng.uniform() < CONTAMINATED_SHARE
    x_c, m = rng.uniform(0.2, 0.7), rng.uniform(2.0, 4.0)
    gravity = rng.uniform(*k['gravity']) * rated
    return JointTruth(
        name=f'joint_{index + 1}', kind=kind,
        lost_motion_new_rad=rng.uniform(0.3, 1.0) * ARCMIN,
        stiffness_nm_per_rad=CATALOGUE_STIFFNESS_NM_PER_ARCMIN * rng.uniform(0.8, 1.2) / ARCMIN,
        knee_torque_nm=rng.uniform(0.02, 0.06) * rated,
        hysteresis_rad=rng.uniform(0.1, 0.4) * ARCMIN,
        hysteresis_torque_nm=rng.uniform(0.02, 0.08) * rated,
        run_in_rad=rng.uniform(0.05, 0.3) * ARCMIN, run_in_fraction=rng.uniform(0.01, 0.08),
        contamination_fraction=x_c if contaminated else 1.0,
        contamination_factor=m if contaminated else 1.0,
        pin_preload_fraction=rng.uniform(0.05, 0.2),
        life_h=math.exp(rng.uniform(math.log(3000.0), math.log(30000.0))),
        efficiency=rng.uniform(0.70, 0.90), no_load_nm=rng.uniform(0.005, 0.015) * rated,
        ripple_nm=rng.uniform(0.005, 0.02) * rated, ripple_phase=rng.uniform(-math.pi, math.pi),
        effort_noise_nm=rng.uniform(0.005, 0.03) * rated,
        torque_constant_scale=rng.uniform(0.95, 1.05),
        gravity_nm=gravity, payload_gravity_nm=gravity * rng.uniform(0.1, 0.4),
        gravity_angle_rad=math.radians(rng.uniform(-10.0, 10.0)), inertia_kg_m2=0.0,
        payload_inertia_kg_m2=rng.uniform(0.2, 0.8), drag_nm_s=rng.uniform(0.002, 0.01) * rated,
        inertial_fraction=rng.uniform(*k['inertial']),
        range_rad=(math.radians(k['range'][0]), math.radians(k['range'][1])),
        eccentricity_rad=rng.uniform(10.0, 40.0) * ARCSEC,
        eccentricity_phase=rng.uniform(-math.pi, math.pi),
        mesh_error_rad=rng.uniform(1.0, 5.0) * ARCSEC, mesh_phase=rng.uniform(-math.pi, math.pi),
        motor_error_rad=rng.uniform(60.0, 180.0) * ARCSEC,
        motor_error_phase=rng.uniform(-math.pi, math.pi),
        link_offset_rad=rng.uniform(-0.01, 0.01), motor_offset_rad=rng.uniform(-200.0, 200.0),
        link_bits=int(rng.integers(19, 24)), motor_bits=int(rng.integers(17, 24)),
        link_noise_rad=rng.uniform(0.05, 0.5) * ARCSEC, link_latency_s=rng.uniform(0.0, 1e-3))


# --------------------------------------------------------------------------- duty


@dataclass(frozen=True)
class Duty:
    """
    The robot's moves: every joint's move from ``start_s`` for ``move_s``, then a dwell.

    Attributes
    ----------
    start_s, move_s : ndarray, shape (M,)
        Start and duration of each move [s].
    accel_share : ndarray, shape (M,)
        Share of the move spent accelerating (and as much decelerating).
    payload : ndarray, shape (M,)
        Payload in [0, 1] during the move and the dwell after it.
    origin_rad, step_rad : ndarray, shape (M, joints)
        Each joint's position at the move's start and its displacement.

    """

    start_s: np.ndarray
    move_s: np.ndarray
    accel_share: np.ndarray
    payload: np.ndarray
    origin_rad: np.ndarray
    step_rad: np.ndarray

    def motion(self, j, t):
        """
        Position, speed, acceleration and payload of joint ``j`` at times ``t``.

        Each move follows the trapezoidal velocity profile of acceleration share
        ``f``: ``s = v*tau^2/(2f)``, ``v*(tau - f/2)``, ``1 - v*(1 - tau)^2/(2f)``
        with ``v = 1/(1 - f)``, ``tau = (t - start)/duration``.

        Parameters
        ----------
        j : int
            Joint index.
        t : ndarray
            Time of the recording [s].

        Returns
        -------
        tuple of ndarray
            ``(q, dq/dt, d2q/dt2, payload)`` [rad, rad/s, rad/s^2, -].

        """
        t = np.asarray(t, dtype=float)
        m = np.clip(np.searchsorted(self.start_s, t, side='right') - 1, 0, len(self.start_s) - 1)
        dur, f = self.move_s[m], self.accel_share[m]
        tau = np.clip((t - self.start_s[m]) / dur, 0.0, 1.0)
        v = 1.0 / (1.0 - f)
        rise, fall = tau < f, tau > 1.0 - f
        s = np.where(rise, 0.5 * v * tau ** 2 / f,
                     np.where(fall, 1.0 - 0.5 * v * (1.0 - tau) ** 2 / f, v * (tau - 0.5 * f)))
        ds = np.where(rise, v * tau / f, np.where(fall, v * (1.0 - tau) / f, v))
        dds = np.where(rise, v / f, np.where(fall, -v / f, 0.0))
        moving = (t - self.start_s[m]) < dur
        d = self.step_rad[m, j]
        q = self.origin_rad[m, j] + d * s
        qd = np.where(moving, d * ds / dur, 0.0)
        qdd = np.where(moving, d * dds / dur ** 2, 0.0)
        return q, qd, qdd, self.payload[m]


def draw_duty(rng, joints, duration_s):
    """
    Draw the robot's moves until ``duration_s`` is covered.

    Parameters
    ----------
    rng : numpy.random.Generator
        The duty's random stream.
    joints : list of JointTruth
        The robot's joints (kinds, ranges).
    duration_s : float
        Time to cover [s].

    Returns
    -------
    Duty
        Moves in time order.

    """
    n_j = len(joints)
    lows = np.array([j.range_rad[0] for j in joints])
    highs = np.array([j.range_rad[1] for j in joints])
    v_max = np.array([_KIND[j.kind]['v_max'] for j in joints])
    a_max = np.array([_KIND[j.kind]['a_max'] for j in joints])
    q = rng.uniform(lows, highs)
    start, moves, shares, loads, origins, steps = [], [], [], [], [], []
    t = -rng.uniform(0.0, 3.0)
    while t < duration_s:
        payload = rng.uniform(0.0, 1.0)
        n_moves = int(rng.integers(2, 7))
        for i in range(n_moves):
            target = np.where(rng.uniform(size=n_j) < 0.85, rng.uniform(lows, highs), q)
            d = target - q
            f = rng.uniform(0.15, 0.45)
            override = rng.uniform(0.3, 1.0)
            v = 1.0 / (1.0 - f)
            need = np.maximum(np.abs(d) * v / (v_max * override),
                              np.sqrt(np.abs(d) * v / (f * a_max * override)))
            dur = max(float(np.max(need)), 0.2)
            start.append(t)
            moves.append(dur)
            shares.append(f)
            loads.append(payload)
            origins.append(q)
            steps.append(d)
            dwell = min(0.1 + rng.exponential(0.6), 4.0)
            if i == n_moves - 1:
                dwell += rng.uniform(0.5, 3.0)
            t += dur + dwell
            q = target
    return Duty(np.array(start), np.array(moves), np.array(shares), np.array(loads),
                np.array(origins).reshape(-1, n_j), np.array(steps).reshape(-1, n_j))


def draw_robot(seed, kinds):
    """
    Draw the joints of one robot.

    Parameters
    ----------
    seed : int
        Recording seed.
    kinds : sequence of str
        Kind of each joint.

    Returns
    -------
    tuple
        ``(joints, mean_exposure_rate)``: list of :class:`JointTruth` (inertia set
        so that the kind's acceleration limit gives the drawn peak inertial
        torque) and each joint's mean exposure rate over a 2000 s reference draw
        of the duty [1/s of operation].

    """
    joints = []
    for i, kind in enumerate(kinds):
        j = draw_joint(seed, i, kind)
        inertia = j.inertial_fraction * RATED_TORQUE_NM / _KIND[kind]['a_max']
        joints.append(replace(j, inertia_kg_m2=inertia,
                              payload_inertia_kg_m2=j.payload_inertia_kg_m2 * inertia))
    reference = draw_duty(_rng(seed, 5), joints, 2000.0)
    t = np.arange(0.0, 2000.0, 2e-3)
    rates = []
    for i, j in enumerate(joints):
        q, qd, qdd, u = reference.motion(i, t)
        rates.append(float(np.mean(exposure_rate(j, true_torque(j, q, qd, qdd, u), qd))))
    return joints, np.array(rates)


def true_torque(joint, q, qd, qdd, payload):
    """Return the torque the reducer output transmits [N*m] (gravity, inertia, drag)."""
    gravity = (joint.gravity_nm + joint.payload_gravity_nm * payload) * \
        np.cos(q - joint.gravity_angle_rad)
    inertia = joint.inertia_kg_m2 + joint.payload_inertia_kg_m2 * payload
    return gravity + inertia * qdd + joint.drag_nm_s * qd


def exposure_rate(joint, torque, speed):
    """Return ``|w|*(|T| + P0)/T_rated`` [rad/s]: sliding distance times the load at the pins."""
    return np.abs(speed) * (np.abs(torque) / RATED_TORQUE_NM + joint.pin_preload_fraction)


def drive_torque(joint, torque, speed, motor_angle):
    """
    Torque the drive reports for the transmitted torque [N*m at the output].

    The motor gives ``T/eta`` when it drives the load and ``T*eta`` when the load
    back-drives it (blended over 0.01 rad/s around standstill), plus the no-load
    running torque and the motor's torque ripple, scaled by the torque-constant error.
    """
    moving = np.tanh(speed / 0.01)
    drive = np.maximum(np.sign(torque) * moving, 0.0)
    back = np.maximum(-np.sign(torque) * moving, 0.0)
    eta = joint.efficiency
    shaft = torque * (1.0 + (1.0 / eta - 1.0) * drive - (1.0 - eta) * back)
    shaft = shaft + joint.no_load_nm * moving + joint.ripple_nm * np.sin(
        RIPPLE_ORDER * motor_angle + joint.ripple_phase)
    return joint.torque_constant_scale * shaft


def dahl_state(joint, torque):
    """
    Dahl hysteresis state in [-1, 1] along a torque history.

    ``z_k = s + (z_{k-1} - s)*exp(-|dT|/Th)``, ``s = sign(dT)``, from 0.

    Parameters
    ----------
    joint : JointTruth
        The joint (``hysteresis_torque_nm`` = Th).
    torque : ndarray
        Transmitted torque in time order [N*m].

    Returns
    -------
    ndarray
        ``z`` per sample.

    """
    dt = np.diff(torque, prepend=torque[:1])
    keep = np.exp(-np.abs(dt) / joint.hysteresis_torque_nm).tolist()
    side = np.sign(dt).tolist()
    z = np.empty(len(torque))
    prev = 0.0
    for k in range(len(z)):
        prev = side[k] + (prev - side[k]) * keep[k]
        z[k] = prev
    return z


# --------------------------------------------------------------------------- the recording


@dataclass(frozen=True)
class Spec(indep.Spec):
    """
    What to generate (the independent generator's options; its ``law`` and noise unused).

    ``effort_noise_pct`` and ``law`` must stay None: this generator draws both.
    """

    def check(self):
        """
        Validate the options.

        Raises
        ------
        GeneratorError
            Naming the first option out of range.

        """
        if self.law is not None:
            raise GeneratorError(f'--law is not an option of this generator, got {self.law!r}')
        if self.effort_noise_pct is not None:
            raise GeneratorError('--effort-noise is not an option of this generator, got '
                                 f'{self.effort_noise_pct!r}')
        super().check()


@dataclass
class Stream(indep.Recording):
    """
    This generator's samples and truth: an ``independent_generator.Recording`` with drops.

    Per controller cycle, ``q`` is the output angle the motor implies, ``effort``
    what the drive reports and ``velocity`` the controller's difference of the
    motor reading.

    Attributes
    ----------
    duty : Duty
        The moves.
    link_kept, motor_kept : ndarray of bool
        Messages that arrived (the others were dropped).

    """

    duty: Duty
    link_kept: np.ndarray
    motor_kept: np.ndarray

    def end_of_life_h(self):
        """
        Operating hours at which each joint's lost motion reaches the limit in this stream.

        Returns
        -------
        ndarray
            Hours per joint, interpolated between samples; NaN where the stream ends first.

        """
        limit = LIMIT_ARCMIN * ARCMIN
        out = np.full(len(self.joints), np.nan)
        for i in range(len(self.joints)):
            lm = self.lost_motion[:, i]
            k = int(np.searchsorted(lm, limit))
            if 0 < k < len(lm):
                h = self.start_hours[i] + self.t[k - 1:k + 1] * self.spec.aging_factor / HOUR
                out[i] = float(np.interp(limit, lm[k - 1:k + 1], h))
            elif k == 0 and lm[0] >= limit:
                out[i] = float(self.start_hours[i])
        return out

    def truth_json(self):
        """
        Return the truth of the recording (edge units).

        Returns
        -------
        dict
            Rate, duration, layout and per joint the drawn unit, load and sensors and
            the truth at the start and the end.

        """
        last = len(self.t) - 1
        eol = self.end_of_life_h()
        out = {}
        for i, j in enumerate(self.joints):
            out[j.name] = {
                'kind': j.kind, 'life_h': j.life_h,
                'lost_motion_new_arcmin': j.lost_motion_new_rad / ARCMIN,
                'stiffness_nm_per_arcmin': j.stiffness_nm_per_rad * ARCMIN,
                'knee_torque_pct': 100.0 * j.knee_torque_nm / RATED_TORQUE_NM,
                'hysteresis_arcmin': j.hysteresis_rad / ARCMIN,
                'run_in_arcmin': j.run_in_rad / ARCMIN,
                'contamination_fraction': j.contamination_fraction,
                'contamination_factor': j.contamination_factor,
                'efficiency': j.efficiency, 'effort_noise_nm': j.effort_noise_nm,
                'torque_constant_scale': j.torque_constant_scale,
                'eccentricity_arcsec': j.eccentricity_rad / ARCSEC,
                'link_latency_us': j.link_latency_s * 1e6,
                'start_hours': float(self.start_hours[i]),
                'end_hours': float(self.hours_at(last)[i]),
                'lost_motion_start_arcmin': float(self.lost_motion[0, i] / ARCMIN),
                'lost_motion_end_arcmin': float(self.lost_motion[last, i] / ARCMIN),
                'remaining_life_end_h': float(self.remaining_life_h(last)[i]),
                'end_of_life_in_stream_h': None if math.isnan(eol[i]) else float(eol[i]),
                'max_abs_torque_nm': float(np.max(np.abs(self.torque[:, i]))),
            }
        return {'generator': 'third', 'seed': self.spec.seed, 'rate_hz': self.rate_hz,
                'duration_s': float(self.spec.duration_s),
                'aging_factor': self.spec.aging_factor, 'samples': len(self.t),
                'dropped_link': int(np.count_nonzero(~self.link_kept)),
                'dropped_motor': int(np.count_nonzero(~self.motor_kept)),
                'stamp_jitter_us': self.jitter_s * 1e6, 'layout': self.spec.layout,
                'motor_angles': self.spec.motor_angles, 'effort_on': self.spec.effort_on,
                'velocity': self.spec.velocity, 'lost_motion_limit_arcmin': LIMIT_ARCMIN,
                'ratio': RATIO, 'joints': out}


def generate(spec):
    """Draw the robot and compute every sample (as ``independent_generator.generate``)."""
    spec.check()
    joints, e_rate = draw_robot(spec.seed, spec.kinds)
    rng = _rng(spec.seed, 3)
    drawn_rate = float(rng.choice(RATES_HZ))
    drawn_jitter = rng.uniform(5e-6, 40e-6)
    drops = rng.uniform(0.0, 0.01, 2)
    delays = rng.uniform(50e-6, 300e-6, 2), rng.uniform(100e-6, 1e-3, 2)
    noise = _rng(spec.seed, 4)
    times = indep.clock(spec, drawn_rate, drawn_jitter, delays, noise)
    rate, t = times['rate_hz'], times['t']
    n = len(t)
    link_kept = noise.uniform(size=n) >= drops[0]
    motor_kept = (noise.uniform(size=n) >= drops[1]) if spec.layout == 'split' else link_kept
    duty = draw_duty(_rng(spec.seed, 2), joints, spec.duration_s)
    e_life, start_h = indep.life_and_start(spec, joints, e_rate)
    arrays = {name: np.empty((n, len(joints))) for name in (
        'q', 'qd', 'torque', 'effort', 'link', 'motor', 'velocity', 'lost_motion', 'exposure')}
    for i, j in enumerate(joints):
        q, qd, qdd, u = duty.motion(i, t)
        torque = true_torque(j, q, qd, qdd, u)
        steps = np.diff(t) * spec.aging_factor * 0.5 * (
            exposure_rate(j, torque[1:], qd[1:]) + exposure_rate(j, torque[:-1], qd[:-1]))
        exposure = e_rate[i] * start_h[i] * HOUR + np.concatenate([[0.0], np.cumsum(steps)])
        lm = j.lost_motion(exposure / e_life[i])
        # The link encoder latches earlier than the motor: its own sample of the motion.
        t_link = t - j.link_latency_s
        q_l, qd_l, qdd_l, u_l = duty.motion(i, t_link)
        torque_l = true_torque(j, q_l, qd_l, qdd_l, u_l)
        out = q_l - j.twist(torque_l, lm, dahl_state(j, torque_l)) \
            + j.mesh_error_rad * np.sin(PIN_COUNT * q_l + j.mesh_phase)
        link = indep.quantise(out + j.eccentricity_rad * np.sin(out + j.eccentricity_phase)
                              + j.link_offset_rad + noise.normal(0.0, j.link_noise_rad, n),
                              j.link_bits)
        shaft = RATIO * q + j.motor_offset_rad
        motor = indep.quantise(shaft + j.motor_error_rad * np.sin(shaft + j.motor_error_phase),
                               j.motor_bits)
        velocity = np.diff(motor, prepend=motor[:1]) * rate / RATIO
        effort = drive_torque(j, torque, qd, shaft) + noise.normal(0.0, j.effort_noise_nm, n)
        for name, value in (('q', q), ('qd', qd), ('torque', torque), ('effort', effort),
                            ('link', link), ('motor', motor), ('velocity', velocity),
                            ('lost_motion', lm), ('exposure', exposure)):
            arrays[name][:, i] = value
    return Stream(spec=spec, joints=joints, duty=duty, link_kept=link_kept,
                  motor_kept=motor_kept, exposure_rate=e_rate, exposure_life=e_life,
                  start_hours=start_h, **times, **arrays)


# --------------------------------------------------------------------------- the bag


def write_bag(stream, out, overwrite=False):
    """Write the stream without its dropped messages (:func:`independent_generator.write_bag`)."""
    return indep.write_bag(stream, out, overwrite, kept=(stream.link_kept, stream.motor_kept),
                           generator='third_generator')


def generate_bag(spec, out, overwrite=False):
    """Generate a recording and write it; return its truth (``indep.generate_bag``)."""
    return indep.generate_bag(spec, out, overwrite, generate=generate, write=write_bag)


# --------------------------------------------------------------------------- CLI


def main(argv=None):
    """Run the command line: ``independent_generator``'s without ``--law``, ``--effort-noise``."""
    args = indep.cli_parser(
        'third_generator.py',
        'Write a rosbag2 MCAP recording of RV-80E joints from catalogue-style physics unlike '
        'the twin and the independent generator; print its truth.').parse_args(argv)
    return indep.cli_run(args, Spec(**indep.cli_spec_options(args)), generate_bag)


if __name__ == '__main__':
    sys.exit(main())
