#!/usr/bin/env python3
"""
Independent joint generator: rosbag2 recordings of RV-80E joints with a known truth.

A second source of recordings that shares nothing with the twin's model (it
imports nothing from ``reducer_twin``), so the twin can be judged on reducers
unlike its own physics. Its physics, simple and stated:

* **Units as built.** New lost motion drawn in 0.3-1.0 arcmin, torsional
  stiffness within +-15 % of the RV-80E catalogue 196 N*m/arcmin, ratio 81
  (the catalogue ratio of the RV-80E, the one ``config/rv80e.yaml`` implies).
* **Transmission error** seen between ``motor/ratio`` and the link:
  ``TE = -(LM/2)*y - T/k + a1*sin(q + p1) + a2*sin(2q + p2)``. ``y`` in
  [-1, 1] is the side of the clearance the output leans on: a play operator
  of half-width ``r`` (drawn 0-0.5) on ``(1 + r)*s(T)``, ``s`` a sine ramp
  that saturates at ``|T| = Ts`` (drawn 1-3 % of rated). Above ``Ts`` the
  play is fully taken up; as the torque falls back to zero the output keeps
  ``r`` of its last side (friction holds it), so at standstill without load
  the TE carries the direction of the last move, not the torque. Harmonics
  of 2-8 and 1-4 arcsec at 1x and 2x of the output angle; quantised
  encoders with noise.
* **Lost motion** (the play at the catalogue's +-3 % rated torque, without
  the elastic windup ``2*T/k``) grows with the Archard-like exposure
  ``E = integral |w|*|T/T_rated|^p dt`` (``p`` drawn 1-2.5):
  ``LM = LM_new + (LM_limit - LM_new)*(E/E_life)^g``, ``g = 1`` for the
  ``'linear'`` law and ``g`` drawn in 0.35-0.75 for the ``'concave'`` law;
  ``E_life`` is the exposure of a drawn life of 3 000-30 000 h under the
  joint's duty, so the 3.0 arcmin limit is reached after that life.
* **Duty.** A periodic pick-and-place cycle common to the robot: 3-5 moves
  (cycloidal motion law) between waypoints, each followed by a dwell; every
  move reverses the joint. Kinds: ``base`` (no gravity: ``T = J*a + c*w``),
  ``shoulder`` and ``forearm`` (``T = G*cos(q) + J*a + c*w``, waypoints on
  both sides of the vertical, so the torque changes sign), ``wrist``.
* **Effort** (a motor-current torque): ``T + Fc*tanh(w/w_s) + Fv*w`` plus
  white noise of 1-5 % of the rated 784 N*m; the friction is seen by the
  motor current, not by the reducer output.
* **Timing.** Encoders sample exactly every ``1/rate`` (drawn among
  100-1000 Hz); header stamps carry a jitter of 10-50 us (each topic its
  own), log times come after the stamps by a random delivery delay, in
  receive order.

Layouts: link on ``/joint_states`` (position, velocity, effort) and raw motor
angles (``ratio*q`` + TE effects) on ``/motor_states``; or one topic with
``<joint>`` and ``<joint>_motor`` entries (absent values NaN, as
joint_state_broadcaster writes them); motor angles raw or divided by the
ratio; effort on the link or on the motor entries (motor units, ``/ratio``);
velocity present or not. Bags are written with rosbags (rosbag2 version 9,
MCAP storage, QoS per topic), with ``reducer_twin.aging_factor`` in
``custom_data`` and the truth at every stream second on
``/truth/<joint>`` (``std_msgs/Float64MultiArray``, fields in the layout
label).

Time compression: ``--hours H`` of operation at ``--aging-factor A`` give a
stream of ``H*3600/A`` s; ``--start-hours`` (or ``--start-fraction`` of the
drawn life) for a unit already used. Every truth is drawn from the seed
(each joint from its own stream, so options such as the rate or the noise
level never change the drawn unit).

Usage::

    python bench/independent_generator.py --out BAG --seed 3 [--kinds base,shoulder,forearm]
        [--hours 0.05] [--aging-factor 1] [--start-fraction 0.4] [--rate-hz 125]
        [--effort-noise 2] [--effort-noise-band 5-50] [--layout split|combined] [--json]
"""

import argparse
from dataclasses import dataclass, replace
import json
import math
import os
from pathlib import Path
import shutil
import sys
import tempfile

import numpy as np

RATIO = 81.0
"""RV-80E ratio (catalogue; 1 + 36/18*40), the nominal ratio of config/rv80e.yaml."""

RATED_TORQUE_NM = 784.0
"""RV-80E rated output torque [N*m] (catalogue)."""

CATALOGUE_STIFFNESS_NM_PER_ARCMIN = 196.0
"""RV-80E torsional rigidity [N*m/arcmin] (catalogue)."""

LIMIT_ARCMIN = 3.0
"""Accuracy limit on lost motion [arcmin] (the twin's default limit)."""

TEST_TORQUE_FRACTION = 0.03
"""Catalogue lost-motion test torque, fraction of rated."""

ARCMIN = math.pi / (180.0 * 60.0)
ARCSEC = ARCMIN / 60.0
HOUR = 3600.0
GRAVITY = 9.81

KINDS = ('base', 'shoulder', 'forearm', 'wrist')
LAWS = ('linear', 'concave')
LAYOUTS = ('split', 'combined')
AGING_KEY = 'reducer_twin.aging_factor'
"""custom_data key a user's configuration would carry the aging factor under."""

RATES_HZ = (100.0, 125.0, 200.0, 250.0, 400.0, 500.0, 800.0, 1000.0)
"""Controller rates drawn from (ros2_control's usual 100 Hz up to 1 kHz)."""

START_S = 1_767_225_600
"""Stamp of the first sample [s since the epoch] (2026-01-01)."""

MAX_MESSAGES = 20_000_000

TRUTH_FIELDS = ('stamp_s', 'lost_motion_rad', 'exposure', 'operating_hours',
                'remaining_life_h', 'lost_motion_new_rad', 'stiffness_nm_per_rad')
"""Fields of a ``/truth/<joint>`` message (SI, hours where named)."""

# Per kind: gravity torque G/rated, peak inertial torque/rated, waypoint ranges [deg]
# (alternating sides for a reversal every move), speed and acceleration limits.
_KIND = {
    'base': {'gravity': (0.0, 0.0), 'inertial': (0.10, 0.35), 'low': (-150.0, -20.0),
             'high': (20.0, 150.0), 'v_max': 1.3, 'a_max': 3.0},
    'shoulder': {'gravity': (0.35, 0.85), 'inertial': (0.05, 0.20), 'low': (30.0, 80.0),
                 'high': (100.0, 150.0), 'v_max': 1.1, 'a_max': 3.0},
    'forearm': {'gravity': (0.15, 0.45), 'inertial': (0.05, 0.20), 'low': (-10.0, 75.0),
                'high': (105.0, 170.0), 'v_max': 1.5, 'a_max': 4.0},
    'wrist': {'gravity': (0.03, 0.10), 'inertial': (0.03, 0.10), 'low': (-120.0, -10.0),
              'high': (10.0, 120.0), 'v_max': 2.0, 'a_max': 6.0},
}


