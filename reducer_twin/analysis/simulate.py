"""
Simulated robot joints written as a rosbag2 recording (what ``reducer-twin simulate`` does).

The bag holds what ``ros2 bag record -s mcap`` would have recorded from the
``joint_simulator`` node: ``/joint_states`` with ``<joint>`` (link position, velocity,
effort) and ``<joint>_motor`` (motor position; NaN velocity and effort) per tick, or, with
``layout='split'``, the link side on ``/joint_states`` and the motor side on
``/motor_states``; and ``/reducer_twin/<joint>/ground_truth`` (layout ``ground_truth``)
every second of stream and once for the state after the last sample. Generation is
vectorised: the core simulator steps whole blocks
(:class:`~reducer_twin.core.simulator.JointSimulator` with the period-mean mesh table,
``exact_mesh=False``) and the writer builds the messages in its chunk buffers. The
truth's lost motion comes from the same table (within 0.1 arcsec of the exact mesh).

The bag is deterministic: stamps start at :data:`START_NS` and the seed fixes the noise.
Its ``custom_data`` records the aging factor (:data:`AGING_KEY`), which the analysis
applies without being told, and the simulation settings (:data:`SIMULATION_KEY`, JSON).

A life in several bags: ``start_hours`` H continues the same joints (same seed and
settings) from operating hour H, so bags of [0, 2000] h and [2000, 4000] h join exactly
(the truth and the stamps at the start of one equal those at the end of the other, and
the samples equal those of one [0, 4000] h bag). The robot's name and the start hours
are recorded in ``custom_data`` (:data:`ROBOT_KEY`, :data:`START_HOURS_KEY`), where the
fleet store reads them.
"""

from dataclasses import asdict, dataclass, field
import json
import math

import numpy as np
from reducer_twin.core.errors import InvalidParameter, out_of_range
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.units import ARCMIN, HOUR, m_to_um
from reducer_twin.io.bag_writer import BagDirWriter
from reducer_twin.io.mcap_format import MESSAGE_HEADER
from reducer_twin.io.rosbag2_metadata import DEFAULT_QOS, QosProfile
from reducer_twin.msg_adapters.jointstate_cdr import JointStateBatch, MSGTYPE as JOINT_STATE
from reducer_twin.msg_adapters.layouts import GROUND_TRUTH
from reducer_twin.msg_adapters.multiarray_cdr import encode_multiarrays, MSGTYPE as MULTIARRAY

START_NS = 1_767_225_600 * 1_000_000_000
"""Stamp of the first sample: 2026-01-01T00:00:00Z (fixed, so equal seeds give equal bags)."""

AGING_KEY = 'reducer_twin.aging_factor'
"""``custom_data`` key of the aging factor (seconds of wear exposure per stream second)."""

SIMULATION_KEY = 'reducer_twin.simulation'
"""``custom_data`` key of the simulation settings (JSON)."""

ROBOT_KEY = 'reducer_twin.robot'
"""``custom_data`` key of the robot's name (a reducer is a robot's joint)."""

START_HOURS_KEY = 'reducer_twin.start_hours'
"""``custom_data`` key of the operating hours at the bag's first sample."""

MAX_ROBOT_NAME = 64

TRUTH_PERIOD_S = 1.0
"""Stream seconds between ground-truth messages (the simulator node's ``truth_period_s``)."""

BLOCK_SAMPLES = 64 * 2048
"""Samples generated per pass: one pass of the core simulator, no concatenation."""

MAX_MESSAGES = 500_000_000
"""Largest number of ticks one bag may hold."""

MAX_JOINTS = 12

MAX_REPLAY_SAMPLES = 3_000_000_000
"""
Most samples of the joints' life (all joints) passed over to reach ``start_hours``.

A bag continues its seed's life exactly, so the life before its first sample is replayed
(the wear and the noise draws, about 6 M samples a second per joint: this is some 8
minutes). At aging factor 1 an 8 000-h unit at 1 kHz would be 2.9e10 samples, hours of
work without a word: such a request is refused, naming ``start_wear_um`` (a unit met at a
given wear, its life before not simulated).
"""

LATEST_QOS = (QosProfile(durability='transient_local'),)
"""QoS rosbag2 records for the nodes' transient-local topics (estimates, truth)."""


