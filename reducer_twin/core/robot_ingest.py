"""
The ingest stage of one robot's joints, as ``encoder_ingest`` runs it live.

Controller messages (stamp, positions, velocities, efforts of the picked entries)
are buffered as they come and processed in batches: every column goes through the
ingestion rules (:class:`~reducer_twin.core.ingest.StreamCleaner`), the motor and
link sides of each joint are paired and despiked, and each joint's clean rows come
out in the ``encoder_pairs`` layout (stamp [s], motor and link angle [rad], effort
[N*m], link velocity [rad/s]), ready for that joint's
:class:`~reducer_twin.core.joint_twin.TwinFront`.

Two forms: *combined* (one message with ``<joint>`` and ``<joint><motor_suffix>``,
columns ``link_1, motor_1, link_2, ...``; every joint is paired and despiked at
once) and *split* (link and motor on two topics, each joint paired by a
:class:`~reducer_twin.core.pairing.Pairer`).
"""

import numpy as np

from .effort_source import choose_effort, motor_effort_scale
from .errors import InvalidParameter
from .ingest import IngestConfig, stream_cleaners
from .pairing import Pairer
from .spikes import SpikeFilter, SpikeFilterBank
from .tick_pairing import SHARED_STAMPS


STREAMS = {
    'joints': (['joint_1'], 'joint names to ingest'),
    'link_topic': ('/joint_states', 'JointState topic with the link-side positions'),
    'motor_topic': ('', 'JointState topic with the motor side; empty: motor entries are in '
                        'link_topic as <joint><motor_suffix>'),
    'motor_suffix': ('_motor', 'suffix of motor-side entries in a combined message'),
    'motor_angles': ('raw', "'raw' (input side) or 'output' (divided by the ratio)"),
    'motor_direction': (1, '1: the motor encoder counts with the link; -1: against it (a '
                           'negative reduction)'),
    'effort_scale': (1.0, 'output torque [N*m] per unit of the effort read (after '
                          'motor_effort_units): -1 for a drive that reports its effort with '
                          'the other sign; for a motor current in A, the torque constant '
                          'times the ratio'),
    'effort_source': ('auto', "torque from the 'link' entry, the 'motor' entry, or 'auto' "
                              '(link where it has one, else motor)'),
    'motor_effort_units': ('auto', "motor entry's effort: 'motor' torque (times the ratio), "
                                   "'joint' units, or 'auto' (motor torque when motor_angles "
                                   'is raw)'),
}
"""
Where a robot's encoder streams are and how to read them: name -> (default, description).

The one source of these defaults: ``encoder_ingest``'s parameters and the ``twin``
section of ``config/twin.yaml`` are derived from it.
"""


class RobotIngest:
    """
    Clean, pair and despike the encoder streams of a robot's joints.

    Parameters
    ----------
    joints : sequence of str
        Joint names (column order).
    ratio : float
        Total reduction ratio.
    config : IngestConfig, optional
        Ingestion thresholds.
    split : bool
        Link and motor sides come in separate messages.
    motor_angles : str
        ``'raw'`` (input side) or ``'output'`` (already divided by the ratio).
    effort_source : str
        ``'link'``, ``'motor'`` or ``'auto'``.
    motor_effort_units : str
        ``'motor'``, ``'joint'`` or ``'auto'`` (see :func:`motor_effort_scale`).
    motor_direction : int
        1, or -1 for a motor encoder that counts against the link (its angles and its
        torque are taken reversed).
    effort_scale : float
        Output torque per unit of the effort read (:func:`check_effort_scale`).

    """

    def __init__(self, joints, ratio, config=None, split=False, motor_angles='raw',
                 effort_source='auto', motor_effort_units='auto', motor_direction=1,
                 effort_scale=1.0):
        config = config or IngestConfig()
        check_motor_direction(motor_direction)
        self.torque_scale = check_effort_scale(effort_scale)
        self.joints = list(joints)
        self.split = bool(split)
        self.scale = motor_direction * (ratio if motor_angles == 'output' else 1.0)
        self.effort_source = effort_source
        self.effort_scale = motor_direction * motor_effort_scale(motor_effort_units,
                                                                 motor_angles, ratio)
        self.link, self.motor = stream_cleaners(config, self.split)
        self.spikes = SpikeFilterBank(ratio, len(self.joints), config)
        self.pairers = [Pairer(config, self.scale, effort=effort_source,
                               motor_effort_scale=self.effort_scale, ratio=ratio,
                               effort_scale=self.torque_scale)
                        for _ in self.joints]
        self.joint_spikes = [SpikeFilter(ratio, config) for _ in self.joints]

    def process(self, link, motor=()):
        """
        Clean buffered messages of both sides, pair and despike them.

        Parameters
        ----------
        link, motor : list of tuple
            Buffered ``(t_ns, position, velocity, effort)`` of the link topic (combined:
            every column) and of the motor topic (split only).

        Returns
        -------
        list of (int, ndarray)
            ``(joint index, rows)`` of every joint with clean rows, in the
            ``encoder_pairs`` layout. The rows must not be modified later by a consumer.

        """
        clean_link = _clean(self.link, link)
        out = []
        if self.split:
            clean_motor = _clean(self.motor, motor)
            for k, pairer in enumerate(self.pairers):
                if clean_link is not None:
                    pairer.add_link(clean_link.column(k))
                if clean_motor is not None:
                    pairer.add_motor(clean_motor.column(k))
                pairs = pairer.pop()
                if len(pairs):
                    rows = pairs.as_rows()
                    rows = rows[self.joint_spikes[k].keep(rows[:, 1], rows[:, 2])]
                    if rows.shape[0]:
                        out.append((k, rows))
        elif clean_link is not None and len(clean_link):
            out = self._pair_all(clean_link)
        return out

    def _pair_all(self, clean):
        """Pair, despike and cut per joint every joint of a combined-form batch at once."""
        position = clean.position
        finite = np.isfinite(position)
        link = position[:, 0::2]
        motor = position[:, 1::2] * self.scale
        if finite.all():
            paired, unpaired = np.ones(link.shape, dtype=bool), None
        else:
            link_ok, motor_ok = finite[:, 0::2], finite[:, 1::2]
            paired = link_ok & motor_ok
            unpaired = np.count_nonzero(link_ok ^ motor_ok, axis=0)
        keep = self.spikes.keep(motor, link, paired)
        n, j = link.shape
        # Joint-major, so that each joint's rows are one contiguous block.
        rows = np.empty((j, n, 5))
        rows[:, :, 0] = clean.t_ns * 1e-9
        rows[:, :, 1] = motor.T
        rows[:, :, 2] = link.T
        rows[:, :, 3] = choose_effort(clean.effort[:, 0::2], clean.effort[:, 1::2],
                                      self.effort_source, self.effort_scale,
                                      self.torque_scale).T
        rows[:, :, 4] = clean.velocity[:, 0::2].T
        all_kept = keep is paired and unpaired is None
        out = []
        for k, pairer in enumerate(self.pairers):
            if unpaired is not None:
                pairer.unpaired += int(unpaired[k])
            joint_rows = rows[k] if all_kept else rows[k][keep[:, k]]
            if joint_rows.shape[0]:
                out.append((k, joint_rows))
        return out

    def counts(self, k):
        """Return the count of every ingestion rule for joint ``k`` (for diagnostics)."""
        c = {}
        sides = ((('link', self.link, [k]), ('motor', self.motor, [k])) if self.split
                 else (('stream', self.link, [2 * k, 2 * k + 1]),))
        for side, cleaner, columns in sides:
            for reason, count in cleaner.counts_for(columns).items():
                c[f'{side}_{reason}'] = count
            c[f'{side}_missing'] = cleaner.missing
            c[f'{side}_retimed'] = cleaner.clock.retimed
        c['unpaired'] = self.pairers[k].unpaired
        c.update(self.pairers[k].ticks.facts() if self.split else
                 {'pairing': SHARED_STAMPS, 'tick_paired': 0})
        c.update(self.joint_spikes[k].counts if self.split else self.spikes.counts(k))
        return c


