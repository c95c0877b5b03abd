"""
What the offline analysis says about each joint of a bag, as sentences.

This module owns the words the analysis of a bag (:class:`.pipeline._Run`) gives a joint:
why it is not observed (encoder entries swapped or in mixed units, a stream that cannot be
read, malformed effort arrays), why it is observed in part only, how its inputs were read
(a motor that counts against the link, a motor torque beside output angles, derived topics
renamed), how its service time was taken, what its reducer's last bag left it, the error
of a ``--config`` its data contradict, and the bag's stream warnings said at the end
(motor angles assumed raw, messages out of stamp order, malformed messages). Each function
takes plain values (names, counts, stamps [ns], seconds) and returns a line, or None when
there is nothing to say; the run says them (:func:`.reading.warn`) and keeps them in the
:class:`.results.JointResult`.
"""

import math

from reducer_twin.core.errors import StateFileError
from reducer_twin.core.joint_twin import TwinFront
from reducer_twin.core.life_basis import play_clause, rate_resolved, rate_unresolved
from reducer_twin.core.soft_zone import carried_line
from reducer_twin.msg_adapters.layouts import WEAR_ESTIMATE

GAP_SHARE = 0.05
"""Share of a joint's stream in holes without samples from which the time lost is said."""

PARTIAL_SHARE = 0.2
"""Share of a joint's stream after its last lost motion from which the estimate is partial."""

PARTIAL_WINDOWS = 3
"""Windows of stream after the last lost motion below which the estimate is taken as current."""


def swap_reason(joint, motor_entry, motor_topic, link_over_motor, ratio):
    """
    Say that a joint's link and motor entries are swapped.

    Parameters
    ----------
    joint : str
        Joint name (its link entry).
    motor_entry : str
        Name of its motor entry.
    motor_topic : str or None
        Topic of the motor entry when the two are split, else None.
    link_over_motor : float
        The link entry's travel over the motor entry's (about the ratio).
    ratio : float
        The reducer's ratio (motor turns per link turn).

    Returns
    -------
    str
        The joint's reason for not being observed.

    """
    where = f'{motor_topic} ' if motor_topic else ''
    return (f'its link entry {joint} moves {link_over_motor:.3g} times its motor '
            f'entry {where}{motor_entry}, where a motor moves about '
            f'{ratio:g} times its link: the two are swapped (the '
            "motor encoder published under the joint's name); the twin reads the link "
            'from the joint entry and the motor from the motor entry')


def units_reason(joint, motor_entry, motor_topic, travel, units, ratio):
    """
    Say that a joint's encoders read in mixed units.

    Parameters
    ----------
    joint : str
        Joint name (its link entry).
    motor_entry : str
        Name of its motor entry.
    motor_topic : str or None
        Topic of the motor entry when the two are split, else None.
    travel : float
        Motor travel over link travel.
    units : tuple of (float, str, str, bool)
        :func:`.travel_ratio.motor_angle_form`'s mixed units: the factor, what gives it,
        the remedy and whether the motor angles are raw.
    ratio : float
        The reducer's ratio (motor turns per link turn).

    Returns
    -------
    str
        The joint's reason for not being observed.

    """
    factor, what, remedy, raw = units
    where = f'{motor_topic} ' if motor_topic else ''
    form = f'{ratio:g} x {factor:.4g}' if raw else f'{factor:.4g}'
    return (f'its motor entry {where}{motor_entry} moves {travel:.4g} times its link entry '
            f'{joint}, where a motor in radians moves {ratio:g} times its link (raw '
            f'angles) or once (divided by the ratio): {form}, which {what} gives; no '
            f'transmission error can be read from the two: {remedy}')