@dataclass(frozen=True)
class SimulationSpec:
    """
    What to simulate.

    Attributes
    ----------
    hours : float
        Operating hours of wear exposure the bag covers [h].
    aging_factor : float
        Seconds of wear exposure per second of stream; the stream lasts
        ``hours·3600/aging_factor`` s.
    joints : int
        Number of joints, named ``joint_1`` ...
    rate_hz : float
        JointState rate [Hz].
    seed : int
        Seed of joint 1; joint k uses ``seed + k - 1`` (as the simulator node).
    wear_rate_scales : tuple of float
        Hidden Archard-rate multiplier per joint.
    profile : str
        ``'robot'`` or ``'paper'`` motion.
    layout : str
        ``'combined'`` (one ``/joint_states``) or ``'split'`` (``/motor_states`` too).
    load_torque_nm : float or None
        Gravity-load amplitude [N·m]; None keeps the simulator's default.
    lost_motion_limit : float
        Accuracy limit on lost motion that ends the life [rad].
    compression : str
        MCAP chunk compression; ``'none'`` is what ``ros2 bag record -s mcap`` writes by
        default (and reads fastest: decompression would double the read cost).
    start_hours : float
        Operating hours of the joints' life at the bag's first sample [h]; the bag
        continues the life of the same seed from there (replayed up to
        :data:`MAX_REPLAY_SAMPLES`).
    start_wear_um : float or tuple of float
        Combined wear at the bag's first sample [µm] (0-100), one for all joints or one per
        joint (kept as a tuple of either; :meth:`start_wear`): a used unit met at that wear,
        its life before not simulated (with ``start_hours`` 0).
    robot : str
        The robot's name ('' for none), recorded in ``custom_data``.

    """

    hours: float = 1000.0
    aging_factor: float = 3600.0
    joints: int = 1
    rate_hz: float = 1000.0
    seed: int = 0
    wear_rate_scales: tuple = field(default=(1.0,))
    profile: str = 'robot'
    layout: str = 'combined'
    load_torque_nm: float = None
    lost_motion_limit: float = 3.0 * ARCMIN
    compression: str = 'none'
    start_hours: float = 0.0
    robot: str = ''
    start_wear_um: object = 0.0

    def __post_init__(self):
        """Check the ranges (the CLI's values arrive here unchanged)."""
        def finite(name, value, unit, lo, hi, lo_open=True):
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and \
                math.isfinite(value) and (lo < value if lo_open else lo <= value) and value <= hi
            if not ok:
                bracket = '(' if lo_open else '['
                raise InvalidParameter(out_of_range(name, value, unit, f'in {bracket}{lo:g}, '
                                                                       f'{hi:g}]'))
        finite('--hours', self.hours, 'h', 0.0, 1e6)
        finite('--aging-factor', self.aging_factor, '', 0.0, 1e9)
        finite('--rate-hz', self.rate_hz, 'Hz', 0.0, 1e5)
        finite('--start-hours', self.start_hours, 'h', 0.0, 1e6, lo_open=False)
        if not isinstance(self.robot, str) or len(self.robot) > MAX_ROBOT_NAME or \
                any(c.isspace() or not c.isprintable() for c in self.robot):
            raise InvalidParameter(out_of_range(
                '--robot', self.robot, '', f'a name of 1 .. {MAX_ROBOT_NAME} printable '
                'characters without spaces'))
        if isinstance(self.joints, bool) or not isinstance(self.joints, int) or \
                not 1 <= self.joints <= MAX_JOINTS:
            raise InvalidParameter(out_of_range('--joints', self.joints, '', f'1 .. {MAX_JOINTS}'))
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or \
                not 0 <= self.seed < 2**63 - MAX_JOINTS:
            raise InvalidParameter(out_of_range('--seed', self.seed, '', 'a whole number >= 0'))
        scales = self._per_joint('--wear-rate-scale', self.wear_rate_scales)
        for s in scales:
            finite('--wear-rate-scale', s, '', 0.0, 100.0)
        object.__setattr__(self, 'wear_rate_scales', tuple(float(s) for s in scales))
        wears = self._per_joint('--start-wear-um', self.start_wear_um)
        for w in wears:
            finite('--start-wear-um', w, 'um', 0.0, 100.0, lo_open=False)
        # Kept as given (one for all, or one per joint), so that a copy for other joints
        # keeps one wear for all.
        given = self.start_wear_um
        given = tuple(given) if isinstance(given, (tuple, list)) else (given,)
        object.__setattr__(self, 'start_wear_um', tuple(float(w) for w in given))
        if any(wears) and self.start_hours:
            raise InvalidParameter(
                f'--start-wear-um {",".join(f"{w:g}" for w in wears)} with --start-hours '
                f'{self.start_hours:g}: expected one of them (a unit met at a given wear, or '
                "the continuation of its seed's life from an hour)")
        if self.load_torque_nm is not None:
            finite('--load-torque-nm', self.load_torque_nm, 'N*m', 0.0, 1e5, lo_open=False)
        if self.layout not in ('combined', 'split'):
            raise InvalidParameter(out_of_range('layout', self.layout, '',
                                                "'combined' or 'split'"))
        n = self.messages
        if n < 1:
            raise InvalidParameter(
                f'--hours {self.hours:g} at --aging-factor {self.aging_factor:g} is '
                f'{self.stream_s:.3g} s of stream, less than one sample at {self.rate_hz:g} Hz; '
                'expected at least one sample')
        if n > MAX_MESSAGES:
            raise InvalidParameter(
                f'--hours {self.hours:g} at --aging-factor {self.aging_factor:g} and --rate-hz '
                f'{self.rate_hz:g} would write {n:,} messages; expected at most '
                f'{MAX_MESSAGES:,} (raise the aging factor or lower the rate)')
        replay = self.first_sample * self.joints
        if replay > MAX_REPLAY_SAMPLES:
            raise InvalidParameter(
                f'--start-hours {self.start_hours:g} at --aging-factor {self.aging_factor:g} and '
                f'--rate-hz {self.rate_hz:g} continues the life of {self.joints} joint(s) from '
                f'its first sample: {replay:.3g} samples to replay; expected at most '
                f'{MAX_REPLAY_SAMPLES:.3g} (some minutes): raise the aging factor, or meet a '
                'used unit at its wear with --start-wear-um (its life before is not simulated)')

    def start_wear(self, k):
        """Return the start wear of joint ``k`` (0-based) [µm]."""
        wears = self.start_wear_um
        return wears[k] if len(wears) > 1 else wears[0]

    def _per_joint(self, flag, values):
        """Return one value per joint of one for all or one each, else refuse."""
        values = tuple(values) if isinstance(values, (tuple, list)) else (values,)
        if len(values) == 1 and self.joints > 1:
            values = values * self.joints
        if len(values) != self.joints:
            raise InvalidParameter(out_of_range(flag, ','.join(map(str, values)), '',
                                                f'one value or {self.joints} values'))
        return values

    @property
    def stream_s(self):
        """Stream seconds of the bag [s]."""
        return self.hours * HOUR / self.aging_factor

    @property
    def first_sample(self):
        """Index of the bag's first tick in the joints' life (0 unless ``start_hours``)."""
        return self._ticks(self.start_hours)

    @property
    def messages(self):
        """Ticks in the bag (JointState messages per topic)."""
        return self._ticks(self.start_hours + self.hours) - self.first_sample

    def _ticks(self, hours):
        return int(math.floor(hours * HOUR / self.aging_factor * self.rate_hz + 1e-9))

    @property
    def names(self):
        """Joint names."""
        return [f'joint_{k + 1}' for k in range(self.joints)]


