"""
The nodes' own numeric settings (timing of their work), as validated dataclasses.

Declared like the core's dataclasses (:class:`~reducer_twin.nodes.parameters.
SpecParameters`, no prefix): one source of each default, unit and range, shown by
ROS tools and checked at start.
"""

from dataclasses import dataclass

from reducer_twin.core.params import _Validated, spec


@dataclass(frozen=True)
class DiagnosticsSettings(_Validated):
    """How often a node reports on ``/diagnostics``."""

    _prefix = 'node'
    diagnostics_period_s: float = spec(1.0, 's', 0.0, 3600.0, 'period of /diagnostics',
                                       lo_open=True)


@dataclass(frozen=True)
class IngestSettings(_Validated):
    """``encoder_ingest``'s ratio and batching."""

    _prefix = 'encoder_ingest'
    gear_ratio: float = spec(0.0, '', 0.0, 1e4, 'total ratio; 0 takes it from the RV-80E '
                                                'geometry (81)')
    batch_period_s: float = spec(0.002, 's', 0.0, 1.0, 'longest time a sample waits to be '
                                 'published; 0: every controller message at once')


@dataclass(frozen=True)
class TEMonitorSettings(_Validated):
    """``te_monitor``'s TE batching, and when a stopped stream is said."""

    _prefix = 'te_monitor'
    te_publish_period_s: float = spec(0.02, 's', 0.0, 3600.0, 'longest wait of a TE row for '
                                      'its batch while the stream flows (the last rows of a '
                                      'stopped stream go with the next analysis)', lo_open=True)
    silent_after_s: float = spec(20.0, 's', 0.0, 86400.0, 'time without encoder pairs after '
                                 'which /diagnostics warn that the stream stopped',
                                 lo_open=True)


@dataclass(frozen=True)
class StoreSettings(_Validated):
    """``wear_estimator``'s live segments in a fleet store."""

    _prefix = 'wear_estimator'
    store_period_s: float = spec(60.0, 's', 0.01, 86400.0,
                                 'period of live segments written to the fleet store')


@dataclass(frozen=True)
class SimulatorSettings(_Validated):
    """``joint_simulator``'s publishing."""

    _prefix = 'joint_simulator'
    truth_period_s: float = spec(1.0, 's', 0.0, 3600.0, 'period of the ground-truth topics',
                                 lo_open=True)
    max_catch_up: int = spec(50, '', 1, 1_000_000, 'most samples published in one late '
                                                   'timer tick', integer=True)