class GeneratorError(ValueError):
    """An option of the generator is out of its range (the message names it)."""


# --------------------------------------------------------------------------- truth


@dataclass(frozen=True)
class JointTruth:
    """
    One drawn reducer and its load (SI inside; the unit in every name).

    Attributes
    ----------
    name, kind : str
        Joint name and kind (``base``, ``shoulder``, ``forearm``, ``wrist``).
    lost_motion_new_rad : float
        Lost motion of the new unit at +-3 % rated torque [rad].
    stiffness_nm_per_rad : float
        Torsional stiffness [N*m/rad].
    law : str
        ``'linear'`` or ``'concave'`` growth in exposure.
    law_exponent : float
        ``g`` of ``LM_new + (LM_limit - LM_new)*(E/E_life)^g`` (1 when linear).
    torque_exponent : float
        ``p`` of the exposure ``integral |w|*|T/T_rated|^p dt``.
    life_h : float
        Operating hours from new to the lost-motion limit under this duty [h].
    play_memory : float
        Half-width ``r`` of the play operator (0: no memory).
    takeup_torque_nm : float
        Torque ``Ts`` above which the play is fully taken up [N*m].
    order1_rad, order1_phase, order2_rad, order2_phase : float
        Manufacturing TE harmonics at 1x and 2x of the output angle [rad].
    gravity_nm, inertia_kg_m2, drag_nm_s : float
        Load: gravity amplitude, link inertia, link-side viscous drag.
    coulomb_nm, viscous_nm_s : float
        Friction the motor current sees and the reducer output does not.
    effort_noise_fraction : float
        Standard deviation of the effort noise, fraction of rated torque.
    waypoints_rad : tuple of float
        Waypoints of the cycle (the cycle returns to the first).
    link_offset_rad, motor_offset_rad : float
        Encoder zeros (link absolute; motor raw, multi-turn).
    link_bits, motor_bits : int
        Counts per turn of the link and of the motor encoder, as powers of two.
    link_noise_rad, motor_noise_rad, velocity_noise_rad_s : float
        Encoder and velocity noise (standard deviations).

    """

    name: str
    kind: str
    lost_motion_new_rad: float
    stiffness_nm_per_rad: float
    law: str
    law_exponent: float
    torque_exponent: float
    life_h: float
    play_memory: float
    takeup_torque_nm: float
    order1_rad: float
    order1_phase: float
    order2_rad: float
    order2_phase: float
    gravity_nm: float
    inertia_kg_m2: float
    drag_nm_s: float
    coulomb_nm: float
    viscous_nm_s: float
    effort_noise_fraction: float
    waypoints_rad: tuple
    link_offset_rad: float
    motor_offset_rad: float
    link_bits: int
    motor_bits: int
    link_noise_rad: float
    motor_noise_rad: float
    velocity_noise_rad_s: float
    inertial_fraction: float = 0.0

    @property
    def effort_noise_nm(self):
        """Return the standard deviation of the effort noise [N*m]."""
        return self.effort_noise_fraction * RATED_TORQUE_NM

    def lost_motion(self, fraction_of_life):
        """
        Lost motion at a fraction ``E/E_life`` of the life's exposure [rad].

        Parameters
        ----------
        fraction_of_life : float or array_like
            Exposure over the exposure of the whole life (>= 0; 1 at the limit).

        Returns
        -------
        float or ndarray
            ``LM_new + (LM_limit - LM_new)*x^g``; grows past the limit beyond 1.

        """
        x = np.maximum(np.asarray(fraction_of_life, dtype=float), 0.0)
        lm = self.lost_motion_new_rad + (LIMIT_ARCMIN * ARCMIN - self.lost_motion_new_rad) * \
            x ** self.law_exponent
        return float(lm) if lm.ndim == 0 else lm


def _rng(seed, *key):
    return np.random.default_rng([int(seed), *key])


def draw_joint(seed, index, kind, law=None, effort_noise_fraction=None):
    """
    Draw one joint's unit and load from its own random stream.

    Parameters
    ----------
    seed : int
        Recording seed.
    index : int
        Joint index (0-based); names are ``joint_<index+1>``.
    kind : str
        One of :data:`KINDS`.
    law : str, optional
        Force the growth law (the draw happens anyway, so nothing else changes).
    effort_noise_fraction : float, optional
        Force the effort noise (fraction of rated torque).

    Returns
    -------
    JointTruth
        The drawn joint; the waypoints still without the inertia scaling
        (:func:`draw_robot` sets ``inertia_kg_m2`` from the cycle).

    """
    rng = _rng(seed, 1, index)
    k = _KIND[kind]
    lm_new = rng.uniform(0.3, 1.0) * ARCMIN
    stiffness = CATALOGUE_STIFFNESS_NM_PER_ARCMIN * rng.uniform(0.85, 1.15) / ARCMIN
    drawn_law = LAWS[int(rng.integers(2))]
    g = rng.uniform(0.35, 0.75)
    p = rng.uniform(1.0, 2.5)
    life_h = math.exp(rng.uniform(math.log(3000.0), math.log(30000.0)))
    memory = rng.uniform(0.0, 0.5)
    takeup = rng.uniform(0.01, TEST_TORQUE_FRACTION) * RATED_TORQUE_NM
    a1, a2 = rng.uniform(2.0, 8.0) * ARCSEC, rng.uniform(1.0, 4.0) * ARCSEC
    p1, p2 = rng.uniform(-math.pi, math.pi, 2)
    gravity = rng.uniform(*k['gravity']) * RATED_TORQUE_NM
    inertial = rng.uniform(*k['inertial'])
    drag = rng.uniform(0.002, 0.01) * RATED_TORQUE_NM  # N*m at 1 rad/s
    coulomb = rng.uniform(0.01, 0.04) * RATED_TORQUE_NM
    viscous = rng.uniform(0.005, 0.02) * RATED_TORQUE_NM
    noise = rng.uniform(0.01, 0.05)
    n_way = 6
    lows = rng.uniform(*k['low'], n_way)
    highs = rng.uniform(*k['high'], n_way)
    first_high = bool(rng.integers(2))
    way = tuple(float(math.radians(highs[i] if (i % 2 == 0) == first_high else lows[i]))
                for i in range(n_way))
    link_offset = rng.uniform(-0.01, 0.01)
    motor_offset = rng.uniform(-200.0, 200.0)
    link_bits = int(rng.integers(20, 24))
    motor_bits = int(rng.integers(17, 21))
    link_noise = rng.uniform(0.1, 1.0) * ARCSEC
    motor_noise = 0.5 * 2.0 * math.pi / 2 ** motor_bits
    vel_noise = rng.uniform(1e-3, 5e-3)
    return JointTruth(
        name=f'joint_{index + 1}', kind=kind, lost_motion_new_rad=lm_new,
        stiffness_nm_per_rad=stiffness, law=law or drawn_law,
        law_exponent=1.0 if (law or drawn_law) == 'linear' else g, torque_exponent=p,
        life_h=life_h, play_memory=memory, takeup_torque_nm=takeup, order1_rad=a1,
        order1_phase=float(p1), order2_rad=a2, order2_phase=float(p2), gravity_nm=gravity,
        inertia_kg_m2=0.0, drag_nm_s=drag, coulomb_nm=coulomb, viscous_nm_s=viscous,
        effort_noise_fraction=noise if effort_noise_fraction is None else effort_noise_fraction,
        waypoints_rad=way, link_offset_rad=link_offset, motor_offset_rad=motor_offset,
        link_bits=link_bits, motor_bits=motor_bits, link_noise_rad=link_noise,
        motor_noise_rad=motor_noise, velocity_noise_rad_s=vel_noise, inertial_fraction=inertial)