@dataclass
class SimulationResult:
    """
    What :func:`simulate_bag` wrote.

    Attributes
    ----------
    path : pathlib.Path
        The bag directory.
    messages : int
        JointState messages written (over all JointState topics).
    truth : dict
        Per joint: ``true_wear_um``, ``true_rul_h`` (at the end of the bag, negative
        once the limit has been crossed) and ``wear_rate_scale``.
    stream_s : float
        Stream seconds [s].

    """

    path: object
    messages: int
    truth: dict
    stream_s: float

    def as_json(self):
        """Return the ``--json`` summary: ``{"joints": {...}, "messages": N}``."""
        return {'joints': self.truth, 'messages': self.messages}


def _simulators(spec, params):
    from reducer_twin.core.simulator import JointSimulator, SimConfig
    sims = []
    for k, name in enumerate(spec.names):
        extra = {} if spec.load_torque_nm is None else {'load_torque_nm': spec.load_torque_nm}
        cfg = SimConfig(name=name, profile=spec.profile, exact_mesh=False, rate_hz=spec.rate_hz,
                        aging_factor=spec.aging_factor, wear_rate_scale=spec.wear_rate_scales[k],
                        seed=spec.seed + k, initial_wear_m=spec.start_wear(k) * 1e-6, **extra)
        sims.append(JointSimulator(params, cfg, lost_motion_limit=spec.lost_motion_limit))
    return sims


