"""Each node's ``/diagnostics``: the period parameter, the publisher and the report timer."""

import math
import time

from diagnostic_msgs.msg import DiagnosticArray
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.observability import derived_link_reason, link_from_motor
from reducer_twin.core.service_time import service_note
from reducer_twin.core.tick_pairing import PAIRING_FACTS
from reducer_twin.core.units import HOUR, m_to_um, rad_to_arcmin
from reducer_twin.msg_adapters.ros import diagnostic_array, diagnostic_status
from reducer_twin.nodes.parameters import SpecParameters
from reducer_twin.nodes.qos import diagnostics_qos
from reducer_twin.nodes.settings import DiagnosticsSettings
from reducer_twin.nodes.timers import create_background_timer


def publish_diagnostics(node, statuses):
    """
    Declare ``diagnostics_period_s`` and publish ``statuses()`` on ``/diagnostics`` every period.

    The report is built and published on the background worker
    (:func:`~reducer_twin.nodes.timers.create_background_timer`).

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    statuses : callable
        Returns a list of ``(name, hardware_id, level, message, values)``.

    Returns
    -------
    callable
        Publishes one report now (tests, the end of a demo).

    Raises
    ------
    InvalidParameter
        If the period is not in (0, 3600] s.

    """
    period = SpecParameters(node, '', DiagnosticsSettings()).value.diagnostics_period_s
    publisher = node.create_publisher(DiagnosticArray, '/diagnostics', diagnostics_qos())

    def report():
        publisher.publish(diagnostic_array(node.get_clock().now().nanoseconds,
                                           [diagnostic_status(*s) for s in statuses()]))

    report.__name__ = f'{node.get_name()} diagnostics'
    create_background_timer(node, period, report)
    return report


def estimator_status(stage, rejected, live=None):
    """
    Return the ``wear_estimator``'s status: level, message and key/values.

    Parameters
    ----------
    stage : EstimatorStage
        The estimator stage (its state writer's failures count).
    rejected : int
        Messages the node dropped (WARN).
    live : LiveHistory, optional
        The fleet store's live history, whose trouble raises the level.

    Returns
    -------
    tuple
        ``(level, message, values)``: ``STALE`` while no lost motion has been used
        (the wear is then the prior's, moved by the model's rate alone).

    """
    est = stage.estimator
    writer = stage.store.writer if stage.store is not None else None
    values = {'wear_um': m_to_um(est.wear), 'wear_std_um': m_to_um(est.wear_std),
              'rate_scale': est.rate_scale, 'updates': est.updates,
              'rejected_updates': est.rejected, 'replayed_windows': stage.skipped_replays,
              # How the windows scatter against their reported sd (the ratio of variances
              # the observation noise is scaled by): well above 1, a noisy effort.
              'window_noise_scale': est.noise_scale,
              # How far both growth models' predictions eight windows ahead fell short of
              # the sd they claimed (1: as claimed); it widens the remaining life's rate.
              'forecast_scale': est.forecast_scale,
              'rejected_messages': rejected,
              'state_writes_failed': writer.failures if writer else 0,
              'state_writes_recovered': writer.recoveries if writer else 0,
              'state_file': str(stage.state_path or 'none'),
              'restored_from': stage.restored_from or 'new reducer'}
    # The lost motion is given less a soft zone (negative: more, loads within one).
    if stage.soft_zone_shortfall != 0.0:
        values['soft_zone_shortfall_arcmin'] = rad_to_arcmin(stage.soft_zone_shortfall)
    level = 'OK' if rejected == 0 else 'WARN'
    error = writer.error if writer is not None else None
    if error is not None:   # the file on disk is the last good state
        level = 'ERROR'
        values['state_write_error'] = str(error)
    message = f'wear {values["wear_um"]:.2f} +/- {values["wear_std_um"]:.2f} um'
    if est.updates == 0:
        # The prior's wear, moved by the model's rate alone: no finding, never 'OK'.
        message = f'not observed: no lost motion used yet; {message} from the prior alone'
        level = 'STALE' if level == 'OK' else level
    if est.config.service_time_s > 0.0:
        # The service time the node was given, and what became of it.
        verdict = est.service_verdict
        values['service_time_h'] = est.config.service_time_s / HOUR
        values['service_time'] = ('waiting for the duty' if verdict is None else
                                  'taken' if verdict[0] else 'not taken')
        if verdict is not None:
            values['service_rate_scale'] = verdict[1]
        if verdict is not None and not verdict[0]:
            level = 'WARN' if level == 'OK' else level
            message += '; ' + service_note(verdict, est.config.service_time_s)
    if error is not None:
        message = f'{error}; {message}'
    if live is not None:
        store_level, store_values = live.status()
        values.update(store_values)
        if store_level == 'ERROR' or (store_level == 'WARN' and level in ('OK', 'STALE')):
            level = store_level
        if store_level != 'OK':
            message += '; fleet store: ' + (store_values.get('store_error')
                                            or store_values['store_busy'])
    return level, message, values


