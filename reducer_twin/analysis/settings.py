"""
What ``reducer-twin analyze`` is told: :class:`AnalysisSettings`, and ``--config`` read into them.

The bringup YAML (``config/twin.yaml``) and the command line give the streams, the
controller forms, the aging factor and window settings (derived from
:class:`~reducer_twin.core.joint_twin.TwinConfig`), the reducers per joint and the life
settings; :mod:`.pipeline` runs a bag with them.
"""

from dataclasses import dataclass, field
import math

from reducer_twin.config import joint_reducers, load_config_sources, twin_config
from reducer_twin.core.effort_source import EFFORT_SOURCES, MOTOR_EFFORT_UNITS
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.estimator import EstimatorConfig
from reducer_twin.core.ingest import IngestConfig
from reducer_twin.core.joint_twin import TwinConfig
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.pipeline import LifeConfig
from reducer_twin.core.robot_ingest import check_effort_scale
from reducer_twin.msg_adapters.dynamic_joint_state import InterfaceMap


@dataclass(frozen=True)
class AnalysisSettings:
    """
    How to analyse a bag (the bringup configuration's meaning, offline).

    Attributes
    ----------
    joints : tuple of str or None
        Joints to analyse; None: every ``<joint>``/``<joint><motor_suffix>`` pair found.
    link_topic, motor_topic : str
        JointState topics (``motor_topic`` empty: motor entries are in the link topic).
    motor_suffix : str
        Suffix of motor entries in a combined message.
    motor_angles : str
        ``'raw'``, ``'output'`` (already divided by the ratio) or ``'auto'``: found
        from the data (motor travel against link travel); a configured value the
        data contradict is an error naming both.
    motor_direction : int or str
        1 (the motor encoder counts with the link), -1 (against it) or ``'auto'``:
        found per joint from the data (its steps against the link's); a configured
        value the data contradict is an error naming both.
    effort_source : str
        Where the torque is read: ``'link'``, ``'motor'`` or ``'auto'`` (the link
        entry where it has an effort, else the motor entry).
    motor_effort_units : str
        The motor entry's effort: ``'motor'`` (motor torque, times the ratio),
        ``'joint'`` (already output torque) or ``'auto'`` (motor torque when the
        motor angles are raw, or beside output angles when its size says so:
        :func:`.effort_source.motor_torque_seen`).
    effort_scale : float
        Output torque [N·m] per unit of the effort so read (-1: an effort of the other
        sign; a torque constant times the ratio for a motor current in A).
    interfaces : InterfaceMap
        DynamicJointState interfaces of the joint (``position``, ...) and the motor
        (``motor_position``, ...) entries.
    aging_factor : float or None
        Seconds of wear exposure per stream second; None: the bag's own
        (``custom_data`` :data:`~reducer_twin.analysis.simulate.AGING_KEY`), else 1.
    window_s : float
        Analysis window [s of stream].
    max_gap_s : float
        Largest stamp gap TE extraction bridges inside a window [s].
    friction_in_effort : int
        1: the effort is the drive's torque, whose friction and efficiency are fitted
        and taken out; 0: a torque sensor at the reducer's output (``twin.friction_in_effort``).
    effort_lag_s : float
        How late the effort is published against the encoders [s]: the time constant of
        the drive's torque filter (``twin.effort_lag_s``; 0: unfiltered).
    params : ReducerParams
        Reducer parameters of every joint without its own.
    joint_params : tuple of (str, ReducerParams)
        Reducer parameters of the joints that carry another reducer (an RV-160E at the
        base, an RV-40E at the wrist); see :meth:`params_of`.
    service_times : tuple of (str, float)
        Operating time [s] of a joint's reducer before the recording, where known
        (``service_time_s`` of the configuration: a robot's hour meter); see
        :meth:`estimator_of`.
    life : LifeConfig
        Limit and thresholds of the remaining-life stage.
    ingest : IngestConfig
        Ingestion thresholds.
    compression : str
        MCAP chunk compression of the derived bag (``'none'``: as ``ros2 bag record``
        writes by default, and the cheapest to write).
    configured_topics : tuple of (str, str)
        ``(key, topic)`` of the topics the configuration names explicitly; each must be
        in the bag.

    """

    joints: tuple = None
    link_topic: str = '/joint_states'
    motor_topic: str = ''
    motor_suffix: str = '_motor'
    motor_angles: str = 'auto'
    motor_direction: object = 'auto'
    effort_source: str = 'auto'
    motor_effort_units: str = 'auto'
    effort_scale: float = 1.0
    interfaces: InterfaceMap = field(default_factory=InterfaceMap)
    aging_factor: float = None
    window_s: float = TwinConfig().window_s
    max_gap_s: float = TwinConfig().max_gap_s
    friction_in_effort: int = TwinConfig().friction_in_effort
    effort_lag_s: float = TwinConfig().effort_lag_s
    params: ReducerParams = field(default_factory=ReducerParams)
    joint_params: tuple = ()
    service_times: tuple = ()
    life: LifeConfig = field(default_factory=LifeConfig)
    ingest: IngestConfig = field(default_factory=IngestConfig)
    compression: str = 'none'
    configured_topics: tuple = ()

    def params_of(self, joint):
        """Return the reducer parameters of ``joint`` (its own, else :attr:`params`)."""
        for name, params in self.joint_params:
            if name == joint:
                return params
        return self.params

    def estimator_of(self, joint):
        """
        Return the estimator tuning of ``joint``'s reducer met without state.

        Its service time where :attr:`service_times` has one, else the defaults (None).
        """
        for name, seconds in self.service_times:
            if name == joint:
                return EstimatorConfig(service_time_s=seconds)
        return None

    @classmethod
    def from_config(cls, path):
        """
        Read a bringup YAML (``config/twin.yaml``) as analysis settings.

        Joints and the aging factor count only when the file sets them; otherwise the
        joints are found in the bag and the bag's aging factor applies.

        Parameters
        ----------
        path : str or Path or None
            The file; None gives the defaults.

        Returns
        -------
        AnalysisSettings
            The settings.

        Raises
        ------
        InvalidParameter
            If the file is unreadable or holds invalid values.

        """
        config, given = load_config_sources(path)
        twin = config['twin']
        for key, allowed in (('motor_angles', MOTOR_ANGLES), ('effort_source', EFFORT_SOURCES),
                             ('motor_effort_units', MOTOR_EFFORT_UNITS)):
            if twin[key] not in allowed:
                raise InvalidParameter(f'{path}: twin.{key} must be one of '
                                       f'{", ".join(repr(a) for a in allowed)}, got {twin[key]!r}')
        aging = None
        if 'twin.aging_factor' in given:
            aging = _number(path, 'twin.aging_factor', twin['aging_factor'], 0.0, 1e9)
            if aging == 0.0:    # every window would count no operating time
                raise InvalidParameter(f'{path}: twin.aging_factor must be a number in (0, '
                                       '1e9] (operating seconds per stream second), got 0')
        try:
            spec = twin_config(config)
        except InvalidParameter as err:
            raise InvalidParameter(f'{path}: {err}') from None
        try:
            params, joint_params = joint_reducers(config, path)
            life = LifeConfig(**{k: (int(v) if k == 'n_samples' else float(v))
                                 for k, v in config['life'].items()})
        except TypeError as err:
            raise InvalidParameter(f'{path}: life section: {err}; allowed keys: '
                                   f'{sorted(LifeConfig.__dataclass_fields__)}') from None
        except ValueError as err:
            raise InvalidParameter(f'{path}: {err}') from None
        try:
            interfaces = InterfaceMap.from_mapping(twin['interfaces'], 'twin.interfaces')
        except InvalidParameter as err:
            raise InvalidParameter(f'{path}: {err}') from None
        named = tuple((f'twin.{key}', twin[key]) for key in ('link_topic', 'motor_topic')
                      if f'twin.{key}' in given and twin[key])
        return cls(joints=tuple(twin['joints']) if 'twin.joints' in given else None,
                   configured_topics=named,
                   link_topic=str(twin['link_topic']), motor_topic=str(twin['motor_topic']),
                   motor_suffix=str(twin['motor_suffix']),
                   motor_angles=twin['motor_angles'] if 'twin.motor_angles' in given else 'auto',
                   motor_direction=(twin['motor_direction'] if 'twin.motor_direction' in given
                                    else 'auto'),
                   effort_source=twin['effort_source'],
                   motor_effort_units=twin['motor_effort_units'],
                   effort_scale=check_effort_scale(twin['effort_scale'], f'{path}: twin.'),
                   interfaces=interfaces, aging_factor=aging, window_s=spec.window_s,
                   max_gap_s=spec.max_gap_s, friction_in_effort=spec.friction_in_effort,
                   effort_lag_s=spec.effort_lag_s,
                   params=params, joint_params=tuple(joint_params.items()),
                   service_times=tuple(config['service_time_s'].items()), life=life)


MOTOR_ANGLES = ('auto', 'raw', 'output')


def _number(path, name, value, lo, hi):
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and \
        math.isfinite(value) and lo <= value <= hi
    if not ok:
        raise InvalidParameter(f'{path}: {name} must be a number in [{lo:g}, {hi:g}], got '
                               f'{value!r}')
    return float(value)
