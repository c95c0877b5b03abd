"""
What a remaining life rests on, read from a ``wear`` record, and the words that say so.

Whether the unit's own wear rate is resolved by its windows (:func:`rate_resolved`)
or the life spans rates they cannot tell apart (:func:`rate_unresolved`), a growth
faster than wear can be (:func:`faster_than_wear`: a change in what the windows read,
or damage, not a rate), the observed growth law's weight in the remaining life and
how far it is extrapolated (:func:`life_trend_probability`, :func:`growth_law`), the
limit a soft zone moves (:func:`play_limit`), the wear model's extrapolation
(:func:`curve_extrapolation`), and the clauses of the life message
(:func:`rate_note`, :func:`growth_note`, :func:`curve_note`, :func:`play_clause`,
:func:`torque_check_lines`; :func:`life_basis` for ``analyze --json``, the report and the
fleet). Pure functions of records:
:class:`.pipeline.LifeStage` (live and offline) and the fleet read them alike.
"""

from dataclasses import dataclass
import math

from .estimator import EstimatorConfig
from .trend_score import SCORE_AFTER, SCORE_LAG

RATE_RESOLVED_SD = 0.5
"""
Sd of ``ln s`` up to which the unit's own wear rate counts as resolved by its windows.

The prior's is 2 (the model's rate may be off by 7 times either way at 1 sd); at 0.5 the
rate alone spans the remaining life's P10-P90 over a factor 3.6. A twin from new gets
there within 10-25 % of a life (``bench_accuracy.py``); one started on a used unit with
a short recording may not: its remaining life then spans the rates its windows cannot
tell apart, the model's at this duty among them. A P10 that does so is not the unit's wear:
the life level goes no higher than ``'WARN'`` for it (:meth:`.pipeline.LifeStage.process`), and the
fleet's verdict is ``WATCH`` (:mod:`reducer_twin.fleet.verdict`).
"""


def rate_note(wear_record):
    """
    Say when the remaining life rests on rates the windows cannot tell apart, not the unit's own.

    Parameters
    ----------
    wear_record : mapping
        A ``wear`` record.

    Returns
    -------
    str
        ``''`` once the prediction rests on the unit's own growth
        (:func:`rate_resolved`), else a clause for the life message.

    """
    if rate_resolved(wear_record):
        return ''
    return f'; {rate_unresolved(wear_record)}'


GROWTH_SEEN_SIGMAS = 3.0
"""
The law's growth to date over its sd from which the law has seen the lost motion grow.

The growth ``k`` is cut to ``k >= 0``: windows that cannot tell it from none give the
half-normal's mean over its sd, 1.33 (measured 1.15-1.43: a used unit recorded for 6
minutes in real time, and for 60 s at aging factor 3600).
"""


def _law_likelier(wear_record):
    """Whether the observed growth law is the likelier model of the record (probability > 0.5)."""
    return float(wear_record.get('trend_probability', 0.0)) > 0.5


def _growth_seen(wear_record):
    """Whether the law's growth to date lies :data:`GROWTH_SEEN_SIGMAS` sds above none."""
    k = float(wear_record.get('trend_growth_rad', math.nan))
    var = float(wear_record.get('var_trend_growth_rad2', math.nan))
    return var > 0.0 and k >= GROWTH_SEEN_SIGMAS * math.sqrt(var)


_PRIOR = EstimatorConfig()

LOG_RATE_PLAUSIBLE = math.log(_PRIOR.initial_rate_scale) + 3.0 * _PRIOR.initial_log_rate_scale_std
"""
``ln s`` beyond which a rate is faster than wear: the estimator's prior mean plus 3 sds (6).

The prior holds a rate 400 times the model's at the duty to 0.13 %. A unit met used and
recorded for minutes in real time shows no growth its windows can read (0.0001 arcmin
true), yet their reading drifts by up to 0.03 arcmin (the first windows, those after a cycle's
pauses) and their mix of flanks changes (a base whose knee lies above its loads' reach:
0.4-5 arcmin from window to window): taken as wear that is a rate e^6-e^18 times the
model's (one-off scripts over the derived bags of ``bench_service_time.py --aging-factor
1 --hours 0.1``: every joint of both generators above e^6; the independent generator's
fastest units read ln s up to 4.6), and the law or a released rate took it as this unit's
own: P50 minutes to hours on units with 1 400-7 200 h left, resolved, REPLACE.
"""


