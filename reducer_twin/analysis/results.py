"""What an analysis of one bag gives: per joint (:class:`JointResult`) and per bag."""

from dataclasses import dataclass, field
import math
from pathlib import Path

import numpy as np
from reducer_twin.analysis.joints import JointPlan
from reducer_twin.core.joint_twin import estimate_numbers
from reducer_twin.core.life_basis import life_basis
from reducer_twin.core.units import rad_to_arcmin
from reducer_twin.msg_adapters.layouts import REMAINING_LIFE
from reducer_twin.msg_adapters.layouts import WEAR_ESTIMATE


@dataclass
class JointResult:
    """
    What the analysis found for one joint.

    Attributes
    ----------
    name : str
        Joint name.
    messages : int
        JointState messages read that carry the joint.
    rejected : int
        Samples the ingestion rules dropped (non-finite, duplicate, out of order,
        unpaired, spikes) plus malformed messages skipped.
    counts : dict
        Count of every ingestion rule (as ``encoder_ingest`` reports them).
    features : numpy.ndarray
        ``te_features`` records, (windows, fields).
    wear, life : numpy.ndarray
        ``wear`` and ``remaining_life`` records, (windows + 1, fields) (first: start).
    levels : list of str
        Health level of each ``life`` record.
    te : numpy.ndarray
        Thinned TE samples (stamp_s, output_angle_rad, te_rad, torque_nm).
    truth : numpy.ndarray or None
        ``ground_truth`` records from the bag, if it has them.
    soft_zone : dict or None
        A soft zone beyond the test torque, where said (:attr:`.joint_twin.TwinFront.soft_zone`).
    within_zone : dict or None
        Loads within a soft zone, where said (:attr:`.within_zone.WithinZoneCheck.said`).
    time_offset_s : float or None
        The encoders' time offset the joint's next bag may start from
        (:attr:`.pipeline.TimeOffsetCalibration.to_carry`).
    front_state : dict or None
        What the joint's next bag continues its front from (:meth:`.joint_twin.TwinFront.state`:
        that offset and the soft-zone check), as a restarted ``te_monitor`` does.

    """

    name: str
    messages: int = 0
    rejected: int = 0
    counts: dict = field(default_factory=dict)
    features: np.ndarray = None
    wear: np.ndarray = None
    life: np.ndarray = None
    levels: list = field(default_factory=list)
    te: np.ndarray = None
    truth: np.ndarray = None
    windows: int = 0
    reason: str = None
    partial: str = None
    velocity: str = None
    service: dict = None
    soft_zone: dict = None
    within_zone: dict = None
    test_torque_check: str = None
    time_offset_s: float = None
    front_state: dict = None
    inputs: list = field(default_factory=list)

    @property
    def observed(self):
        """Whether windows gave a lost motion the twin trusts (the estimate rests on data)."""
        return self.windows > 0 and self.reason is None

    def summary(self):
        """
        Return the ``--json`` fields of this joint (edge units; NaN as None).

        Returns
        -------
        dict
            ``wear_um``, ``wear_std_um``, ``rul_p10_h``, ``rul_p50_h``, ``rul_p90_h``,
            ``lost_motion_arcmin`` and ``lost_motion_std_arcmin`` (None when not
            observed), ``messages``, ``rejected``,
            ``observed``, ``windows`` (windows with a lost motion), ``reason`` (why
            not observed, else None), ``partial`` (why an observed estimate stands as of
            a window well before the recording's end, else None), ``pairing`` (how
            link and motor samples were paired, and why) and ``velocity`` (``'field'``:
            the velocity field, found to be the link angle's rate; ``'link_angle'``: the
            rate of the link angle, where the field is missing or is not that rate; None
            without samples), ``inputs`` (how the inputs are read otherwise than published:
            the lines of the joint's input ``WARNING`` s,
            :meth:`.joint_twin.TwinFront.input_warnings`; empty when none),
            ``soft_zone`` (where the play is still being taken up at the lost-motion test
            torque, :attr:`.joint_twin.TwinFront.soft_zone` in arcmin: ``width_arcmin``, the
            catalogue's lost motion there, ``play_arcmin``, ``shortfall_arcmin``,
            ``shortfall_sd_arcmin``, stream means, ``windows``, ``few_samples`` and
            ``taken_off_arcmin``, what the lost motion given was taken off the play by: the
            shortfall, less where the play followed lies nearer the width,
            :func:`.pipeline.taken_off`; None when not observed; else None),
            ``within_zone`` (where the lost motion read from the flanks is below the width
            its bins give at the test torque, :mod:`.within_zone`, in arcmin:
            ``width_arcmin``, that width less the catalogue windup, ``read_arcmin``, the
            windows' reading, ``gap_arcmin``, ``gap_sd_arcmin``, ``slope`` (the width's
            growth with the load over the windup's), ``windows`` and ``added_arcmin``, what
            the lost motion given was raised by: the gap, less where the play followed lies
            nearer the width; None when not observed; else None),
            ``test_torque_check`` (what comparing the width at the test torque with the
            flanks of higher loads found: ``'soft zone'``, ``'unconfirmed'`` (a shortfall
            past the floor that is not said: too few windows or standard errors, or under a
            fifth of the play), ``'none found'`` or
            ``'not compared'``; but for the first, the lost motion given is the play;
            :attr:`.soft_zone.SoftZoneCheck.outcome`; None when not observed) and
            ``rate_resolved`` (whether the remaining life rests on
            the unit's own growth, :func:`.life_basis.rate_resolved`; None when not observed),
            ``growth_law`` (where the remaining life follows the lost motion's observed growth
            law rather than the wear model's curve: its ``probability``, its ``weight`` in
            the remaining life, ``exponent`` and ``extrapolation``, the times the exposure
            seen it is extrapolated to, :func:`.life_basis.growth_law`; else None),
            ``curve_extrapolation`` (where the remaining life follows the wear model's curve
            beyond the span its shape was compared with the observed growth over: the times
            the exposure seen its P50 reaches, :func:`.life_basis.curve_extrapolation`; else
            None) and ``service`` (how the service time of a reducer met without state was
            taken: ``hours``, ``taken``, ``rate_scale``; ``taken`` None while too few
            windows have judged it; None without one).

        """
        wear = dict(zip(WEAR_ESTIMATE.fields, self.wear[-1])) if self.wear is not None and \
            len(self.wear) else {}
        life = dict(zip(REMAINING_LIFE.fields, self.life[-1])) if self.life is not None and \
            len(self.life) else {}
        observed = self.observed
        out = estimate_numbers(wear, life, observed)
        out['messages'] = int(self.messages)
        out['rejected'] = int(self.rejected)
        out['observed'] = observed
        out['windows'] = int(self.windows)
        out['reason'] = None if observed else (self.reason or 'no usable window')
        out['partial'] = self.partial if observed else None
        out['pairing'] = self.counts.get('pairing')
        out['velocity'] = self.velocity
        out['inputs'] = list(self.inputs)
        out['soft_zone'] = soft_zone_numbers(self.soft_zone)
        out['within_zone'] = within_zone_numbers(self.within_zone) if observed else None
        out['test_torque_check'] = self.test_torque_check if observed else None
        taken = wear.get('soft_zone_shortfall_rad') if observed else None
        if out['soft_zone'] is not None:
            # What the lost motion given was taken off the play by (pipeline.taken_off).
            out['soft_zone']['taken_off_arcmin'] = None if taken is None else \
                rad_to_arcmin(float(taken))
        if out['within_zone'] is not None:
            out['within_zone']['added_arcmin'] = None if taken is None else \
                rad_to_arcmin(max(-float(taken), 0.0))
        out.update(life_basis(wear, life, observed))
        out['service'] = self.service
        return out


