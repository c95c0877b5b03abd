"""
What a joint's window analysis says in words: why it gives no lost motion, and its warnings.

Never silent: a joint the twin cannot observe is said to be so with the reason a
maintenance engineer can act on (no effort, an effort in other units, encoders that do
not measure the same motion, too low a rate, no torque reversal...), everywhere the
answer appears (``analyze --json`` and its warnings, the nodes' ``/diagnostics``); so is
an observed joint whose lost motion stopped, and what the analysis found in a stream it
still reads (an effort held between slower updates, an effort's noise correlated over
samples, a step of the TE's constant). One line each. These read a
:class:`.window_analysis.WindowAnalyzer`'s counts; its ``not_observed_reason``,
``stale_reason``, ``effort_held``, ``effort_correlated`` and ``te_stepped`` are these.
"""

import math

import numpy as np

from .effort_check import PLAUSIBLE_LOST_MOTION_RAD
from .kinematics import total_ratio
from .units import ARCMIN, ARCSEC, rad_to_arcmin
from .window_fit import PLAUSIBLE_TE_SPAN_RAD

EFFORT_PLAUSIBLE_RATED = 5.0
"""
Largest effort, in rated torques, a joint's reducer is taken to carry.

An RV reducer's momentary maximum torque is about 5 times its rated torque (RV-80E:
3920 N·m against 784); an effort beyond it explains a joint without lost motion as an
effort in other units.
"""

LOW_RATE_HZ = 200.0
"""
Below this sample rate [Hz] a joint without lost motion is reported as sampled too slowly.
"""

SINCE = ('seen', 'without_effort', 'implausible', 'windows')
"""What :class:`SinceLostMotion` counts for :func:`stale_reason`: samples and windows."""

_EMPTY = np.zeros(0)

UNLIKE_MOTIONS = 'the motor and link encoders do not measure the same motion'
"""How the reason for windows whose TE spans degrees begins (:func:`not_observed_reason`)."""

DERIVED_LINK_SPAN_RAD = 0.1 * ARCMIN
"""
Transmission-error span [rad] below which a link angle is the motor's divided by the ratio.

A window gives a lost motion only across a torque reversal under load, and there the
output moves against the motor by the reducer's play (0.3-0.5 arcmin new, more worn) and
its windup: every window's TE spans at least that. A link position that a controller
computes from the motor encoder (most robots have no encoder at the reducer's output)
spans nothing but rounding. 0.1 arcmin is a quarter of a new unit's play and above the
rounding of a position published to 0.001 deg (3.6 arcsec).
"""