def implied_log_rate(wear_record):
    """
    Return ``ln s`` of the rate the remaining life rests on (NaN where it cannot be read).

    Where the observed growth law is the likelier, its growth to date ``k`` over the
    Archard exposure ``A`` seen (wear at the model's rate [m]) as a rate on the wear
    model's curve, through the curve's secant from the new unit::

        ln s = ln(k / (A · (LM - LM_new) / w))

    else the wear model's own ``ln s``.
    """
    if not _law_likelier(wear_record):
        return float(wear_record.get('log_rate_scale', math.nan))
    k = float(wear_record.get('trend_growth_rad', math.nan))
    exposure = float(wear_record.get('archard_exposure_m', math.nan))
    wear = float(wear_record.get('wear_m', math.nan))
    play = float(wear_record.get('lost_motion_rad', math.nan)) \
        + float(wear_record.get('soft_zone_shortfall_rad', 0.0))
    growth = play - float(wear_record.get('lost_motion_new_rad', math.nan))
    if not (k > 0.0 and exposure > 0.0 and wear > 0.0 and growth > 0.0):
        return math.nan
    return math.log(k * wear / (growth * exposure))


def faster_than_wear(wear_record):
    """Return :func:`implied_log_rate` where it exceeds :data:`LOG_RATE_PLAUSIBLE`, else None."""
    log_rate = implied_log_rate(wear_record)
    return log_rate if log_rate > LOG_RATE_PLAUSIBLE else None


def faster_than_wear_words(log_rate):
    """Return the clause that says a growth is faster than wear, at ``ln s`` (bracket open)."""
    return (f'lost motion reads as growing faster than wear can (e^{log_rate:.1f} times the '
            "model's wear rate at this duty")


def rate_unresolved(wear_record):
    """Return how far the unit's own wear rate is from resolved, and what that means, in words."""
    log_rate = faster_than_wear(wear_record)
    if log_rate is not None:
        return (f"this unit's {faster_than_wear_words(log_rate)}; its prior allows up to "
                f'e^{LOG_RATE_PLAUSIBLE:g}): that is a change in what its windows read, or '
                'damage (a step, not wear; inspect it if the lost motion stays high), not a wear '
                'rate, so its remaining life spans rates its windows do not resolve')
    sd = math.sqrt(max(float(wear_record['var_log_rate']), 0.0))
    return (f"this unit's own wear rate is not yet resolved (ln-rate sd {sd:.2f}, resolved at "
            f'{RATE_RESOLVED_SD:g}): its remaining life spans the rates its windows cannot '
            "tell apart, the model's at this duty among them")


def rate_resolved(wear_record):
    """
    Return whether a ``wear`` record's remaining life rests on the unit's own growth.

    True once ``ln s`` has an sd of at most :data:`RATE_RESOLVED_SD`, or the observed
    growth law is the likelier (it is fitted to the unit's windows) and has seen the lost
    motion grow (:data:`GROWTH_SEEN_SIGMAS`): a law that won its score on minutes of a
    real-time recording, whose growth its windows cannot tell from none, resolves no rate
    (``bench_service_time.py --aging-factor 1 --hours 0.1``: of the joints called resolved
    with P10 at hours, REPLACE for units with thousands of hours left, 1 of 3 on the
    independent generator and 5 of 10 on the third were such). Never a rate faster than
    wear can be (:func:`faster_than_wear`).
    """
    if faster_than_wear(wear_record) is not None:
        return False
    if _law_likelier(wear_record) and _growth_seen(wear_record):
        return True
    var = float(wear_record.get('var_log_rate', math.nan))
    return math.isfinite(var) and var <= RATE_RESOLVED_SD ** 2