# --------------------------------------------------------------------------- duty


@dataclass(frozen=True)
class Cycle:
    """
    The robot's periodic pick-and-place cycle (common timing of all joints).

    Attributes
    ----------
    move_s, dwell_s : tuple of float
        Duration of each move and of the dwell after it [s].
    phase_s : float
        Where in the cycle the recording starts [s].

    """

    move_s: tuple
    dwell_s: tuple
    phase_s: float

    @property
    def period_s(self):
        """Return the cycle period [s]."""
        return float(sum(self.move_s) + sum(self.dwell_s))

    def motion(self, waypoints, t):
        """
        Position, speed and acceleration of one joint on the cycle.

        Each move follows the cycloidal law ``q0 + D*(s - sin(2*pi*s)/(2*pi))``,
        ``s = t/T`` (zero speed and acceleration at both ends), then dwells.

        Parameters
        ----------
        waypoints : sequence of float
            The joint's waypoints [rad] (at least as many as moves).
        t : ndarray
            Time of the recording [s].

        Returns
        -------
        tuple of ndarray
            ``(q, dq/dt, d2q/dt2)`` [rad, rad/s, rad/s^2].

        """
        n = len(self.move_s)
        way = np.asarray(waypoints[:n], dtype=float)
        frm, to = way, np.roll(way, -1)
        starts = np.cumsum(np.ravel(np.column_stack([self.move_s, self.dwell_s])))
        starts = np.concatenate([[0.0], starts[:-1]])
        tc = np.mod(np.asarray(t, dtype=float) + self.phase_s, self.period_s)
        seg = np.clip(np.searchsorted(starts, tc, side='right') - 1, 0, 2 * n - 1)
        move = seg // 2
        in_move = seg % 2 == 0
        dur = np.asarray(self.move_s)[move]
        s = np.where(in_move, np.clip((tc - starts[seg]) / dur, 0.0, 1.0), 1.0)
        d = (to - frm)[move]
        two_pi_s = 2.0 * math.pi * s
        q = frm[move] + d * (s - np.sin(two_pi_s) / (2.0 * math.pi))
        qd = np.where(in_move, d / dur * (1.0 - np.cos(two_pi_s)), 0.0)
        qdd = np.where(in_move, d / dur ** 2 * 2.0 * math.pi * np.sin(two_pi_s), 0.0)
        return q, qd, qdd


def draw_robot(seed, kinds, law=None, effort_noise_fraction=None):
    """
    Draw the joints and the cycle of one robot.

    Parameters
    ----------
    seed : int
        Recording seed.
    kinds : sequence of str
        Kind of each joint.
    law : str, optional
        Force every joint's growth law.
    effort_noise_fraction : float, optional
        Force every joint's effort noise (fraction of rated torque).

    Returns
    -------
    tuple
        ``(joints, cycle)``: list of :class:`JointTruth` (inertia set so that
        the cycle's peak inertial torque is the drawn fraction of rated) and
        the :class:`Cycle`.

    """
    joints = [draw_joint(seed, i, kind, law, effort_noise_fraction)
              for i, kind in enumerate(kinds)]
    rng = _rng(seed, 2)
    n_moves = int(rng.integers(3, 6))
    moves, dwells = [], []
    for m in range(n_moves):
        need = 0.0
        for j in joints:
            way = j.waypoints_rad[:n_moves]
            d = abs(way[(m + 1) % n_moves] - way[m])
            k = _KIND[j.kind]
            need = max(need, 2.0 * d / k['v_max'], math.sqrt(2.0 * math.pi * d / k['a_max']))
        moves.append(max(need, 0.3) * rng.uniform(1.0, 1.25))
        dwells.append(rng.uniform(0.2, 1.5))
    cycle = Cycle(tuple(moves), tuple(dwells), 0.0)
    cycle = replace(cycle, phase_s=float(rng.uniform(0.0, cycle.period_s)))
    t = np.linspace(0.0, cycle.period_s, 20_001)
    out = []
    for j in joints:
        _, _, qdd = cycle.motion(j.waypoints_rad, t)
        peak = float(np.max(np.abs(qdd)))
        out.append(replace(j, inertia_kg_m2=j.inertial_fraction * RATED_TORQUE_NM / peak,
                           waypoints_rad=tuple(j.waypoints_rad[:n_moves])))
    return out, cycle


def effort_noise(white, band_hz, rate_hz):
    """
    Unit-RMS effort noise from unit white noise: itself, or band-limited to ``band_hz``.

    Raises
    ------
    GeneratorError
        If the band does not lie below half the rate.

    """
    if band_hz is None:
        return white
    if not band_hz[1] < 0.5 * rate_hz:
        raise GeneratorError(f'--effort-noise-band: {band_hz[0]:g}-{band_hz[1]:g} Hz, allowed '
                             f'HIGH below half the rate ({rate_hz:g} Hz)')
    from scipy.signal import butter, sosfiltfilt
    sos = butter(4, list(band_hz), btype='band', fs=rate_hz, output='sos')
    band = sosfiltfilt(sos, white)
    return band / math.sqrt(float(np.mean(band ** 2)))


def filtered(x, tau_s, rate_hz):
    """Return ``x`` through a first-order low-pass of time constant ``tau_s`` (None: as is)."""
    if not tau_s:
        return x
    from scipy.signal import lfilter
    a = 1.0 - math.exp(-1.0 / (tau_s * rate_hz))   # y[k] = y[k-1] + a·(x[k] - y[k-1])
    return lfilter([a], [1.0, a - 1.0], x, zi=[(1.0 - a) * x[0]])[0]


def true_torque(joint, q, qd, qdd):
    """Return the torque the reducer output transmits [N*m] (gravity, inertia, link drag)."""
    return joint.gravity_nm * np.cos(q) + joint.inertia_kg_m2 * qdd + joint.drag_nm_s * qd


def friction(joint, qd):
    """Return the friction the motor current carries and the reducer output does not [N*m]."""
    return joint.coulomb_nm * np.tanh(qd / 0.02) + joint.viscous_nm_s * qd


def exposure_rate(joint, torque, speed):
    """Return the exposure rate ``|w|*|T/T_rated|^p`` [rad/s] (Archard-like)."""
    return np.abs(speed) * np.abs(torque / RATED_TORQUE_NM) ** joint.torque_exponent


def cycle_exposure_rate(joint, cycle, samples=200_001):
    """
    Mean exposure rate over one cycle [1/s of operation].

    Parameters
    ----------
    joint : JointTruth
        The joint.
    cycle : Cycle
        The duty cycle.
    samples : int
        Points of the trapezoid rule over one period.

    Returns
    -------
    float
        ``(1/P) * integral over one period of |w|*|T/T_rated|^p dt``.

    """
    t = np.linspace(0.0, cycle.period_s, samples)
    q, qd, qdd = cycle.motion(joint.waypoints_rad, t)
    rate = exposure_rate(joint, true_torque(joint, q, qd, qdd), qd)
    return float(np.trapezoid(rate, t) / cycle.period_s)