def not_observed_reason(analyzer, effort_source='the joint states'):
    """
    Say why no window has given a lost motion the wear is read from, or None once one has.

    An effort found not to be the output torque (the analyzer's ``effort_fault``) is
    said even after windows gave lost motions: they were read with that effort. Encoders
    that do not measure the same motion are said first (they distort the check).

    Parameters
    ----------
    analyzer : WindowAnalyzer
        The joint's window analysis.
    effort_source : str
        Where the effort was expected (a topic name), for the message.

    Returns
    -------
    str or None
        One line a maintenance engineer can act on.

    """
    fault = analyzer.effort_fault
    if fault is None and analyzer.windows_read:
        return None
    derived = derived_link_reason(analyzer)
    if derived is not None:
        # Before the effort's checks: without a TE they read nothing of the effort.
        return derived
    if fault is not None and not analyzer.fit.windows_implausible:
        return fault
    seen = analyzer.samples_seen
    if seen == 0:
        return 'no encoder samples with a transmission error (no motor/link pairs)'
    if analyzer.samples_without_effort >= 0.99 * seen:
        return (f'no effort on {effort_source} ({analyzer.samples_without_effort} of {seen} '
                'samples): the lost motion needs the torque')
    if analyzer.windows_emitted == 0:
        return f'no complete analysis window yet ({seen} samples)'
    if analyzer.fit.windows_implausible:
        return (f'{UNLIKE_MOTIONS}: the '
                f'transmission error spans up to {math.degrees(analyzer.fit.largest_te_span):.3g} '
                f'deg in {analyzer.fit.windows_implausible} of {analyzer.windows_emitted} windows '
                f"(a reducer's moves by arcminutes; at most "
                f'{math.degrees(PLAUSIBLE_TE_SPAN_RAD):g} deg and a lost motion of '
                f'{math.degrees(PLAUSIBLE_LOST_MOTION_RAD) * 60:g} arcmin are read): a '
                'frozen encoder, a motor encoder that counts against the link, link and '
                'motor entries swapped, a wrong reduction ratio or motor_angles, or angles '
                'in degrees or revolutions')
    if fault is not None:
        return fault
    if analyzer.windows_observed:       # every one censored
        return (f'none of its {analyzer.windows_observed} windows with a lost motion read a '
                "play beyond a new nominal unit's (their wear fits lie on the table's "
                "lower bound, and the estimate would be the prior's alone): a unit built "
                'tighter than nominal, read once its play has grown past that, or an '
                'effort whose zero lies beyond the loads (an offset from the torque), or an '
                'effort with the load taken out of it (an external-torque estimate: the '
                'gravity and the motion model subtracted)')
    if analyzer.largest_effort == 0.0:
        return (f'the effort on {effort_source} is zero in every sample that carries '
                f'one ({seen - analyzer.samples_without_effort}): a controller that fills '
                'zeros where it has no effort; the lost motion needs the torque')
    if analyzer.largest_effort < analyzer.edges[0]:
        # Nothing reaches the lowest torque bin: a joint that carries no load, or an
        # effort in other units (a motor torque taken for the output torque).
        return (f'the effort on {effort_source} stays within +-{analyzer.largest_effort:.3g} '
                f'N*m in {analyzer.windows_emitted} windows, below the '
                f'{analyzer.edges[0]:.3g} N*m '
                f'({100.0 * analyzer.edges[0] / analyzer.rated_torque:.0f} % of the rated torque) '
                'from which the lost motion is read: a joint without load, or an effort '
                'in other units (a motor torque: on the motor entry, set motor_effort_units '
                'to motor; on the joint entry, set effort_scale (twin.effort_scale in '
                f'--config) to the ratio, {total_ratio(analyzer.params.geometry):g})')
    rate = analyzer.rate_hz
    if math.isfinite(rate) and rate < LOW_RATE_HZ:
        return (f'{rate:.0f} Hz: too few samples per torque reversal in '
                f'{analyzer.windows_emitted} windows')
    if analyzer.largest_effort > EFFORT_PLAUSIBLE_RATED * analyzer.rated_torque:
        return (f'the effort on {effort_source} reaches {analyzer.largest_effort:.3g} N*m, '
                f'{analyzer.largest_effort / analyzer.rated_torque:.3g} times the rated torque '
                f'(a reducer takes at most about {EFFORT_PLAUSIBLE_RATED:g} times, '
                'momentarily): not the output torque in N*m (a torque in joint units '
                'on the motor entry, taken for a motor torque and multiplied by the '
                'ratio: motor_effort_units joint; or other units: effort_scale, '
                'twin.effort_scale in --config)')
    if analyzer.fit.windows_offset_unremoved:
        return (f'the link and motor encoders are stamped up to '
                f'{1e3 * analyzer.fit.largest_unremoved_offset_s:.3g} ms apart: '
                f'{analyzer.fit.windows_offset_unremoved} of {analyzer.windows_emitted} windows '
                'had torque reversals, but their transmission error carried that offset, which '
                'is removed once learnt from 5 windows that find it; no lost motion is read '
                'before (stamp both encoders on one clock)')
    if analyzer.fit.windows_friction_unknown:
        return (f'the friction in the effort could not yet be told from the load: '
                f'{analyzer.fit.windows_friction_unknown} of {analyzer.windows_emitted} windows '
                'had torque reversals, but the joint has not yet moved both ways in a fifth '
                'of the samples each, and a motor friction in the effort would pick the '
                'flank (an effort measured by a torque sensor at the output carries no '
                'friction: set twin.friction_in_effort to 0)')
    return (f'no torque reversal at equal |T| above the effort noise in '
            f'{analyzer.windows_emitted} windows (the joint did not reverse under load)')


def link_from_motor(analyzer):
    """
    Return whether a joint's link angle is its motor angle over the ratio (no output encoder).

    True once windows with a torque reversal under load were analysed and none had a
    transmission error spanning :data:`DERIVED_LINK_SPAN_RAD`; such a joint is never
    observed (:func:`not_observed_reason` says so).
    """
    return bool(analyzer.fit.windows_reversed) and \
        analyzer.fit.largest_reversed_te_span < DERIVED_LINK_SPAN_RAD


def derived_link_reason(analyzer):
    """
    Say that a joint's link angle is its motor angle over the ratio, else None.

    :func:`link_from_motor` in words: the reason it is not observed, wherever said.
    """
    if not link_from_motor(analyzer):
        return None
    return (f'the link angle follows the motor angle divided by the reduction ratio to within '
            f'{analyzer.fit.largest_reversed_te_span / ARCSEC:.2g} arcsec in all '
            f'{analyzer.fit.windows_reversed} windows with a torque reversal under load, where a '
            "reducer's play alone moves it by tenths of an arcminute: the link position is "
            "computed from the motor encoder, not read by an encoder at the reducer's output "
            "(or the motor position from the link's); the lost motion needs both encoders (a "
            'secondary, output-side one)')