def ingest_statuses(counts, rejects, unheard=None, unstamped=()):
    """
    Return the ``encoder_ingest`` statuses, one per joint, from its rule counts.

    Parameters
    ----------
    counts : dict
        Per joint, the count of every ingestion rule and ``published``.
    rejects : RejectCounter
        Malformed messages dropped (:class:`.rejects.RejectCounter`).
    unheard : UnheardPublishers, optional
        Publishers the subscriptions cannot hear, for their QoS or type
        (:class:`.qos.UnheardPublishers`).
    unstamped : sequence of str
        Topics whose publisher does not stamp its messages (their arrival times are
        taken instead): WARN, and ``unstamped_topics`` names them.

    Returns
    -------
    list of tuple
        ``(name, hardware_id, level, message, values)`` per joint: WARN once a sample
        was dropped or repaired (unwrapping and steps are no fault) or a message dropped
        (the latest one's fault said: a message that lacks the joint's entries never
        counts as a sample); ERROR while a publisher of the joint states is not heard
        for its QoS or its type.

    """
    not_heard = [unheard.reason(t) for t in unheard.topics] if unheard is not None else []
    statuses = []
    for joint, c in counts.items():
        bad = sum(v for k, v in c.items()
                  if k not in ('published', 'step', *PAIRING_FACTS) and not k.endswith('_wrap'))
        c['rejected_messages'] = rejects.total
        level, message = ('OK', 'streams clean') if bad == 0 else \
            ('WARN', f'{bad} samples dropped or repaired')
        if rejects.total:
            said = f'{rejects.total} messages dropped, the latest: {rejects.last}'
            level, message = 'WARN', said if bad == 0 else f'{message}; {said}'
        if unstamped:
            said = f'header stamps zero on {", ".join(unstamped)}: arrival times taken'
            level, message = 'WARN', said if level == 'OK' else f'{message}; {said}'
            c['unstamped_topics'] = ', '.join(unstamped)
        if not_heard:
            level, message = 'ERROR', '; '.join([*not_heard, message])
            c['unheard_topics'] = ', '.join(unheard.topics)
        statuses.append((f'reducer_twin: {joint} encoder ingest', joint, level, message, c))
    return statuses


def say_faults(logger, joint, twin, said):
    """
    Log a joint's input faults on stderr, each kind once (``/diagnostics`` carry them on).

    An effort that is not the output torque, or a link angle computed from the motor's
    (:func:`.observability.link_from_motor`), is an error (the joint is not observed); the
    inputs read otherwise than published (:meth:`.joint_twin.TwinFront.input_warnings`: a
    velocity field that is not the link angle's rate, an effort or an encoder reading held
    between slower updates, an effort whose noise is correlated over samples, an encoder
    that reports the angle coarsely, a motor that turns another number of times than the
    configured ratio) are warnings.

    Parameters
    ----------
    logger : rclpy.impl.rcutils_logger.RcutilsLogger
        The node's logger.
    joint : str
        The joint's name, for the line.
    twin : TwinFront
        The joint's TE extraction and window analysis.
    said : set
        Kinds already said; updated.

    """
    analyzer = twin.analyzer
    derived = derived_link_reason(analyzer)
    if derived is not None:
        # No TE to read: the effort's checks, which read it, say nothing then.
        faults = {'link': ('error', f'not observed: {derived}')}
    else:
        fault = analyzer.effort_fault
        faults = {'effort': ('error', fault and f'not observed: {fault}')}
    faults.update((kind, ('warning', line)) for kind, line in twin.input_warnings().items())
    for kind, (level, line) in faults.items():
        if line and kind not in said:
            said.add(kind)
            # One call site per severity: rclpy refuses a call site's second severity.
            if level == 'error':
                logger.error(f'{joint}: {line}')
            else:
                logger.warning(f'{joint}: {line}')