def play_side(joint, torque):
    """
    Side of the clearance the output leans on, in [-1, 1] (play operator with memory).

    ``u = (1 + r)*s(T)`` with ``s = sin(pi/2*T/Ts)`` inside ``|T| < Ts``, ``sign(T)``
    beyond; ``y_k = min(max(y_{k-1}, u_k - r), u_k + r)``, starting from 0.

    Parameters
    ----------
    joint : JointTruth
        The joint (``play_memory`` = r, ``takeup_torque_nm`` = Ts).
    torque : ndarray
        Transmitted torque, in time order [N*m].

    Returns
    -------
    ndarray
        ``y``, +1 when the torque has taken the play up in the positive sense.

    """
    r = joint.play_memory
    x = np.clip(torque / joint.takeup_torque_nm, -1.0, 1.0)
    u = (1.0 + r) * np.sin(0.5 * math.pi * x)
    if r == 0.0:
        return u
    y = np.empty_like(u)
    # Only samples inside the band can keep the past; outside it y = u -+ r at once.
    prev = 0.0
    lo, hi = (u - r).tolist(), (u + r).tolist()
    for k in range(len(u)):
        if prev < lo[k]:
            prev = lo[k]
        elif prev > hi[k]:
            prev = hi[k]
        y[k] = prev
    return y


# --------------------------------------------------------------------------- the recording


@dataclass(frozen=True)
class Spec:
    """
    What to generate (edge units where named).

    Attributes
    ----------
    seed : int
        Seed of every draw.
    kinds : tuple of str
        Kind of each joint (names ``joint_1``, ...).
    hours : float
        Operating hours the recording spans.
    aging_factor : float
        Operating seconds per stream second (the stream lasts ``hours*3600/aging_factor`` s).
    start_hours, start_fraction : float or None
        Operating hours before the recording, or the fraction of each joint's drawn life
        (one of them; neither: a new unit).
    rate_hz : float or None
        Controller rate; None: drawn from :data:`RATES_HZ`.
    effort_noise_pct : float or None
        Effort noise [% of rated torque]; None: drawn per joint in 1-5 %.
    effort_noise_band_hz : tuple of float or None
        ``(low, high)``: the effort noise band-limited to it [Hz] (a current loop's ripple:
        a fourth-order Butterworth band-pass run forwards and backwards, scaled to the
        same RMS); None: white.
    velocity_filter_s : float or None
        Time constant of a first-order filter the velocity field passes through [s] (a
        drive's filtered velocity, which lags the motion); None: unfiltered.
    effort_filter_s : float or None
        Time constant of a first-order filter the effort passes through [s] (a drive's
        filtered torque estimate, which lags the load); None: unfiltered.
    law : str or None
        Force the growth law of every joint.
    layout : str
        ``'split'``: link on ``link_topic``, motor on ``motor_topic``; ``'combined'``:
        ``<joint>`` and ``<joint><motor_suffix>`` in one message on ``link_topic``.
    motor_angles : str
        ``'raw'`` (``ratio*q``) or ``'output'`` (divided by the ratio).
    effort_on : str
        ``'link'`` [N*m] or ``'motor'`` (motor units: divided by the ratio).
    velocity : bool
        Whether the link entries carry the velocity field.
    truth_topics : bool
        Whether ``/truth/<joint>`` is written.
    link_topic, motor_topic, motor_suffix : str
        Names.
    stamp_jitter_us : float or None
        Standard deviation of the stamp jitter; None: drawn in 10-50 us.
    motor_stamp_offset_s, motor_clock_ppm : float or None
        The motor topic's stamps later than the link's by this much [s], and drifting
        from them by this many parts per million (two clocks; ``'split'`` layout only);
        None: on the link's clock.

    """

    seed: int = 0
    kinds: tuple = ('base', 'shoulder', 'forearm')
    hours: float = 0.05
    aging_factor: float = 1.0
    start_hours: float = None
    start_fraction: float = None
    rate_hz: float = None
    effort_noise_pct: float = None
    effort_noise_band_hz: tuple = None
    velocity_filter_s: float = None
    effort_filter_s: float = None
    motor_stamp_offset_s: float = None
    motor_clock_ppm: float = None
    law: str = None
    layout: str = 'split'
    motor_angles: str = 'raw'
    effort_on: str = 'link'
    velocity: bool = True
    truth_topics: bool = True
    link_topic: str = '/joint_states'
    motor_topic: str = '/motor_states'
    motor_suffix: str = '_motor'
    stamp_jitter_us: float = None

    def check(self):
        """
        Validate the options.

        Raises
        ------
        GeneratorError
            Naming the first option out of range, its value and the allowed range.

        """
        def bad(name, value, allowed):
            raise GeneratorError(f'{name} must be {allowed}, got {value!r}')

        if not self.kinds or any(k not in KINDS for k in self.kinds):
            bad('--kinds', ','.join(self.kinds), f'a list of {", ".join(KINDS)}')
        if len(self.kinds) > 32:
            bad('--kinds', len(self.kinds), 'at most 32 joints')
        for name, value, lo, hi in (('--hours', self.hours, 0.0, 1e6),
                                    ('--aging-factor', self.aging_factor, 0.0, 1e9)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and lo < value <= hi):
                bad(name, value, f'in ({lo:g}, {hi:g}]')
        if self.start_hours is not None and self.start_fraction is not None:
            bad('--start-hours', self.start_hours, 'left out when --start-fraction is given')
        if self.start_hours is not None and not (0.0 <= self.start_hours <= 1e6):
            bad('--start-hours', self.start_hours, 'in [0, 1e6] h')
        if self.start_fraction is not None and not (0.0 <= self.start_fraction <= 2.0):
            bad('--start-fraction', self.start_fraction, 'in [0, 2]')
        if self.rate_hz is not None and not (1.0 <= self.rate_hz <= 10_000.0):
            bad('--rate-hz', self.rate_hz, 'in [1, 10000] Hz')
        if self.effort_noise_pct is not None and not (0.0 <= self.effort_noise_pct <= 50.0):
            bad('--effort-noise', self.effort_noise_pct, 'in [0, 50] % of rated torque')
        band = self.effort_noise_band_hz
        if band is not None and not (len(band) == 2 and 0.0 < band[0] < band[1]):
            bad('--effort-noise-band', band, 'LOW-HIGH with 0 < LOW < HIGH [Hz]')
        if band is not None and self.rate_hz is not None and not band[1] < 0.5 * self.rate_hz:
            bad('--effort-noise-band', band, f'HIGH below half the rate ({self.rate_hz:g} Hz)')
        if self.velocity_filter_s is not None and not (0.0 <= self.velocity_filter_s <= 1.0):
            bad('--velocity-filter-ms', 1e3 * self.velocity_filter_s, 'in [0, 1000] ms')
        if self.effort_filter_s is not None and not (0.0 <= self.effort_filter_s <= 1.0):
            bad('--effort-filter-ms', 1e3 * self.effort_filter_s, 'in [0, 1000] ms')
        if self.stamp_jitter_us is not None and not (0.0 <= self.stamp_jitter_us <= 1000.0):
            bad('--stamp-jitter-us', self.stamp_jitter_us, 'in [0, 1000] us')
        for name, value, scale in (('--motor-stamp-offset-ms', self.motor_stamp_offset_s, 1e3),
                                   ('--motor-clock-ppm', self.motor_clock_ppm, 1.0)):
            if value is not None and not abs(value * scale) <= 1000.0:
                bad(name, value * scale, 'in [-1000, 1000]')
            if value is not None and self.layout != 'split':
                bad(name, value * scale, 'given with --layout split (one message, one stamp)')
        for name, value, allowed in (('--law', self.law, LAWS + (None,)),
                                     ('--layout', self.layout, LAYOUTS),
                                     ('--motor-angles', self.motor_angles, ('raw', 'output')),
                                     ('--effort-on', self.effort_on, ('link', 'motor'))):
            if value not in allowed:
                bad(name, value, f'one of {", ".join(a for a in allowed if a)}')
        if self.layout == 'split' and self.link_topic == self.motor_topic:
            bad('--motor-topic', self.motor_topic, 'a topic other than --link-topic')
        if self.duration_s * self.rate_upper_bound() * 2 > MAX_MESSAGES:
            bad('--hours', self.hours, f'short enough for at most {MAX_MESSAGES:,} messages '
                f'({self.duration_s:.0f} s of stream at {self.rate_upper_bound():g} Hz)')

    @property
    def duration_s(self):
        """Return the length of the stream [s]."""
        return self.hours * HOUR / self.aging_factor

    def rate_upper_bound(self):
        """Return the rate, or the highest that can be drawn [Hz]."""
        return self.rate_hz if self.rate_hz is not None else max(RATES_HZ)