def stale_reason(analyzer, after_s, effort_source='the joint states'):
    """
    Say why an observed reducer's lost motion stopped, once ``after_s`` of stream passed.

    Parameters
    ----------
    analyzer : WindowAnalyzer
        The joint's window analysis.
    after_s : float
        Stream time [s] after the last window with a lost motion from which it counts.
    effort_source : str
        Where the effort was expected (a topic name), for the message.

    Returns
    -------
    tuple of (float, str, bool) or None
        Stream seconds since the last lost motion, the cause (one line), and whether
        the stream is faulty (effort missing, encoders that do not measure the same
        motion) rather than only without a torque reversal; None while the lost
        motion is current or was never read (:func:`not_observed_reason` says why).

    """
    if analyzer.last_observed_t is None or analyzer.latest_t is None:
        return None
    gap = analyzer.latest_t - analyzer.last_observed_t
    if gap < after_s:
        return None
    since = analyzer.since_lost_motion
    if since['without_effort'] >= 0.1 * max(since['seen'], 1):
        return gap, (f'no effort on {effort_source} in {since["without_effort"]} of '
                     f'{since["seen"]} samples since (their operating time is not '
                     'counted)'), True
    if since['implausible']:
        return gap, (f'in {since["implausible"]} of {since["windows"]} windows since, the '
                     f'transmission error spans up to '
                     f'{math.degrees(analyzer.fit.largest_te_span):.3g} deg '
                     '(a frozen encoder?)'), True
    return gap, (f'no torque reversal under load in {since["windows"]} windows since'), False


def effort_held(analyzer):
    """
    Say when the effort is held between updates slower than the stream, else None.

    See :mod:`.held_effort`: its noise is then taken between its updates.
    """
    hz = analyzer.fit.held_effort.update_hz
    if hz is None:
        return None
    return (f'the effort repeats itself on successive samples: it changes at about '
            f'{hz:.0f} Hz on a {analyzer.rate_hz:.0f} Hz stream (held between slower updates, '
            'or quantised more coarsely than it changes); its noise is taken between its '
            'changes, and the lost motion rests on fewer independent samples than the '
            "stream's rate suggests")


def effort_correlated(analyzer):
    """
    Say when the effort's noise is correlated over samples, else None.

    See :meth:`.torque_smoothing.TorqueSmoothing.mean_noise`. A filter that makes the
    noise so also delays the load (a drive's torque filter: by its time constant), which
    the noise cannot tell from a ripple of the current loop: the line names the setting
    that undoes a filter (``effort_lag_s``, :mod:`.effort_lag`) while it is 0.
    """
    smoothing = analyzer.fit.smoothing
    ratio = smoothing.correlated_ratio
    if ratio is None:
        return None
    line = (f"the effort's noise is correlated over successive samples (band-limited or "
            f'filtered): its averages are {ratio:.1f} times as noisy as its sample-to-sample '
            f'scatter implies (in {smoothing.correlated_windows} windows); the '
            "torque bands are widened to the averages' own noise, and the lost motion rests "
            'on fewer independent samples')
    if analyzer.effort_lag_s:
        return line
    return (line + '. If the drive low-pass filters its torque, the effort also lags the '
            'load by about the time constant, which puts samples of each torque reversal '
            'on the wrong flank (an unloaded joint read half its lost motion through a '
            "50 ms filter): set twin.effort_lag_s to the drive's filter time constant")


def te_stepped(analyzer):
    """
    Say where the TE's constant stepped between windows, else None.

    A step of :data:`.flanks._POOL_JUMP` or more in a window's mean, less what the
    time offset and the windup under its mean load give it, is an encoder re-homed or
    whose offset changed, or a motor turn count lost across a gap (``2·pi/i``); the
    flank pool starts afresh there, so the readings hold, but the step is said.
    """
    fit = analyzer.fit
    if fit.te_step is None:
        return None
    into, step = fit.te_step
    more = fit.te_steps - 1
    also = f' (and {more} more)' if more else ''
    return (f"the transmission error's constant stepped by about "
            f'{rad_to_arcmin(step):+.0f} arcmin {into:.1f} s into the '
            f'stream{also}: an encoder re-homed or its offset changed, or a motor turn '
            'count lost across a gap; the windows after a step are read afresh')


class SinceLostMotion:
    """
    Count a joint's samples and windows since its last window with a lost motion.

    What :func:`stale_reason` tells the cause from (:data:`SINCE`): the samples seen
    and those without an effort, the windows and those whose TE spans more than a
    reducer's (``implausible``). A window with a lost motion starts the counts afresh
    at its end, with the samples after it of the update that cut it.

    Attributes
    ----------
    counts : dict
        Count per name of :data:`SINCE`.

    """

    def __init__(self):
        self.counts = dict.fromkeys(SINCE, 0)
        # Stamps [s] of the last update's fresh samples, and of those without an effort.
        self._recent = (_EMPTY, _EMPTY)

    def samples(self, fresh_t, effortless_t):
        """Count an update's fresh samples and those without an effort (their stamps [s])."""
        self.counts['seen'] += fresh_t.size
        self.counts['without_effort'] += effortless_t.size
        self._recent = (fresh_t, effortless_t)

    def windows(self, found):
        """Count an update's windows, in order (:class:`.window_fit.WindowFeatures`)."""
        for f in found:
            if math.isfinite(f.lost_motion):
                seen, without = self._recent
                self.counts = {'seen': int(np.count_nonzero(seen > f.t_end)),
                               'without_effort': int(np.count_nonzero(without > f.t_end)),
                               'implausible': 0, 'windows': 0}
            else:
                self.counts['windows'] += 1
                self.counts['implausible'] += int(f.implausible)