@dataclass
class BagResult:
    """
    The analysis of one bag.

    Attributes
    ----------
    bag : pathlib.Path
        The input.
    out : pathlib.Path
        The derived bag directory.
    plan : JointPlan
        Topics and joints used.
    joints : dict of str to JointResult
        Per joint.
    messages : int
        JointState messages read.
    seconds : float
        Wall time of the analysis [s].
    aging_factor : float
        Aging factor applied.
    warnings : list of ReadWarning
        Problems met while reading.
    damaged : bool
        Whether reading stopped early or skipped data (truncated or corrupt files).
    states : dict of str to dict
        Per joint, where its estimator and life stages ended (``JointBack.state``): the
        ``initial_states`` of the reducer's next bag.

    """

    bag: Path
    out: Path
    plan: JointPlan
    joints: dict
    messages: int
    seconds: float
    aging_factor: float
    warnings: list
    damaged: bool
    states: dict = field(default_factory=dict)

    @property
    def messages_per_s(self):
        """Return the JointState messages analysed per second of wall time."""
        return self.messages / self.seconds if self.seconds > 0 else float('nan')

    def as_json(self):
        """Return ``{"joints": {name: {...}}, "messages_per_s": x}``."""
        rate = self.messages_per_s
        joints = {name: j.summary() for name, j in self.joints.items()}
        for name, reason in self.plan.not_analysed().items():
            joints[name] = {**estimate_numbers({}, {}, False), 'messages': 0, 'rejected': 0,
                            'observed': False, 'windows': 0, 'reason': reason,
                            'partial': None, 'pairing': None, 'velocity': None,
                            **life_basis({}, {}, False), 'service': None, 'inputs': [],
                            'soft_zone': None, 'within_zone': None,
                            'test_torque_check': None}
        return {'joints': joints,
                'messages_per_s': float(rate) if math.isfinite(rate) else None}