COMPRESSED_FRACTION = {'none': 1.0, 'zstd': 0.35, 'lz4': 0.45}
"""Size of a compressed bag against a plain one; measured on 1 and 3 simulated joints:
zstd 0.30-0.32, lz4 0.38-0.41 (the fractions here err on the large side)."""

_RECORD_BYTES = MESSAGE_HEADER + 16
"""File bytes of a message beside its payload: record header and Message Index entry."""


def estimated_bytes(spec):
    """
    Estimate the size of the bag :func:`simulate_bag` writes, before writing anything.

    Plain chunks are estimated to within a few per cent (every message of a topic has the
    same length); compressed ones by :data:`COMPRESSED_FRACTION`.

    Parameters
    ----------
    spec : SimulationSpec
        What to simulate.

    Returns
    -------
    int
        Bytes on disk.

    """
    from reducer_twin.msg_adapters.jointstate_cdr import joint_state_columns
    from reducer_twin.msg_adapters.multiarray_cdr import multiarray_template

    def joint_state_bytes(names, fields):
        row = np.zeros((1, len(names)))
        template, _ = joint_state_columns(np.zeros(1, np.int64), names,
                                          *[row if k < fields else None for k in range(3)])
        return _RECORD_BYTES + template.shape[0]

    names = spec.names
    if spec.layout == 'combined':
        per_tick = joint_state_bytes([x for n in names for x in (n, n + '_motor')], 3)
    else:
        per_tick = joint_state_bytes(names, 3) + joint_state_bytes(names, 1)
    truth, _ = multiarray_template(GROUND_TRUTH)
    truths = spec.joints * (spec.stream_s / TRUTH_PERIOD_S + 2)
    plain = spec.messages * per_tick + truths * (_RECORD_BYTES + truth.shape[0]) + 65536
    return int(plain * COMPRESSED_FRACTION.get(spec.compression, 1.0))


def _custom_data(spec):
    settings = asdict(spec)
    settings['wear_rate_scales'] = list(spec.wear_rate_scales)
    settings['joint_names'] = spec.names
    out = {AGING_KEY: repr(float(spec.aging_factor)),
           SIMULATION_KEY: json.dumps(settings, sort_keys=True),
           START_HOURS_KEY: repr(float(spec.start_hours))}
    if spec.robot:
        out[ROBOT_KEY] = spec.robot
    return out