def stream_reason(sides, counts, samples, span_ns, max_gap_s, link_topic, motor_topic):
    """
    Say why a joint's stream gives no lost motion before its windows are asked.

    Stamps that do not advance, samples too far apart (:func:`too_slow_reason`), pairs
    all dropped as spikes, or no pairs at all, naming the topic.

    Parameters
    ----------
    sides : list of str
        The ingest count prefixes of the joint: ``['stream']``, or ``['link', 'motor']``
        for two topics.
    counts : dict
        The joint's ingest counts (``<side>_duplicate``, ``spike``, ``unpaired``).
    samples : int
        Motor/link sample pairs published to the twin.
    span_ns : list of int or None
        First and last stamp [ns] of its paired samples, None without any.
    max_gap_s : float
        Longest step between samples [s] the twin bridges (``twin.max_gap_s``).
    link_topic, motor_topic : str
        The JointState topics of the link and motor entries (``motor_topic`` None when
        one message carries both).

    Returns
    -------
    str or None
        The joint's reason for not being observed, or None when its stream is readable
        (the window analysis then says why).

    """
    for side in sides:
        topic = motor_topic if side == 'motor' else link_topic
        dup = counts.get(f'{side}_duplicate', 0)
        if dup and dup >= 0.5 * max(samples + dup, 1):
            return (f'stamps do not advance on {topic}: {dup} samples repeat an earlier '
                    'stamp (frozen clock or all-zero header stamps)')
    slow = too_slow_reason(samples + counts.get('spike', 0), span_ns, max_gap_s, link_topic)
    if slow is not None:
        return slow
    spikes = counts.get('spike', 0)
    if spikes and spikes >= samples:
        return (f'{spikes} of {spikes + samples} motor/link sample pairs were '
                'dropped as spikes of the transmission error: the encoders jump against '
                'each other (positions in degrees or counts, a wrong reduction ratio or '
                'motor_angles, link and motor entries swapped, or faulty encoders)')
    if samples == 0:
        return (f'no motor/link sample pairs on {link_topic}'
                + (f' and {motor_topic}' if motor_topic else '')
                + f' ({counts.get("unpaired", 0)} unpaired)')
    return None


def too_slow_reason(pairs, span_ns, max_gap_s, link_topic):
    """
    Say a stream whose samples are further apart than the twin bridges.

    Every step then starts a new segment: no transmission error, and the motor's turns
    between samples look like spikes (a 10 Hz stream was said to be in degrees).

    Parameters
    ----------
    pairs : int
        Motor/link sample pairs, spikes included.
    span_ns : list of int or None
        First and last stamp [ns] of the joint's paired samples, None without any.
    max_gap_s : float
        Longest step between samples [s] the twin bridges (``twin.max_gap_s``).
    link_topic : str
        The JointState topic of the link entries.

    Returns
    -------
    str or None
        The reason, or None when the samples are close enough (or too few to tell).

    """
    if span_ns is None or pairs < 2:
        return None
    first, last = (t * 1e-9 for t in span_ns)
    step = (last - first) / (pairs - 1)
    if not step > max_gap_s:
        return None
    return (f'its samples on {link_topic} are {step:.3f} s apart on average '
            f'({1.0 / step:.0f} Hz), further than the {max_gap_s:g} s the '
            'twin bridges (twin.max_gap_s): too slow to read the transmission error; '
            'record the joint states at 100 Hz or more')


def effort_faults_reason(reason, faults, rows):
    """
    Name malformed effort arrays as the cause of a joint's missing effort.

    Parameters
    ----------
    reason : str or None
        The joint's reason for not being observed.
    faults : dict of str to tuple of (int, str)
        Per topic, the messages whose effort array is malformed and the first problem.
    rows : dict of str to int
        Per topic, the messages read.

    Returns
    -------
    str or None
        ``reason``, preceded by the malformed arrays where it is a missing effort.

    """
    if reason is None or not reason.startswith('no effort on ') or not faults:
        return reason
    said = '; '.join(f'{count:,} of {rows[topic]:,} JointState messages '
                     f'on {topic} are malformed: {first}'
                     for topic, (count, first) in faults.items())
    return f'{said}; their efforts are not read: {reason}'


def gaps_line(gap_time_s, gaps, span_ns, max_gap_s):
    """
    Say how much of a joint's stream fell in holes, not counted as operation.

    Parameters
    ----------
    gap_time_s : float
        Stream time [s] in holes without samples.
    gaps : int
        Holes longer than ``max_gap_s``.
    span_ns : list of int or None
        First and last stamp [ns] of the joint's paired samples, None without any.
    max_gap_s : float
        Longest step between samples [s] the twin bridges (``twin.max_gap_s``).

    Returns
    -------
    str or None
        The line (after ``<joint>: ``), or None below :data:`GAP_SHARE` of the stream.

    """
    if span_ns is None or not gaps:
        return None
    first, last = (t * 1e-9 for t in span_ns)
    if gap_time_s < GAP_SHARE * max(last - first, 1e-9):
        return None
    return (f'{gap_time_s:,.1f} s of its '
            f'{last - first:,.1f} s stream ({100 * gap_time_s / (last - first):.0f} %) fall '
            f'in {gaps:,} hole{"s" if gaps > 1 else ""} longer than '
            f'{max_gap_s:g} s without samples '
            '(lost messages, or a pause in publishing): that time is not counted as '
            'operation; if the robot ran meanwhile, its wear rate per operating hour reads '
            'high and its remaining life short by up to that share')