def _clean(cleaner, rows):
    """Run buffered ``(t, pos, vel, eff)`` rows through a cleaner; None if there are none."""
    if not rows:
        return None
    if len(rows) == 1:      # the live case: one controller message at a time
        t, pos, vel, eff = rows[0]
        return cleaner.process(np.array([t], dtype=np.int64), pos[None, :], vel[None, :],
                               eff[None, :])
    t = np.fromiter((r[0] for r in rows), dtype=np.int64, count=len(rows))
    pos = np.stack([r[1] for r in rows])
    vel = np.stack([r[2] for r in rows])
    eff = np.stack([r[3] for r in rows])
    return cleaner.process(t, pos, vel, eff)


def check_motor_direction(value, prefix=''):
    """
    Check a motor direction: 1 or -1.

    Raises
    ------
    InvalidParameter
        Naming the value and the allowed ones.

    """
    if isinstance(value, bool) or value not in (1, -1):
        raise InvalidParameter(f'{prefix}motor_direction must be 1 (the motor encoder counts '
                               f'with the link) or -1 (against it), got {value!r}')


def check_effort_scale(value, prefix=''):
    """
    Check an effort scale: a finite number, not 0, of magnitude 1e-6 to 1e6.

    Returns
    -------
    float
        The scale.

    Raises
    ------
    InvalidParameter
        Naming the value and the allowed ones.

    """
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and \
        np.isfinite(value) and 1e-6 <= abs(value) <= 1e6
    if not ok:
        raise InvalidParameter(f'{prefix}effort_scale must be a number of magnitude 1e-6 to '
                               '1e6 (output torque [N*m] per unit of the effort; negative '
                               f'for an effort of the other sign), got {value!r}')
    return float(value)


def check_streams(joints, link_topic, motor_topic, motor_suffix, prefix=''):
    """
    Check that the motor side of every joint can be told from its link side.

    Parameters
    ----------
    joints : sequence of str
        Joint names.
    link_topic, motor_topic : str
        JointState topics (``motor_topic`` empty: motor entries are in the link topic).
    motor_suffix : str
        Suffix of the motor entries in a combined message.
    prefix : str
        Prefix of the names in messages (``'twin.'`` in the bringup YAML).

    Raises
    ------
    InvalidParameter
        On empty joint names, a motor topic equal to the link topic, or an empty
        suffix with the motor entries in the link topic.

    """
    if not joints or any(not j for j in joints):
        raise InvalidParameter(f'{prefix}joints must be non-empty names, got {joints!r}')
    if motor_topic and motor_topic == link_topic:
        raise InvalidParameter(f'{prefix}motor_topic must differ from {prefix}link_topic '
                               f"({link_topic!r}); leave it '' when the motor entries are in "
                               f'{prefix}link_topic')
    if not motor_topic and not motor_suffix:
        raise InvalidParameter(f'{prefix}motor_suffix must not be empty when the motor '
                               f'entries are in {prefix}link_topic ({link_topic!r}): <joint> '
                               "and <joint><motor_suffix> would be the same entry; e.g. '_motor'")