@dataclass
class Recording:
    """
    The samples and truth both generators compute (before serialisation).

    Attributes
    ----------
    spec : Spec
        The request.
    joints : list of JointTruth
        The drawn joints.
    rate_hz : float
        Controller rate.
    jitter_s : float
        Standard deviation of the stamp jitter [s].
    t : ndarray
        Sampling instants from the first sample [s].
    link_stamp_ns, motor_stamp_ns, link_log_ns, motor_log_ns : ndarray
        Header stamps and log (receive) times of the two streams.
    q, qd, torque, effort, link, motor, velocity, lost_motion, exposure : ndarray
        Per sample and joint (samples, joints): the output angle, its speed, the
        transmitted torque, the measured effort [N*m at the output], the measured
        link angle, the measured motor angle (raw), the measured link velocity,
        the true lost motion [rad] and the exposure.
    exposure_rate : ndarray
        The duty's mean exposure rate per joint [1/s of operation].
    exposure_life : ndarray
        Exposure at the end of life per joint.
    start_hours : ndarray
        Operating hours of each joint at the first sample.

    """

    spec: Spec
    joints: list
    rate_hz: float
    jitter_s: float
    t: np.ndarray
    link_stamp_ns: np.ndarray
    motor_stamp_ns: np.ndarray
    link_log_ns: np.ndarray
    motor_log_ns: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    torque: np.ndarray
    effort: np.ndarray
    link: np.ndarray
    motor: np.ndarray
    velocity: np.ndarray
    lost_motion: np.ndarray
    exposure: np.ndarray
    exposure_rate: np.ndarray
    exposure_life: np.ndarray
    start_hours: np.ndarray

    def hours_at(self, k):
        """Return the operating hours of every joint at sample ``k``."""
        return self.start_hours + self.t[k] * self.spec.aging_factor / HOUR

    def remaining_life_h(self, k):
        """Return each joint's hours from sample ``k`` to the limit at the mean exposure rate."""
        return (self.exposure_life - self.exposure[k]) / (self.exposure_rate * HOUR)


@dataclass
class Stream(Recording):
    """
    This generator's samples and truth: a :class:`Recording` on a periodic cycle.

    Attributes
    ----------
    cycle : Cycle
        The duty cycle (its mean exposure rate is ``exposure_rate``).

    """

    cycle: Cycle

    def truth_json(self):
        """
        Return the truth of the recording (edge units).

        Returns
        -------
        dict
            ``rate_hz``, ``duration_s``, ``aging_factor``, ``samples``,
            ``stamp_jitter_us``, ``cycle_s`` and ``joints``: per joint the drawn
            unit and load and the truth at the start and at the end.

        """
        last = len(self.t) - 1
        out = {}
        for i, j in enumerate(self.joints):
            lm_test = TEST_TORQUE_FRACTION * RATED_TORQUE_NM
            out[j.name] = {
                'kind': j.kind, 'law': j.law, 'law_exponent': j.law_exponent,
                'torque_exponent': j.torque_exponent,
                'lost_motion_new_arcmin': j.lost_motion_new_rad / ARCMIN,
                'stiffness_nm_per_arcmin': j.stiffness_nm_per_rad * ARCMIN,
                'life_h': j.life_h,
                'start_hours': float(self.start_hours[i]),
                'end_hours': float(self.hours_at(last)[i]),
                'lost_motion_start_arcmin': float(self.lost_motion[0, i] / ARCMIN),
                'lost_motion_end_arcmin': float(self.lost_motion[last, i] / ARCMIN),
                'remaining_life_end_h': float(self.remaining_life_h(last)[i]),
                'windup_at_test_torque_arcmin': 2.0 * lm_test / j.stiffness_nm_per_rad / ARCMIN,
                'effort_noise_nm': j.effort_noise_nm,
                'effort_noise_pct': 100.0 * j.effort_noise_fraction,
                'coulomb_nm': j.coulomb_nm, 'viscous_nm_s': j.viscous_nm_s,
                'gravity_nm': j.gravity_nm, 'inertia_kg_m2': j.inertia_kg_m2,
                'play_memory': j.play_memory, 'takeup_torque_nm': j.takeup_torque_nm,
                'order1_arcsec': j.order1_rad / ARCSEC, 'order2_arcsec': j.order2_rad / ARCSEC,
                'max_abs_torque_nm': float(np.max(np.abs(self.torque[:, i]))),
            }
        return {'seed': self.spec.seed, 'rate_hz': self.rate_hz,
                'duration_s': float(self.spec.duration_s),
                'aging_factor': self.spec.aging_factor, 'samples': len(self.t),
                'stamp_jitter_us': self.jitter_s * 1e6, 'cycle_s': self.cycle.period_s,
                'layout': self.spec.layout, 'motor_angles': self.spec.motor_angles,
                'effort_on': self.spec.effort_on, 'velocity': self.spec.velocity,
                'effort_noise_band_hz': (None if self.spec.effort_noise_band_hz is None
                                         else list(self.spec.effort_noise_band_hz)),
                'velocity_filter_s': self.spec.velocity_filter_s,
                'effort_filter_s': self.spec.effort_filter_s,
                'motor_stamp_offset_s': self.spec.motor_stamp_offset_s,
                'motor_clock_ppm': self.spec.motor_clock_ppm,
                'lost_motion_limit_arcmin': LIMIT_ARCMIN, 'ratio': RATIO, 'joints': out}