def _truth_rows(sims, batches, first, n, spec, tables):
    """Ground-truth records at the whole truth periods inside samples ``[first, first + n)``."""
    period = max(1, int(round(TRUTH_PERIOD_S * spec.rate_hz)))
    idx = np.arange(-(-max(first, 1) // period) * period, first + n, period)
    out = []
    for sim, batch in zip(sims, batches):
        wear = batch.true_wear[idx - first]
        t = idx / spec.rate_hz
        rows = np.column_stack([
            START_NS * 1e-9 + t, wear, tables.lost_motion(wear), t * spec.aging_factor,
            np.full(idx.size, sim.config.wear_rate_scale), np.full(idx.size, spec.aging_factor),
            np.full(idx.size, sim.limit_time_s), sim.limit_time_s - t * spec.aging_factor])
        out.append(rows)
    return idx, out


def _final_truth(sims, spec, tables):
    rows = []
    for sim in sims:
        tr = sim.truth()
        rows.append(np.array([[START_NS * 1e-9 + tr.time_s, tr.wear,
                               float(tables.lost_motion(tr.wear)), tr.exposure_s,
                               tr.wear_rate_scale, spec.aging_factor, tr.limit_time_s,
                               sim.true_rul_s()]]))
    return rows


def simulate_bag(out_dir, spec, params=None, overwrite=False):
    """
    Simulate joints and write them as a rosbag2 bag directory.

    Parameters
    ----------
    out_dir : str or os.PathLike
        Bag directory to create (must be empty or missing unless ``overwrite``).
    spec : SimulationSpec
        What to simulate.
    params : ReducerParams, optional
        Reducer parameters of every joint.
    overwrite : bool
        Replace a bag written by reducer-twin in ``out_dir``.

    Returns
    -------
    SimulationResult
        Path, message count and the truth at the end.

    Raises
    ------
    InvalidParameter
        If ``out_dir`` is not empty without ``overwrite``, or holds other files.
    BagError
        If ``out_dir`` cannot be written (``DiskFull`` when the disk fills up; nothing
        is left there then).

    """
    from reducer_twin.core.transmission_error import model_tables
    params = params or ReducerParams()
    tables = model_tables(params)
    sims = _simulators(spec, params)
    names = spec.names
    # Sample indices of the joints' life: [first, n_total).
    first = spec.first_sample
    n_total = first + spec.messages
    for sim in sims:
        sim.advance(first)
    written = 0
    # The project's array framing: about a million messages per bag (see mcap_writer).
    with BagDirWriter(out_dir, compression=spec.compression, custom_data=_custom_data(spec),
                      overwrite=overwrite, framing='fast', needed=estimated_bytes(spec),
                      what='simulated bag') as writer:
        link_ch = writer.add_topic('/joint_states', JOINT_STATE, DEFAULT_QOS)
        motor_ch = writer.add_topic('/motor_states', JOINT_STATE, DEFAULT_QOS) \
            if spec.layout == 'split' else None
        truth_ch = [writer.add_topic(joint_topic(name, 'ground_truth'), MULTIARRAY, LATEST_QOS)
                    for name in names]
        while first < n_total:
            n = min(BLOCK_SAMPLES, n_total - first)
            batches = [sim.step(n) for sim in sims]
            stamps = START_NS + np.round(batches[0].t * 1e9).astype(np.int64)
            written += _write_joint_states(writer, link_ch, motor_ch, names, batches, stamps)
            idx, rows = _truth_rows(sims, batches, first, n, spec, tables)
            if idx.size:
                logs = START_NS + np.round(idx / spec.rate_hz * 1e9).astype(np.int64)
                for ch, values in zip(truth_ch, rows):
                    writer.write_batch(ch, logs, *encode_multiarrays(GROUND_TRUTH, values))
            first += n
        # The state after the last sample (what the summary reports) closes the bag.
        end_ns = np.array([START_NS + int(round(n_total / spec.rate_hz * 1e9))], np.int64)
        for ch, values in zip(truth_ch, _final_truth(sims, spec, tables)):
            writer.write_batch(ch, end_ns, *encode_multiarrays(GROUND_TRUTH, values))
    truth = {}
    for sim in sims:
        tr = sim.truth()
        truth[sim.config.name] = {'true_wear_um': m_to_um(tr.wear),
                                  'true_rul_h': sim.true_rul_s() / HOUR,
                                  'wear_rate_scale': tr.wear_rate_scale}
    return SimulationResult(writer.out_dir, written, truth, spec.messages / spec.rate_hz)


def _write_joint_states(writer, link_ch, motor_ch, names, batches, stamps):
    """Write one block as the simulator node publishes it; return the messages written."""
    from reducer_twin.core.simulator import joint_state_columns, joint_state_names
    n = stamps.size
    split = motor_ch is not None
    pos, vel, eff, motor = joint_state_columns(batches, split)
    writer.write_joint_states(link_ch, JointStateBatch(stamps, joint_state_names(names, split),
                                                       pos, vel, eff))
    if not split:
        return n
    empty = np.full_like(motor, np.nan)
    writer.write_joint_states(motor_ch, JointStateBatch(stamps, tuple(names), motor, empty,
                                                        empty))
    return 2 * n