def carried_front(state, params):
    """
    Return what the reducer's last bag left its front (``JointFront``'s ``carried``).

    The front's state, or from a store written before it was kept the time offset
    alone; a front state this analysis cannot continue from (another version, or
    values out of range) is said, and only its time offset is carried.

    Parameters
    ----------
    state : dict or None
        The joint's state at the end of its reducer's last bag (``BagResult.states``).
    params : ReducerParams
        The joint's reducer.

    Returns
    -------
    carried : dict
        ``{'front': state}`` or ``{'time_offset_s': seconds or None}``.
    line : str or None
        Why the front state is not usable (after ``<joint>: ``), None when it is or
        there is none.

    """
    state = state or {}
    front = state.get('front')
    if front is None:
        return {'time_offset_s': state.get('time_offset_s')}, None
    try:
        TwinFront(params).continue_from(front)
    except StateFileError as err:
        return {'time_offset_s': state.get('time_offset_s')}, (
            f'what its last bag learnt of the encoders and the soft '
            f'zone is not usable ({err}): learnt afresh from this bag')
    return {'front': front}, None


def soft_zone_carried_line(soft_zone, wear, within_zone=None):
    """
    Say a soft zone carried over from the reducer's last bag that this one has not shown.

    Its shortfall still gives the lost motion at the test torque (``initial_states``,
    :meth:`.pipeline.EstimatorStage.step`).

    Parameters
    ----------
    soft_zone : dict or None
        The soft zone this bag showed (:attr:`.joint_twin.TwinFront.soft_zone`).
    wear : ndarray or None
        The joint's wear records (rows of :data:`.layouts.WEAR_ESTIMATE`).
    within_zone : str or None
        Where the shortfall carried is negative (loads within a soft zone): this bag's own
        line of it (:attr:`.window_analysis.WindowAnalyzer.within_zone`), if said.

    Returns
    -------
    str or None
        The line, or None when this bag showed what was carried or none was carried.

    """
    short = _latest_shortfall(wear)
    shown = soft_zone if short > 0.0 else within_zone
    if shown is not None or short == 0.0 or not math.isfinite(short):
        return None
    return carried_line(short)


def _latest_shortfall(wear):
    """Return the soft zone's shortfall the latest wear record gives the lost motion less [rad]."""
    if wear is None or not len(wear):
        return 0.0
    return float(wear[-1][WEAR_ESTIMATE.fields.index('soft_zone_shortfall_rad')])


def not_compared_line(observed, levels, wear, line):
    """
    Say that an alarm rests on the loaded flanks' play, the test torque never compared.

    Said only where the answer is a warning or worse: a clean short recording whose
    loads seldom dwell at the test torque is common, and on a unit without a soft zone the
    play is its lost motion. Nothing where a soft zone carried over from the reducer's last
    recording gives the lost motion at the test torque. The rule is
    :func:`.life_basis.play_clause`, the live ``life_publisher``'s too.

    Parameters
    ----------
    observed : bool
        Whether the joint is observed (:attr:`.results.JointResult.observed`).
    levels : list of str
        Its ``/diagnostics`` levels, one per window.
    wear : ndarray
        Its wear records (rows of :data:`.layouts.WEAR_ESTIMATE`).
    line : str or None
        Why no window compared (:attr:`.soft_zone.SoftZoneCheck.not_compared`), or None.

    Returns
    -------
    str or None
        ``line`` where it is to be said, else None.

    """
    if not observed or not levels:
        return None
    return play_clause(levels[-1], 'not compared', line,
                       {'soft_zone_shortfall_rad': _latest_shortfall(wear)})


def rate_line(observed, wear):
    """
    Say when an observed joint's wear rate is not yet its own (not resolved).

    Parameters
    ----------
    observed : bool
        Whether the joint is observed (:attr:`.results.JointResult.observed`).
    wear : ndarray
        The joint's wear records (rows of :data:`.layouts.WEAR_ESTIMATE`).

    Returns
    -------
    str or None
        The line (after ``<joint>: ``), or None when the rate is resolved or the joint
        not observed.

    """
    if not (observed and len(wear)):
        return None
    last = dict(zip(WEAR_ESTIMATE.fields, wear[-1]))
    if rate_resolved(last):
        return None
    return (f'{rate_unresolved(last)}; watch it longer, analyse its '
            'recordings in time order with --store, or give its operating time before '
            'the recording (service_time_s in --config: the hour meter)')