def quantise(angle, bits):
    """Return ``angle`` [rad] rounded to the counts of a ``bits``-bit-per-turn encoder."""
    step = 2.0 * math.pi / 2 ** bits
    return np.round(angle / step) * step


def _log_times(rng, stamp_ns, base_s, mean_s):
    delay = base_s + rng.exponential(mean_s, stamp_ns.size)
    log = stamp_ns + np.round(delay * 1e9).astype(np.int64)
    return np.maximum.accumulate(log)


def clock(spec, drawn_rate, drawn_jitter, delays, noise):
    """
    Return the sampling instants, header stamps and log times of the link and motor streams.

    Parameters
    ----------
    spec : Spec
        The request (its ``rate_hz``, ``stamp_jitter_us`` override the draws).
    drawn_rate, drawn_jitter : float
        Drawn controller rate [Hz] and stamp jitter [s].
    delays : tuple of ndarray
        ``(base, mean)`` delivery delays of the link and of the motor stream [s].
    noise : numpy.random.Generator
        The recording's noise stream (draws the jitter, then the delays).

    Returns
    -------
    dict
        The :class:`Recording` fields ``rate_hz``, ``jitter_s``, ``t``,
        ``link_stamp_ns``, ``motor_stamp_ns``, ``link_log_ns``, ``motor_log_ns``.

    """
    rate = spec.rate_hz or drawn_rate
    jitter = drawn_jitter if spec.stamp_jitter_us is None else spec.stamp_jitter_us * 1e-6
    n = max(int(math.floor(spec.duration_s * rate + 1e-6)) + 1, 2)
    t = np.arange(n) / rate

    def stamps():
        clip = min(3.0 * jitter, 0.3 / rate)
        j = np.clip(noise.normal(0.0, 1.0, n) * jitter, -clip, clip) if jitter > 0 else 0.0
        return START_S * 10 ** 9 + np.round((t + j) * 1e9).astype(np.int64)

    link_stamp, motor_stamp = stamps(), stamps()
    link_log = _log_times(noise, link_stamp, delays[0][0], delays[1][0])
    motor_log = _log_times(noise, motor_stamp, delays[0][1], delays[1][1])
    # The motor topic stamped by another clock: later by an offset, drifting by ppm
    # (the recorder logs it on arrival, by its own clock).
    shift = (spec.motor_stamp_offset_s or 0.0) + 1e-6 * (spec.motor_clock_ppm or 0.0) * t
    if np.any(shift):
        motor_stamp = motor_stamp + np.round(shift * 1e9).astype(np.int64)
    return {'rate_hz': rate, 'jitter_s': jitter, 't': t, 'link_stamp_ns': link_stamp,
            'motor_stamp_ns': motor_stamp, 'link_log_ns': link_log, 'motor_log_ns': motor_log}


def life_and_start(spec, joints, exposure_rate):
    """
    Return each joint's exposure at the limit and its operating hours at the first sample.

    Parameters
    ----------
    spec : Spec
        The request (``start_fraction`` of the drawn life or ``start_hours``).
    joints : list
        Drawn joints (``life_h``).
    exposure_rate : ndarray
        The duty's mean exposure rate per joint [1/s of operation].

    Returns
    -------
    tuple of ndarray
        ``(exposure_life, start_hours)``.

    """
    e_life = exposure_rate * np.array([j.life_h for j in joints]) * HOUR
    if spec.start_fraction is not None:
        start_h = np.array([spec.start_fraction * j.life_h for j in joints])
    else:
        start_h = np.full(len(joints), spec.start_hours or 0.0)
    return e_life, start_h


def generate(spec):
    """
    Draw the robot and compute every sample of the recording.

    Parameters
    ----------
    spec : Spec
        What to generate (validated here).

    Returns
    -------
    Stream
        Samples and truth.

    Raises
    ------
    GeneratorError
        If an option is out of range.

    """
    spec.check()
    noise_frac = None if spec.effort_noise_pct is None else spec.effort_noise_pct / 100.0
    joints, cycle = draw_robot(spec.seed, spec.kinds, spec.law, noise_frac)
    rng = _rng(spec.seed, 3)
    drawn_rate = float(rng.choice(RATES_HZ))
    drawn_jitter = rng.uniform(10e-6, 50e-6)
    delays = rng.uniform(50e-6, 300e-6, 2), rng.uniform(100e-6, 1e-3, 2)
    noise = _rng(spec.seed, 4)
    times = clock(spec, drawn_rate, drawn_jitter, delays, noise)
    rate, t = times['rate_hz'], times['t']
    n = len(t)
    arrays = {name: np.empty((n, len(joints))) for name in (
        'q', 'qd', 'torque', 'effort', 'link', 'motor', 'velocity', 'lost_motion', 'exposure')}
    e_rate = np.array([cycle_exposure_rate(j, cycle) for j in joints])
    e_life, start_h = life_and_start(spec, joints, e_rate)
    for i, j in enumerate(joints):
        q, qd, qdd = cycle.motion(j.waypoints_rad, t)
        torque = true_torque(j, q, qd, qdd)
        rate_e = exposure_rate(j, torque, qd) * spec.aging_factor
        steps = 0.5 * (rate_e[1:] + rate_e[:-1]) / rate
        exposure = e_rate[i] * start_h[i] * HOUR + np.concatenate([[0.0], np.cumsum(steps)])
        lm = j.lost_motion(exposure / e_life[i])
        te = (-0.5 * lm * play_side(j, torque) - torque / j.stiffness_nm_per_rad
              + j.order1_rad * np.sin(q + j.order1_phase)
              + j.order2_rad * np.sin(2.0 * q + j.order2_phase))
        link = quantise(q + te + j.link_offset_rad + noise.normal(0.0, j.link_noise_rad, n),
                        j.link_bits)
        motor_step = 2.0 * math.pi / 2 ** j.motor_bits
        motor = np.round((RATIO * q + j.motor_offset_rad) / motor_step
                         + noise.normal(0.0, j.motor_noise_rad / motor_step, n)) * motor_step
        effort = filtered(torque + friction(j, qd) + j.effort_noise_nm * effort_noise(
            noise.normal(0.0, 1.0, n), spec.effort_noise_band_hz, rate),
            spec.effort_filter_s, rate)
        velocity = filtered(qd + noise.normal(0.0, j.velocity_noise_rad_s, n),
                            spec.velocity_filter_s, rate)
        for name, value in (('q', q), ('qd', qd), ('torque', torque), ('effort', effort),
                            ('link', link), ('motor', motor), ('velocity', velocity),
                            ('lost_motion', lm), ('exposure', exposure)):
            arrays[name][:, i] = value
    return Stream(spec=spec, joints=joints, cycle=cycle, exposure_rate=e_rate,
                  exposure_life=e_life, start_hours=start_h, **times, **arrays)


# --------------------------------------------------------------------------- the bag


def _qos(durability):
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness
    from rosbags.interfaces import QosReliability, QosTime
    infinite = QosTime(sec=2147483647, nsec=4294967295)
    return [Qos(history=QosHistory.UNKNOWN, depth=0, reliability=QosReliability.RELIABLE,
                durability=getattr(QosDurability, durability), deadline=infinite,
                lifespan=infinite, liveliness=QosLiveliness.AUTOMATIC,
                liveliness_lease_duration=infinite, avoid_ros_namespace_conventions=False)]