TREND_PRIOR = _PRIOR.trend_probability
"""Prior probability of the observed growth law (the estimator's default)."""

SCORED_FROM = SCORE_AFTER + SCORE_LAG
"""Usable window at which the two models' lagged predictions are first scored."""


def life_trend_probability(wear_record, limit):
    """
    Return the weight of the observed growth law in the remaining life.

    The probability that the law holds comes from predictions a few windows ahead, scored
    over the exposure from the first scored window to now: a log-span ``S = ln(n/16)`` for
    ``n`` usable windows of a steady duty. The remaining life extrapolates the law over
    ``L = ln(A_lim/A_now)`` (its mean's reach of the limit). Beyond the span its evidence
    was gathered on it says nothing, so the weight moves back towards the prior ``p0``
    in proportion: ``p0 + (p - p0)·min(1, S/L)``.
    """
    return _weighed(wear_record, _law_reach(wear_record, limit))


def _weighed(wear_record, reach):
    """:func:`life_trend_probability` of a record whose law's reach is ``reach`` (or None)."""
    p = float(wear_record.get('trend_probability', 0.0))
    if reach is None or reach <= 1.0:
        return p
    share = min(1.0, math.log(_scored_span(wear_record)) / math.log(reach))
    return TREND_PRIOR + (p - TREND_PRIOR) * share


def _scored_span(wear_record):
    """Return the ratio of exposures the two models were scored over, ``n/16`` (at least 1)."""
    return max(float(wear_record.get('updates', 0.0)), SCORED_FROM) / SCORED_FROM


def play_limit(wear_record, limit):
    """
    Return the play [rad] at which the lost motion at the test torque meets ``limit``.

    The estimator and the growth law follow the play the loaded flanks give; where a soft
    zone reaches beyond the test torque (:mod:`.soft_zone`), the lost motion at the test
    torque is that play less the record's ``soft_zone_shortfall_rad``, so the limit is met
    where the play reaches ``limit`` plus it. ``limit`` itself where the record has none.
    """
    shortfall = float(wear_record.get('soft_zone_shortfall_rad', 0.0))
    return limit + shortfall if math.isfinite(shortfall) and shortfall != 0.0 else limit


def _law_reach(wear_record, limit):
    """Return how many times the exposure seen the law's mean meets ``limit`` at (None: never)."""
    limit = None if limit is None else play_limit(wear_record, limit)
    g = float(wear_record.get('trend_exponent', math.nan))
    beta = float(wear_record.get('trend_new_rad', math.nan))
    k = float(wear_record.get('trend_growth_rad', math.nan))
    if limit is not None and k > 0.0 and g > 0.0 and limit > beta + k:
        return float(((limit - beta) / k) ** (1.0 / g))
    return None


def growth_law(wear_record, limit=None):
    """
    Return the observed growth law a ``wear`` record's remaining life follows, if it does.

    Parameters
    ----------
    wear_record : mapping
        A ``wear`` record.
    limit : float, optional
        The lost-motion limit [rad].

    Returns
    -------
    dict or None
        None while the model's curve is the likelier law; else ``probability`` (that the
        law holds, by its predictions a few windows ahead), ``weight`` (its weight in the
        remaining life, :func:`life_trend_probability`: lower where the law is
        extrapolated beyond the span it was scored on; the probability without
        ``limit``), ``exponent`` (``g`` of ``z = β + k·(A/A_now)^g`` in the Archard
        exposure) and ``extrapolation``: how many times the exposure seen the law's mean
        reaches the limit at, ``((limit - β)/k)^(1/g)`` (None without ``limit``, or where
        the law does not reach it or has passed it).

    """
    if not _law_likelier(wear_record):
        return None
    p = float(wear_record['trend_probability'])
    reach = _law_reach(wear_record, limit)    # None without a limit: the weight is p
    return {'probability': p, 'weight': _weighed(wear_record, reach),
            'exponent': float(wear_record['trend_exponent']), 'extrapolation': reach}