def service_taken(outputs):
    """
    Give how a joint's service time was taken, and the lines of one that was not.

    ``taken`` None: the reducer met without state has a service time the windows have
    not judged yet (fewer than the duty needs); it is judged in a later bag of its
    history (``--store``).

    Parameters
    ----------
    outputs : list of dict
        The joint's estimator and life outputs per window (their ``'service'`` where
        judged: taken, rate scale, line, hours).

    Returns
    -------
    service : dict or None
        ``{'hours', 'taken', 'rate_scale'}`` as last judged, None when never.
    lines : list of str
        Why a service time was not taken, once per judgement that refused it.

    """
    service, lines = None, []
    for out in outputs:
        if 'service' in out:
            taken, scale, line, hours = out['service']
            service = {'hours': hours, 'taken': taken, 'rate_scale': scale}
            if taken is False:
                lines.append(line)
    return service, lines


def stale_after_s(span_ns, window_s):
    """
    Return the stream time [s] after the last lost motion from which an estimate is partial.

    Parameters
    ----------
    span_ns : list of int
        First and last stamp [ns] of the joint's paired samples.
    window_s : float
        Analysis window [s].

    Returns
    -------
    float
        :data:`PARTIAL_SHARE` of the joint's stream, at least :data:`PARTIAL_WINDOWS`
        windows.

    """
    first, last = (t * 1e-9 for t in span_ns)
    return max(PARTIAL_SHARE * (last - first), PARTIAL_WINDOWS * window_s)


def partial_reason(joint, span_ns, spans_ns, window_s, stale, last_observed_t,
                   samples_without_effort, samples_seen, effort_topic):
    """
    Say when an observed joint's lost motion stopped well before its stream did.

    The estimate then stands as of its last observed window (without effort the
    operating time after it is not even counted): never presented as the end's
    without a word.

    Parameters
    ----------
    joint : str
        Joint name.
    span_ns : list of int
        First and last stamp [ns] of the joint's paired samples.
    spans_ns : iterable of list of int
        The same of every joint of the run (the recording's extent).
    window_s : float
        Analysis window [s].
    stale : tuple of (float, str, bool) or None
        The window analysis's ``stale_reason`` after :func:`stale_after_s`.
    last_observed_t : float or None
        Stream time [s] of the last window with a lost motion.
    samples_without_effort, samples_seen : int
        Samples without an effort, and all samples the window analysis saw.
    effort_topic : str
        Where the effort was expected (a topic name), for the message.

    Returns
    -------
    str or None
        The line, or None when the estimate is current.

    """
    spans_ns = list(spans_ns)
    first, last = (t * 1e-9 for t in span_ns)
    start = min(s[0] for s in spans_ns) * 1e-9
    end = max(s[1] for s in spans_ns) * 1e-9
    if end - last >= max(PARTIAL_SHARE * (end - start), PARTIAL_WINDOWS * window_s):
        # Its entries went missing while the others' went on: renamed, or no longer
        # published (nothing about its reducer after that is in the recording).
        return (f'its samples stop {end - last:.1f} s before the recording ends (after '
                f'{last - start:.1f} s of {end - start:.1f} s): the later messages do not '
                f'carry {joint} with its motor entry (renamed, or no longer published); '
                'the wear and remaining life stand as of its last observed window')
    if stale is not None:
        gap, why, _ = stale
        return (f'no lost motion in the last {100 * gap / (last - first):.0f} % of the '
                f'stream (after {last_observed_t - first:.1f} s of {last - first:.1f} '
                f's): {why}; the wear and remaining life stand as of the last observed '
                'window')
    if samples_without_effort >= PARTIAL_SHARE * max(samples_seen, 1):
        return (f'no effort on {effort_topic} in {samples_without_effort} of '
                f'{samples_seen} samples: their operating time is not counted in the '
                'wear')
    return None


def derived_topics_line(derived):
    """
    Say the derived topics of a joint whose name is no ROS 2 topic name.

    Parameters
    ----------
    derived : str
        Its derived topics (:func:`.joint_twin.joint_topic` of ``'...'``).

    Returns
    -------
    str
        The line (after ``<joint>: ``).

    """
    return (f'its derived topics are {derived} (a '
            "ROS 2 topic name takes letters, digits and '_', and no part of it "
            'starts with a digit)')