def _columns(stream):
    """Return ``(link (position, velocity, effort), motor ..., link names, motor names)``."""
    spec = stream.spec
    names = [j.name for j in stream.joints]
    motor_pos = stream.motor * (1.0 if spec.motor_angles == 'raw' else 1.0 / RATIO)
    motor_eff = stream.effort / RATIO
    velocity = stream.velocity if spec.velocity else None
    if spec.layout == 'split':
        link = (stream.link, velocity, stream.effort if spec.effort_on == 'link' else None)
        motor = (motor_pos, None, motor_eff if spec.effort_on == 'motor' else None)
        return link, motor, names, names
    nan = np.full(stream.link.shape, np.nan)
    link = (np.hstack([stream.link, motor_pos]),
            None if velocity is None else np.hstack([velocity, nan]),
            np.hstack([stream.effort, nan]) if spec.effort_on == 'link'
            else np.hstack([nan, motor_eff]))
    return link, None, names + [name + spec.motor_suffix for name in names], None


def _events(stream, kept=None):
    """
    Return ``(log_ns, topic, sample)`` in receive order (topic 0 link, 1 motor, 2 truth).

    Parameters
    ----------
    stream : Stream
        Generated samples (``t``, ``link_log_ns``, ``motor_log_ns``, ``spec``).
    kept : tuple of ndarray of bool, optional
        ``(link, motor)``: the messages that arrived (default: every one).

    """
    n = len(stream.t)
    kept = kept or (np.ones(n, dtype=bool),) * 2
    index = [np.flatnonzero(kept[0])]
    logs = [stream.link_log_ns[index[0]]]
    if stream.spec.layout == 'split':
        index.append(np.flatnonzero(kept[1]))
        logs.append(stream.motor_log_ns[index[1]])
    kinds = list(range(len(index)))
    if stream.spec.truth_topics:
        picks = np.unique(np.concatenate([
            np.searchsorted(stream.t, np.arange(0.0, stream.t[-1], 1.0)), [n - 1]]))
        index.append(picks)
        logs.append(stream.link_log_ns[picks] + 1000)
        kinds.append(2)
    log = np.concatenate(logs)
    kind = np.concatenate([np.full(len(x), c) for x, c in zip(index, kinds)])
    sample = np.concatenate(index)
    order = np.lexsort((kind, log))
    return log[order], kind[order], sample[order]