def te_monitor_statuses(monitor, stale_after_s):
    """
    Return a ``te_monitor``'s ``/diagnostics`` statuses (one: its joint's TE).

    Its counts, latency, last window and state file (a write that failed is ``ERROR``:
    the file on disk is the last good state), at the level :func:`te_status` gives.

    Parameters
    ----------
    monitor : TEMonitor
        The node.
    stale_after_s : float
        Stream time [s] without a lost motion after which it is said.

    """
    f = monitor.last_features
    values = {'samples': monitor.samples, 'windows': monitor.windows,
              'rejected_messages': monitor.rejects.total,
              'latency_p99_ms': monitor.latency.stats_since_report()['p99'] * 1e3}
    if f is not None:
        values.update({'te_pp_arcmin': rad_to_arcmin(f.te_pp),
                       'lost_motion_arcmin': rad_to_arcmin(f.lost_motion)})
    last = monitor.last_pairs_at
    quiet = None if last is None else time.monotonic() - last
    error = monitor.state.values(values)
    level, message = te_status(
        monitor.twin, joint_topic(monitor.joint, 'encoder_pairs'),
        'OK' if monitor.rejects.total == 0 else 'WARN', f'{monitor.windows} windows analysed',
        values, stale_after_s, quiet, monitor.silent_after_s)
    if error is not None:
        level, message = 'ERROR', f'{error}; {message}'
    return [(f'reducer_twin: {monitor.joint} transmission error', monitor.joint, level, message,
             values)]


def te_status(twin, topic, level, message, values, stale_after_s, quiet_s, silent_after_s):
    """
    Return ``te_monitor``'s level and message from its window analysis; fill ``values``.

    Never OK without a lost motion (``STALE`` with the reason; ``ERROR`` for an effort
    or encoders in other units, a configuration to fix, or a link angle computed from the
    motor's, an encoder missing); seen before but not for
    ``stale_after_s`` of stream, the message says since when and why (``WARN`` for a
    faulty stream); no encoder pairs for ``silent_after_s`` [s of wall time] is a
    stopped stream (``WARN``): the analysis stands where it was.

    Parameters
    ----------
    twin : TwinFront
        The joint's TE extraction and window analysis: its reason not to observe
        (:meth:`.joint_twin.TwinFront.refusal`), else the inputs it reads otherwise than
        published (:meth:`.joint_twin.TwinFront.input_warnings`), each turning OK to WARN.
    topic : str
        Where its samples come from, for the messages.
    level, message : str
        The level and message when all is well.
    values : dict
        Key/values of the status, completed here.
    stale_after_s : float
        Stream time [s] without a lost motion after which it is said.
    quiet_s : float or None
        Wall time [s] since the latest encoder pairs (None: none yet).
    silent_after_s : float
        Wall time [s] without pairs from which the stream is said to have stopped.

    Returns
    -------
    tuple of str
        Level and message.

    """
    analyzer = twin.analyzer
    reason = twin.refusal(analyzer.not_observed_reason(topic))
    values['observed_windows'] = analyzer.windows_observed
    values['seconds_in_gaps'] = analyzer.gap_time_s
    if math.isfinite(analyzer.velocity_scale):
        values['velocity_scale'] = analyzer.velocity_scale
    soft = twin.soft_zone
    if soft is not None:     # the soft zone's line as numbers (analyze --json's soft_zone)
        values['lost_motion_at_test_torque_arcmin'] = rad_to_arcmin(soft['width'])
        values['soft_zone_play_arcmin'] = rad_to_arcmin(soft['play'])
    if analyzer.test_torque_check is not None:    # analyze --json's test_torque_check
        values['test_torque_check'] = analyzer.test_torque_check
    stale = analyzer.stale_reason(stale_after_s, topic)
    if reason is not None:
        fixed = analyzer.effort_fault is not None or link_from_motor(analyzer)
        level = 'ERROR' if fixed else 'STALE'
        message = f'not observed: {reason}'
    elif stale is not None:
        gap, why, faulty = stale
        values['seconds_since_lost_motion'] = gap
        message = f'{message}; no lost motion for {gap:.0f} s: {why}'
        level = 'WARN' if faulty else level
    for said in twin.input_warnings().values() if reason is None else ():
        message = f'{message}; {said}'
        level = 'WARN' if level == 'OK' else level
    if quiet_s is not None:
        values['seconds_since_pairs'] = quiet_s
        if quiet_s >= silent_after_s and level in ('OK', 'WARN'):
            level = 'WARN'
            message = (f'{message}; no encoder pairs for {quiet_s:.0f} s (the controller '
                       'stopped publishing this joint, or renamed it)')
    return level, message