def reversed_motor_line(joint):
    """
    Say that a joint's motor encoder counts against the link, and is read reversed.

    Parameters
    ----------
    joint : str
        Joint name.

    Returns
    -------
    str
        The line.

    """
    return (f'the motor encoder of {joint} counts against '
            'the link (a negative reduction): its angles are taken reversed')


def motor_torque_line(topic, peak, lowest, ratio):
    """
    Say that a motor entry's effort beside output motor angles is read as a motor torque.

    Parameters
    ----------
    topic : str
        The JointState topic of the motor entry.
    peak : float
        Largest effort of the motor entry [N*m].
    lowest : float
        Torque [N*m] from which the lost motion is read.
    ratio : float
        The reducer's ratio, which the effort is multiplied by.

    Returns
    -------
    str
        The line (after ``<joint>: ``).

    """
    return (f'the effort of its motor entry on {topic} stays within '
            f'+-{peak:.3g} N*m beside motor angles divided by the ratio, below the '
            f'{lowest:.3g} N*m from which the lost motion is read: it is read as the '
            f"motor's torque, times the ratio {ratio:g} (set twin.motor_effort_units "
            'in --config to joint to read it as the output torque)')


def config_contradicted(bag_path, key, configured, joint, topic, seen, found):
    """
    Return the error of a ``twin.<key>`` in ``--config`` that a joint's data contradict.

    Parameters
    ----------
    bag_path : os.PathLike
        The recording.
    key : str
        ``'motor_angles'`` or ``'motor_direction'``.
    configured, found : object
        The value configured, and the one the data show.
    joint : str
        Joint name.
    topic : str
        The JointState topic of its motor entry.
    seen : str
        What its motor angles do (``'move 81 times the link ...'``).

    Returns
    -------
    str
        One line naming the bag, both values and what the data show.

    """
    return (f'{bag_path}: twin.{key} is {configured!r} in --config, but '
            f'the motor angles of {joint} on {topic} {seen}: {key} {found!r}')


def angles_assumed_raw_line(unknown, min_travel_rad):
    """
    Say the joints whose motor angles could not be told raw from output (taken as raw).

    Parameters
    ----------
    unknown : list of str
        The joints.
    min_travel_rad : float
        Link travel [rad] a chunk must show before its motor angles are classified.

    Returns
    -------
    str
        The line: never a silent guess, it says what was assumed and how to say it.

    """
    return (f'motor angles of {", ".join(unknown)} could not '
            f'be told raw from output (the link moved less than '
            f'{min_travel_rad:g} rad in a chunk): taken as raw; set '
            'twin.motor_angles in --config')


def out_of_order_line(late, messages, topic):
    """
    Say the JointState messages of a topic dropped for coming out of stamp order.

    Parameters
    ----------
    late : int
        Messages dropped.
    messages : int
        Messages of the topic.
    topic : str
        The JointState topic.

    Returns
    -------
    str or None
        The line, or None below 1 % of the messages.

    """
    if not (late and late * 100 >= messages):
        return None
    return (f'{late:,} of {messages:,} '
            f'JointState messages on {topic} were logged after a later stamp (out of '
            'stamp order) and were dropped, as encoder_ingest drops them live')


def malformed_line(count, topic, first):
    """
    Say the malformed JointState messages of a topic that were skipped.

    Parameters
    ----------
    count : int
        Messages skipped (> 0).
    topic : str
        The JointState topic.
    first : str
        The first message's problem.

    Returns
    -------
    str
        The line, as ``Bag.read_joint_states`` reports them.

    """
    return f'{count} malformed JointState message(s) on {topic} skipped; the first: {first}'


def effort_faults_line(count, topic, first):
    """
    Say the JointState messages of a topic whose effort arrays are malformed.

    Parameters
    ----------
    count : int
        Messages (> 0).
    topic : str
        The JointState topic.
    first : str
        The first message's problem.

    Returns
    -------
    str
        The line: their efforts are not read, their positions are.

    """
    return (f'{count} malformed JointState message(s) on {topic}: {first}; '
            'their efforts are not read (which entry a value belongs to cannot be '
            'known), their positions are')


def ingest_status(bad):
    """
    Return the level and message of a joint's encoder ingest status.

    Parameters
    ----------
    bad : int
        Samples dropped or repaired.

    Returns
    -------
    level : str
        ``'OK'`` or ``'WARN'``.
    message : str
        What the status says.

    """
    if bad == 0:
        return 'OK', 'streams clean'
    return 'WARN', f'{bad} samples dropped or repaired'