def soft_zone_numbers(said):
    """
    Return the soft zone's figures in edge units (``--json``), or None.

    Parameters
    ----------
    said : dict or None
        :attr:`.joint_twin.TwinFront.soft_zone` ([rad]).

    Returns
    -------
    dict or None
        ``width_arcmin``, ``play_arcmin``, ``shortfall_arcmin``, ``shortfall_sd_arcmin``,
        ``windows`` and ``few_samples`` (compared on bins of a few samples each).

    """
    if said is None:
        return None
    out = {f'{key}_arcmin': rad_to_arcmin(float(said[key]))
           for key in ('width', 'play', 'shortfall', 'shortfall_sd')}
    out['windows'] = int(said['windows'])
    out['few_samples'] = bool(said.get('few_samples', False))
    return out


def within_zone_numbers(said):
    """
    Return the within-zone check's figures in edge units (``--json``), or None.

    Parameters
    ----------
    said : dict or None
        :attr:`.within_zone.WithinZoneCheck.said` ([rad]).

    Returns
    -------
    dict or None
        ``width_arcmin``, ``read_arcmin``, ``gap_arcmin``, ``gap_sd_arcmin``, ``slope`` and
        ``windows``.

    """
    if said is None:
        return None
    out = {f'{key}_arcmin': rad_to_arcmin(float(said[key]))
           for key in ('width', 'read', 'gap', 'gap_sd')}
    out['slope'] = float(said['slope'])
    out['windows'] = int(said['windows'])
    return out


def is_damage(warning):
    """
    Tell whether a read warning means data were lost (truncation, corruption).

    Parameters
    ----------
    warning : ReadWarning
        A warning of the bag reader.

    Returns
    -------
    bool
        True when reading stopped early or skipped a damaged part.

    """
    text = warning.message
    # A file cut short (no footer), storage files missing, or fewer messages than the
    # metadata counts: messages were lost even where everything left is readable.
    return warning.offset is not None or any(
        key in text for key in ('reading stopped', 'corrupt', 'skipping that file',
                                'without a data end', 'no footer', 'do not exist',
                                'but the storage files hold', 'but no storage file holds'))
