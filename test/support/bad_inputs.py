"""
The table of bad inputs, shared by the live (DDS) and the offline (bag) reliability tests.

One simulated joint (the core's :class:`~reducer_twin.core.simulator.JointSimulator`,
robot profile under 1.2x rated gravity load, 500 Hz, aging factor 3.6e5 so that a 2 s
window is 200 operating hours and every window carries wear information) is turned
into the JointState messages a controller publishes: ``<joint>`` (link side) and
``<joint>_motor`` (motor side) in one message, or the two sides on two topics. Each
:class:`Case` takes that clean stream and spoils it at one place (:data:`AT`), as the
issue lists: NaN / inf positions, arrays of mismatched length, unknown joint names,
duplicate and out-of-order stamps, the clock jumping back (a bag played in a loop, sim
time reset), a 10 s dropout, encoder wrap-around, single-sample spikes, motor and link
at different rates.

Where a case moves stamps (dropout, clock reset) it moves the stamps of the *same*
samples, so that the clean run of the stream is the reference of what the estimate
should be: the difference isolates how the twin handles the anomaly.

Each case states what the README's ingestion table promises: the counts of
``EncoderIngest.counts()`` (live) and of the analysis' ingest diagnostics (offline).
They differ in one documented place: the live node rejects a whole malformed message
(``rejected_messages``), the bag decoder reads a field whose length does not match the
names, or a joint the message does not name, as NaN (counted ``non_finite``).

Not a test module (pytest collects ``test_*.py`` only); the test modules load it by
path, because the test tree is imported without packages (``--import-mode=importlib``).
"""

from dataclasses import dataclass, field
import math

import numpy as np
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, SimConfig

RATE_HZ = 500.0
"""Sample rate of the simulated encoders [Hz]."""

SECONDS = 12.0
"""Stream length [s]: five complete 2 s windows after the injection point."""

AGING = 3.6e5
"""Seconds of wear exposure per stream second (a 2 s window is 200 h)."""

SAMPLES = int(RATE_HZ * SECONDS)

AT = int(0.4 * SAMPLES)
"""Index of the sample every case spoils (4.8 s into the stream, mid-window)."""

JOINT = 'j'
MOTOR = JOINT + '_motor'

DROPOUT_S = 10.0
"""Length of the dropout [s]."""

CLOCK_RESET_S = 100.0
"""How far sim time is reset [s]: past the estimator's 60 s replay horizon."""


@dataclass(frozen=True)
class Message:
    """One JointState message as a controller sends it."""

    topic: str              # 'link' (the joint_states topic) or 'motor' (split form)
    stamp_ns: int
    names: tuple
    position: tuple
    velocity: tuple = ()
    effort: tuple = ()


@dataclass(frozen=True)
class Stream:
    """The clean simulated stream of one joint (arrays over samples)."""

    t0_ns: int
    t: np.ndarray
    motor: np.ndarray
    link: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray

    def stamp(self, k, shift_s=0.0):
        """Return the stamp of sample ``k`` [ns], moved by ``shift_s``."""
        return self.t0_ns + int(round((self.t[k] + shift_s) * 1e9))

    def message(self, k, shift_s=0.0, link=None, motor=None):
        """Return the combined message of sample ``k`` (positions overridable)."""
        return Message('link', self.stamp(k, shift_s), (JOINT, MOTOR),
                       (self.link[k] if link is None else link,
                        self.motor[k] if motor is None else motor),
                       (self.velocity[k], math.nan), (self.effort[k], math.nan))

    def messages(self, ks=None, shift_s=0.0):
        """Return the combined messages of samples ``ks`` (default all)."""
        ks = range(self.t.size) if ks is None else ks
        return [self.message(k, shift_s) for k in ks]