def write_bag(stream, out, overwrite=False, kept=None, generator='independent_generator'):
    """
    Write the stream as a rosbag2 (version 9, MCAP) bag directory with rosbags.

    The bag is written beside ``out`` under a temporary name and renamed into place.

    Parameters
    ----------
    stream : Stream
        Generated samples (this generator's or one with the same fields, such
        as ``third_generator.Stream``).
    out : str or Path
        Bag directory to create.
    overwrite : bool
        Replace an existing ``out``.
    kept : tuple of ndarray of bool, optional
        ``(link, motor)``: the messages that arrived; the others are not
        written (default: every one; the combined layout uses ``link`` only).
    generator : str
        Name of the generator: the seed goes to ``custom_data`` as ``<generator>.seed``.

    Returns
    -------
    dict
        Messages written per topic.

    Raises
    ------
    GeneratorError
        If ``out`` exists and ``overwrite`` is false.

    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores

    out = Path(out)
    if out.exists() and not overwrite:
        raise GeneratorError(f'--out {out} exists already; choose another path')
    ts = get_typestore(Stores.ROS2_JAZZY)
    js_type, ma_type = 'sensor_msgs/msg/JointState', 'std_msgs/msg/Float64MultiArray'
    types = ts.types
    spec = stream.spec
    link_cols, motor_cols, link_names, motor_names = _columns(stream)
    empty = np.empty(0, dtype=np.float64)
    dim = types['std_msgs/msg/MultiArrayDimension'](
        label=','.join(TRUTH_FIELDS), size=len(TRUTH_FIELDS), stride=len(TRUTH_FIELDS))
    truth_layout = types['std_msgs/msg/MultiArrayLayout'](dim=[dim], data_offset=0)

    def joint_state(cols, msg_names, stamp_ns, k):
        st = int(stamp_ns[k])
        header = types['std_msgs/msg/Header'](
            stamp=types['builtin_interfaces/msg/Time'](sec=st // 10 ** 9, nanosec=st % 10 ** 9),
            frame_id='')
        return ts.serialize_cdr(types[js_type](
            header=header, name=msg_names, position=np.ascontiguousarray(cols[0][k]),
            velocity=empty if cols[1] is None else np.ascontiguousarray(cols[1][k]),
            effort=empty if cols[2] is None else np.ascontiguousarray(cols[2][k])), js_type)

    def truth(i, k, remaining, hours):
        values = np.array([stream.link_stamp_ns[k] * 1e-9, stream.lost_motion[k, i],
                           stream.exposure[k, i], hours[i], remaining[i],
                           stream.joints[i].lost_motion_new_rad,
                           stream.joints[i].stiffness_nm_per_rad])
        return ts.serialize_cdr(types[ma_type](layout=truth_layout, data=values), ma_type)

    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f'.{out.name}.', dir=out.parent))
    try:
        writer = Writer(tmp / out.name, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_custom_data(AGING_KEY, repr(float(spec.aging_factor)))
        writer.set_custom_data(f'{generator}.seed', str(spec.seed))
        writer.open()
        volatile, latched = _qos('VOLATILE'), _qos('TRANSIENT_LOCAL')
        conns = [writer.add_connection(spec.link_topic, js_type, typestore=ts,
                                       offered_qos_profiles=volatile)]
        if spec.layout == 'split':
            conns.append(writer.add_connection(spec.motor_topic, js_type, typestore=ts,
                                               offered_qos_profiles=volatile))
        truth_conns = [writer.add_connection(f'/truth/{j.name}', ma_type, typestore=ts,
                                             offered_qos_profiles=latched)
                       for j in stream.joints] if spec.truth_topics else []
        counts = {c.topic: 0 for c in conns + truth_conns}
        log, kind, sample = _events(stream, kept)
        for log_ns, c, k in zip(log.tolist(), kind.tolist(), sample.tolist()):
            if c == 2:
                remaining, hours = stream.remaining_life_h(k), stream.hours_at(k)
                for i, conn in enumerate(truth_conns):
                    writer.write(conn, log_ns, truth(i, k, remaining, hours))
                    counts[conn.topic] += 1
                continue
            cols, msg_names, stamp_ns = ((link_cols, link_names, stream.link_stamp_ns) if c == 0
                                         else (motor_cols, motor_names, stream.motor_stamp_ns))
            writer.write(conns[c], log_ns, joint_state(cols, msg_names, stamp_ns, k))
            counts[conns[c].topic] += 1
        writer.close()
        if out.exists():
            shutil.rmtree(out)
        os.rename(tmp / out.name, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return counts


def generate_bag(spec, out, overwrite=False, generate=generate, write=write_bag):
    """
    Generate a recording and write it; return its truth.

    Parameters
    ----------
    spec : Spec
        What to generate.
    out : str or Path
        Bag directory to create.
    overwrite : bool
        Replace an existing ``out``.
    generate, write : callable
        The generator's :func:`generate` and :func:`write_bag` (default: this one's).

    Returns
    -------
    dict
        :meth:`Stream.truth_json` plus ``bag`` and ``messages`` (per topic).

    """
    stream = generate(spec)
    counts = write(stream, out, overwrite=overwrite)
    truth = stream.truth_json()
    truth.update(bag=str(out), messages=counts)
    return truth


# --------------------------------------------------------------------------- CLI


def cli_parser(prog, description):
    """
    Return a parser with the options every generator takes (each adds its own).

    Parameters
    ----------
    prog, description : str
        The generator's script name and what it writes.

    Returns
    -------
    argparse.ArgumentParser
        ``--out``, ``--seed``, ``--kinds``, the time and layout options, ``--json``.

    """
    p = argparse.ArgumentParser(prog=prog, description=description)
    p.add_argument('--out', required=True, help='bag directory to create')
    p.add_argument('--seed', type=int, default=0, help='seed of every draw (default 0)')
    p.add_argument('--kinds', default='base,shoulder,forearm',
                   help=f'joint kinds, comma-separated, of {", ".join(KINDS)}')
    p.add_argument('--hours', type=float, default=0.05,
                   help='operating hours the recording spans (default 0.05)')
    p.add_argument('--aging-factor', type=float, default=1.0,
                   help='operating seconds per stream second (default 1)')
    start = p.add_mutually_exclusive_group()
    start.add_argument('--start-hours', type=float, help='operating hours before the recording')
    start.add_argument('--start-fraction', type=float,
                       help="fraction of each joint's drawn life before the recording")
    p.add_argument('--rate-hz', type=float, help='controller rate (default: drawn, 100-1000 Hz)')
    p.add_argument('--layout', choices=LAYOUTS, default='split',
                   help="'split': link and motor topics; 'combined': <joint>_motor entries")
    p.add_argument('--motor-angles', choices=('raw', 'output'), default='raw')
    p.add_argument('--effort-on', choices=('link', 'motor'), default='link')
    p.add_argument('--no-velocity', action='store_true', help='leave the velocity field empty')
    p.add_argument('--no-truth-topics', action='store_true', help='no /truth/<joint> topics')
    p.add_argument('--stamp-jitter-us', type=float, help='stamp jitter std (default drawn)')
    p.add_argument('--link-topic', default='/joint_states')
    p.add_argument('--motor-topic', default='/motor_states')
    p.add_argument('--overwrite', action='store_true', help='replace an existing --out')
    p.add_argument('--json', action='store_true', help='print the truth as JSON')
    return p


def cli_spec_options(args):
    """Return the :class:`Spec` keywords of the options :func:`cli_parser` adds."""
    return {'seed': args.seed, 'kinds': tuple(k.strip() for k in args.kinds.split(',')),
            'hours': args.hours, 'aging_factor': args.aging_factor,
            'start_hours': args.start_hours, 'start_fraction': args.start_fraction,
            'rate_hz': args.rate_hz, 'layout': args.layout, 'motor_angles': args.motor_angles,
            'effort_on': args.effort_on, 'velocity': not args.no_velocity,
            'truth_topics': not args.no_truth_topics, 'link_topic': args.link_topic,
            'motor_topic': args.motor_topic, 'stamp_jitter_us': args.stamp_jitter_us}


def cli_run(args, spec, generate_bag=generate_bag):
    """
    Write the bag a command line asks for and print its truth; return the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options (``out``, ``overwrite``, ``json``).
    spec : Spec
        What to generate.
    generate_bag : callable
        The generator's :func:`generate_bag` (default: this one's).

    Returns
    -------
    int
        0, or 1 (``ERROR: <reason>`` on stderr) for invalid values.

    """
    try:
        truth = generate_bag(spec, args.out, overwrite=args.overwrite)
    except GeneratorError as err:
        print(f'ERROR: {err}', file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(truth, indent=1))
    else:
        for name, j in truth['joints'].items():
            law = f" ({j['law']})" if 'law' in j else ''
            print(f"{name} ({j['kind']}): lost motion {j['lost_motion_end_arcmin']:.3f} arcmin, "
                  f"remaining life {j['remaining_life_end_h']:.0f} h{law}")
    return 0


SIGNAL_CHAIN_OPTIONS = ('--effort-filter-ms', '--motor-stamp-offset-ms', '--motor-clock-ppm')
"""Options of :func:`add_signal_chain_options` (the generator's, and ``bench_lost_motion``'s)."""


def add_signal_chain_options(p):
    """Add the effort's filter and the motor topic's clock (:func:`signal_chain_spec`)."""
    p.add_argument('--effort-filter-ms', type=float, metavar='MS',
                   help="effort through a first-order filter of MS ms (a drive's filtered "
                   'torque estimate; default unfiltered)')
    p.add_argument('--motor-stamp-offset-ms', type=float, metavar='MS',
                   help='motor topic stamped MS ms later than the link topic (--layout split)')
    p.add_argument('--motor-clock-ppm', type=float, metavar='PPM',
                   help="motor topic's clock drifting from the link's by PPM (--layout split)")


def signal_chain_spec(args):
    """Return the :class:`Spec` keywords of :func:`add_signal_chain_options` (SI)."""
    def seconds(ms):
        return None if ms is None else 1e-3 * ms
    return {'effort_filter_s': seconds(args.effort_filter_ms),
            'motor_stamp_offset_s': seconds(args.motor_stamp_offset_ms),
            'motor_clock_ppm': args.motor_clock_ppm}


def _parser():
    p = cli_parser('independent_generator.py',
                   'Write a rosbag2 MCAP recording of RV-80E joints from a model independent '
                   'of the twin, and print its truth.')
    p.add_argument('--effort-noise', type=float,
                   help='effort noise, %% of rated torque (default: drawn per joint, 1-5)')
    p.add_argument('--effort-noise-band', type=band_hz, metavar='LOW-HIGH',
                   help='effort noise band-limited to LOW-HIGH Hz (default: white)')
    p.add_argument('--velocity-filter-ms', type=float, metavar='MS',
                   help="velocity field through a first-order filter of MS ms (a drive's "
                   'filtered velocity; default unfiltered)')
    add_signal_chain_options(p)
    p.add_argument('--law', choices=LAWS, help='force the lost-motion growth law')
    return p


def band_hz(text):
    """Parse ``LOW-HIGH`` [Hz] (an option's value)."""
    try:
        low, high = (float(v) for v in text.split('-'))
    except ValueError:
        raise argparse.ArgumentTypeError(f'{text!r}: want LOW-HIGH in Hz, e.g. 5-50') from None
    return (low, high)


def main(argv=None):
    """
    Run the command line; return the exit status (0, 1 for invalid values).

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status.

    """
    args = _parser().parse_args(argv)
    spec = Spec(**cli_spec_options(args), effort_noise_pct=args.effort_noise,
                effort_noise_band_hz=args.effort_noise_band,
                velocity_filter_s=(None if args.velocity_filter_ms is None
                                   else 1e-3 * args.velocity_filter_ms),
                **signal_chain_spec(args), law=args.law)
    return cli_run(args, spec)


if __name__ == '__main__':
    sys.exit(main())