def curve_extrapolation(wear_record, life_record):
    """
    Return how far the wear model's curve carries a remaining life beyond its tested span.

    Where the remaining life follows the wear model's curve on the unit's own rate (the
    observed growth law not the likelier, :func:`growth_law`; the rate resolved,
    :func:`rate_resolved`), its P50 lies at the Archard exposure ``A_now + P50·ȧ``: the
    curve is extrapolated to ``1 + P50·ȧ/A_now`` times the exposure seen. The curve's
    shape was compared with the observed growth over the span the two models were scored
    on (``n/16`` for ``n`` usable windows of a steady duty, as in
    :func:`life_trend_probability`); beyond it nothing in the windows tested it. Early in a
    life a few tenths of an arcminute of growth cannot tell the curve from a straight law
    (``bench_early_life.py``): the curve then extrapolates 10-100 times, and its interval
    holds only if the lost motion keeps to it.

    Parameters
    ----------
    wear_record : mapping
        A ``wear`` record.
    life_record : mapping
        Its ``remaining_life`` record (``p50_s``; the horizon where censored).

    Returns
    -------
    float or None
        The times the exposure seen the P50 reaches, where that is beyond the scored span;
        else None (the law is the likelier, the rate is the model's, or within the span).

    """
    if growth_law(wear_record) is not None or not rate_resolved(wear_record):
        return None
    exposure = float(wear_record.get('archard_exposure_m', math.nan))
    rate = float(wear_record.get('duty_rate_m_per_s', math.nan))
    p50 = float(life_record.get('p50_s', math.nan))
    if not (exposure > 0.0 and rate > 0.0 and p50 > 0.0 and math.isfinite(exposure * rate * p50)):
        return None
    reach = 1.0 + p50 * rate / exposure
    return reach if reach > _scored_span(wear_record) else None


def life_basis(wear_record, life_record, observed):
    """
    Return what a reducer's remaining life rests on, as ``analyze --json`` and ``fleet`` say it.

    One place for a bag's summary and a live segment's, so that the fleet's verdict reads
    the same clauses for a reducer whichever path saw it last.

    Parameters
    ----------
    wear_record, life_record : mapping
        The last ``wear`` record and its ``remaining_life`` record (empty: none yet).
    observed : bool
        Whether the estimate rests on a lost motion.

    Returns
    -------
    dict
        ``rate_resolved`` (:func:`rate_resolved`), ``faster_than_wear``
        (:func:`faster_than_wear`: the ``ln s`` of a growth faster than wear, else None),
        ``growth_law`` (:func:`growth_law` at the record's lost-motion limit) and
        ``curve_extrapolation`` (:func:`curve_extrapolation`); each None when not observed
        or without a record.

    """
    if not (observed and wear_record):
        return {'rate_resolved': None, 'faster_than_wear': None, 'growth_law': None,
                'curve_extrapolation': None}
    return {'rate_resolved': rate_resolved(wear_record),
            'faster_than_wear': faster_than_wear(wear_record),
            'growth_law': growth_law(wear_record, life_record.get('lost_motion_limit_rad')),
            'curve_extrapolation': curve_extrapolation(wear_record, life_record)}


def curve_note(wear_record, life_record):
    """
    Say when the remaining life extrapolates the wear model's curve beyond its tested span.

    Parameters
    ----------
    wear_record, life_record : mapping
        A ``wear`` record and its ``remaining_life`` record.

    Returns
    -------
    str
        ``''`` unless :func:`curve_extrapolation` gives a reach, else a clause for the
        life message.

    """
    reach = curve_extrapolation(wear_record, life_record)
    if reach is None:
        return ''
    return (f"; the prediction follows the wear model's curve, extrapolated to {reach:.0f}x "
            f'the exposure it was learnt on (its shape compared with the observed growth over '
            f'{_scored_span(wear_record):.0f}x)')