def simulate(t0_ns):
    """
    Return the clean stream, stamped from ``t0_ns``.

    Parameters
    ----------
    t0_ns : int
        Stamp of the first sample [ns].

    Returns
    -------
    Stream
        :data:`SAMPLES` samples of one joint.

    """
    sim = JointSimulator(ReducerParams(), SimConfig(
        profile='robot', exact_mesh=False, aging_factor=AGING, rate_hz=RATE_HZ, seed=5,
        load_torque_nm=1.2 * 784.0))
    b = sim.step(SAMPLES)
    return Stream(int(t0_ns), b.t, b.motor_angle, b.link_angle, b.link_velocity, b.effort)


def _wrap(x):
    """
    Angles as a single-turn encoder reports them, in [0, 2 pi).

    The robot cycle swings the link from -30 to 170 deg, across the encoder's zero.
    """
    return np.mod(np.asarray(x), 2.0 * math.pi)


def wraps(values):
    """Return how often a single-turn reading jumps by more than pi between neighbours."""
    return int(np.count_nonzero(np.abs(np.diff(values)) > math.pi))


@dataclass(frozen=True)
class Case:
    """
    One bad input: how it spoils the stream and what the twin must count.

    Attributes
    ----------
    name : str
        What happens, as a sentence (the test id).
    spoil : callable
        ``spoil(stream) -> list of Message`` in arrival order.
    live : dict
        Expected ``EncoderIngest.counts()`` entries of the joint (keys not listed are
        0, ``published`` excepted); ``rejected_messages``: messages the node refuses.
    bag : dict
        Expected ingest counts of the offline analysis, the same keys; also what its
        ``rejected`` total is made of.
    split : bool
        Link and motor on two topics (the node's ``motor_topic``).
    published : callable
        ``published(stream) -> int``: paired samples that must come out.
    same_windows : bool
        The windows hold the clean run's samples but for the bad one, so the
        estimate must match the clean one closely; False where the case cuts the
        windows elsewhere (a hole, a reset) or changes every sample (interpolation).
    not_naming : int
        Messages that do not name the joint: offline neither messages of it nor
        rejected samples (its entries are absent, not bad values).

    """

    name: str
    spoil: object
    live: dict
    bag: dict = None
    split: bool = False
    published: object = field(default=lambda s: SAMPLES)
    same_windows: bool = True
    not_naming: int = 0

    def expected(self, offline):
        """Return the expected counts, live or offline."""
        return dict(self.live if not offline or self.bag is None else self.bag)


def _replace(stream, k, message):
    out = stream.messages()
    out[k] = message
    return out


def _nan_link(s):
    return _replace(s, AT, s.message(AT, link=math.nan))


def _inf_motor(s):
    return _replace(s, AT, s.message(AT, motor=math.inf))


def _short_position(s):
    m = s.message(AT)
    return _replace(s, AT, Message('link', m.stamp_ns, m.names, m.position[:1], m.velocity,
                                   m.effort))


def _unknown_joints(s):
    m = s.message(AT)
    return _replace(s, AT, Message('link', m.stamp_ns, ('gripper', 'tool_changer'),
                                   m.position, m.velocity, m.effort))


def _reordered_with_extra(s):
    m = s.message(AT)
    return _replace(s, AT, Message('link', m.stamp_ns, ('gripper', MOTOR, JOINT),
                                   (0.01, m.position[1], m.position[0]),
                                   (0.0, math.nan, m.velocity[0]), (1.0, math.nan, m.effort[0])))


def _duplicate(s):
    out = s.messages()
    out.insert(AT + 1, out[AT])
    return out


def _swapped(s):
    out = s.messages()
    out[AT], out[AT + 1] = out[AT + 1], out[AT]
    return out


def _bag_loop(s):
    return s.messages(range(AT)) + s.messages()


def _clock_reset(s):
    return s.messages(range(AT)) + s.messages(range(AT, SAMPLES), -CLOCK_RESET_S)


def _dropout(s):
    return s.messages(range(AT)) + s.messages(range(AT, SAMPLES), DROPOUT_S)


def _single_turn(s):
    link, motor = _wrap(s.link), _wrap(s.motor)
    return [s.message(k, link=link[k], motor=motor[k]) for k in range(SAMPLES)]


def _single_turn_wraps(s):
    return wraps(_wrap(s.link)) + wraps(_wrap(s.motor))


def _link_spike(s):
    return _replace(s, AT, s.message(AT, link=s.link[AT] + 0.05))


def _motor_spike(s):
    return _replace(s, AT, s.message(AT, motor=s.motor[AT] + 2.0))


def _half_rate_motor(s):
    """Link at 500 Hz on one topic, motor at 250 Hz on another, ending on a motor sample."""
    out = []
    for k in range(SAMPLES - 1):
        m = s.message(k)
        out.append(Message('link', m.stamp_ns, (JOINT,), m.position[:1], m.velocity[:1],
                           m.effort[:1]))
        if k % 2 == 0:
            out.append(Message('motor', m.stamp_ns, (JOINT,), m.position[1:]))
    return out


CASES = [
    Case('a NaN link position is dropped and counted as non-finite, its pair as unpaired',
         _nan_link, {'stream_non_finite': 1, 'unpaired': 1},
         published=lambda s: SAMPLES - 1),
    Case('an infinite motor position is dropped and counted as non-finite',
         _inf_motor, {'stream_non_finite': 1, 'unpaired': 1},
         published=lambda s: SAMPLES - 1),
    Case('a position array shorter than the names is refused whole',
         _short_position, {'rejected_messages': 1, 'stream_missing': 1},
         published=lambda s: SAMPLES - 1),
    Case('a message that names only unknown joints is refused whole',
         _unknown_joints, {'rejected_messages': 1, 'stream_missing': 1},
         bag={}, published=lambda s: SAMPLES - 1, not_naming=1),
    Case('an unknown extra joint and another name order are read by name',
         _reordered_with_extra, {}),
    Case('a duplicate stamp is dropped and counted',
         _duplicate, {'stream_duplicate': 1}),
    Case('an out-of-order stamp is dropped and counted, leaving a missing sample',
         _swapped, {'stream_out_of_order': 1, 'stream_missing': 1},
         published=lambda s: SAMPLES - 1),
    Case('a bag played in a loop restarts the stream and its windows are not counted twice',
         _bag_loop, {'stream_clock_jump': 1}, published=lambda s: SAMPLES + AT),
    Case('sim time reset 100 s back restarts the stream and the new windows count',
         _clock_reset, {'stream_clock_jump': 1}, same_windows=False),
    Case('a 10 s dropout starts a new segment and nothing is bridged across it',
         _dropout, {'stream_gap': 1}, same_windows=False),
    Case('single-turn encoders that wrap around are unwrapped',
         _single_turn, {'stream_wrap': _single_turn_wraps}),
    Case('a single-sample link spike is dropped',
         _link_spike, {'spike': 1}, published=lambda s: SAMPLES - 1),
    Case('a single-sample motor spike is dropped',
         _motor_spike, {'spike': 1}, published=lambda s: SAMPLES - 1),
    Case('a motor stream at half the link rate is interpolated at the link stamps',
         _half_rate_motor, {}, split=True, published=lambda s: SAMPLES - 1,
         same_windows=False),
]
"""Every bad input of the issue, in the order of its list."""


def expected_counts(case, stream, offline=False):
    """
    Return every ingest count the case must produce (zeros included).

    Parameters
    ----------
    case : Case
        The bad input.
    stream : Stream
        The clean stream (for counts that depend on it).
    offline : bool
        The analysis' expectations rather than the node's.

    Returns
    -------
    dict
        Count name to value, for the keys of the node's (or the analysis') counts
        except ``published``, ``step`` and the ``*_missing`` of the motor side.

    """
    sides = ('link', 'motor') if case.split else ('stream',)
    keys = [f'{side}_{r}' for side in sides for r in
            ('non_finite', 'duplicate', 'out_of_order', 'clock_jump', 'gap', 'wrap',
             'missing')] + ['unpaired', 'spike']
    out = dict.fromkeys(keys, 0)
    for key, value in case.expected(offline).items():
        out[key] = value(stream) if callable(value) else value
    return out