def growth_note(wear_record, limit=None):
    """
    Say when the observed lost-motion trend departs from the model's curve.

    Parameters
    ----------
    wear_record : mapping
        A ``wear`` record.
    limit : float, optional
        The lost-motion limit [rad]: the clause then says how far beyond the exposure
        seen the law is extrapolated (:func:`growth_law`).

    Returns
    -------
    str
        ``''`` while the model's curve is the likelier law, else a clause for
        the life message: the prediction follows the observed trend, with the
        exponent of its power law in the Archard exposure and, with ``limit``, how
        far it is extrapolated.

    """
    law = growth_law(wear_record, limit)
    if law is None:
        return ''
    note = (f'; lost motion grows unlike the wear model (as exposure^{law["exponent"]:.2f}, '
            f'probability {law["probability"]:.2f}): the prediction follows the observed '
            'trend')
    if law['extrapolation'] is not None:
        note += f', extrapolated to {law["extrapolation"]:.0f}x the exposure it was learnt on'
        if law['weight'] < law['probability']:
            note += f' (weighed {law["weight"]:.2f}: its score spans less)'
    return note


TEST_TORQUE_CAVEATS = ('unconfirmed', 'not compared')
"""
Outcomes of :class:`.soft_zone.SoftZoneCheck` whose line goes beside an alarm.

The lost motion is then the loaded flanks' play, whether or not the unit has a soft zone
reaching beyond the test torque: the windows compared the width there too little to say
one (``'unconfirmed'``), or not at all (``'not compared'``).
"""


def play_clause(level, check, line, wear_record):
    """
    Say beside an alarm that its lost motion may be the play, not the width at the test torque.

    Said only where the life's level is ``'WARN'`` or ``'ERROR'``: a short clean recording
    whose loads seldom dwell at the test torque is common, and on a unit without a soft zone
    the play is its lost motion. Nothing where the lost motion is already given less a soft
    zone (the record's ``soft_zone_shortfall_rad``, this stream's or carried over).

    Parameters
    ----------
    level : str
        The life's ``/diagnostics`` level.
    check : str or None
        What the comparison at the test torque found (:attr:`.soft_zone.SoftZoneCheck.outcome`).
    line : str or None
        Its line (:attr:`.soft_zone.SoftZoneCheck.caveat` or ``not_compared``).
    wear_record : Mapping
        The ``wear`` record the life was assessed from.

    Returns
    -------
    str or None
        ``line`` where it is to be said, else None.

    """
    if not line or check not in TEST_TORQUE_CAVEATS or level not in ('WARN', 'ERROR'):
        return None
    return None if float(wear_record.get('soft_zone_shortfall_rad', 0.0)) != 0.0 else line


@dataclass(frozen=True)
class TorqueCheckFinding:
    """
    What a joint's window analysis found at the lost-motion test torque, as told live.

    ``te_monitor`` reads it; ``life_publisher`` and a ``wear_estimator`` writing a fleet
    store hear it (:mod:`reducer_twin.nodes.torque_check`) and say it beside the life
    (:func:`torque_check_lines`).

    Attributes
    ----------
    check : str
        The soft-zone comparison's outcome (:attr:`.soft_zone.SoftZoneCheck.outcome`).
    line : str or None
        Its caveat (``'unconfirmed'``) or why nothing was compared (``'not compared'``).
    within_zone : str or None
        Why the lost motion read is below its bins' width at the test torque
        (:attr:`.within_zone.WithinZoneCheck.reason`), or None.

    """

    check: str
    line: str = None
    within_zone: str = None


def torque_check_lines(level, finding, wear_record):
    """
    Return the lines said beside a life about what was found at the test torque.

    A lost motion read below its bins' width at the test torque is said whatever the
    life's level: its error is the optimistic one (the life too long), as ``analyze``
    says it among the joint's ``"inputs"``. The play's caveat follows :func:`play_clause`.

    Parameters
    ----------
    level : str
        The life's ``/diagnostics`` level.
    finding : TorqueCheckFinding or None
        What was heard (None: nothing).
    wear_record : Mapping
        The ``wear`` record the life was assessed from.

    Returns
    -------
    list of str
        The lines, in the order said (none, one or both).

    """
    if finding is None:
        return []
    clause = play_clause(level, finding.check, finding.line, wear_record)
    return [x for x in (finding.within_zone, clause) if x]
