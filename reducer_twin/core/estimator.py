"""
State estimator of a reducer's wear, as-built lost motion, wear rate and growth law.

progpy vocabulary: the *model* is the Archard rate of :mod:`.wear` (process)
and the lost-motion table of :mod:`.transmission_error` (observation); this
module is the *state estimator*; :mod:`.life` is the *predictor*.

State ``x = [w, θ, b, c]``:

* ``w``: combined wear of disc and pins since new [m] (the two cannot be
  separated from the signals, physics notes section 4);
* ``θ = ln s``: ``s`` the multiplier on the Archard rate (field data wear
  about 10x slower than the paper's lab scenario, physics notes section 5;
  a reducer that lost its lubrication wears many times faster);
* ``b``: the unit's as-built offset [m]: a modification that adds clearance
  acts like uniform wear (physics notes section 4), so a unit built looser or
  tighter than nominal has lost motion ``h(w + b)``. New lost motion 0.3-1.0
  arcmin (catalogue: at most 1 arcmin, nominal 0.435) is ``b`` in about
  -0.5 .. +2.4 µm;
* ``c``: the bias of the window fit's lost motion [rad]. The 1x and 2x
  manufacturing harmonics cannot be told from the torque dependence under a
  gravity load and leave 0.02-0.07 arcmin in the fitted lost motion, more at
  higher speed (measured on the project's simulator with clean effort: 0 with
  the harmonics switched off). It is constant for a unit and duty, and is told
  from ``b`` by the curve: ``b`` moves the lost motion less as the unit wears.

Process model, one window of encoder data (physics notes section 5)::

    w' = W(S(w) + exp(θ)·Δa)        θ' = θ + ν_θ        b' = b        c' = c

``Δa`` is ``duty.archard_increment``: ∫ wear_rate(T, ω, w=0) dt of the
observed torque/speed history at rate scale 1 without run-in. ``S`` is the
run-in-free wear ``S(w) = ∫ dw/g(w)``, ``g = (Rrms(w)/Rrms0)^1.589``
(:func:`.wear._run_in_map`), ``W`` its inverse, both extended with slope 1
below zero. Process noise ``Q = diag(q_w, q_θ, 0, 0)·Δe`` per operating
second ``Δe``: ``q_w`` (default (0.05 µm)² per 1000 h) unmodelled wear,
``q_θ`` (0.02² per 1000 h) slow drift of the rate. Both are small: a sudden
change is caught by the disagreement test below, not by a process noise that
would widen every interval.

Observation, the window's lost motion at ±3 % of rated torque::

    z = h(w + b) + c + v        v ~ t_ν(0, R)

``h`` the catalogue lost motion of the model (``model_tables(params)``).
A window's lost motion describes the middle of its exposure, not its end:
each step predicts over the first half of the window's exposure, updates,
and predicts over the second half. ``R = ρ·max(σ_z, σ_min)² + ΔLM²/12``
with ``ΔLM`` each component's lost-motion growth over the window (a
time-compressed window spans much wear), ``σ_z`` the window fit's standard
error and ``ρ`` learnt from the innovations
(covariance matching in the manner of Mehra 1972, made robust): the
``ρ`` that puts the median of the differences of the last
:data:`.noise_scale.NOISE_MEMORY` successive innovations, normalised, at the median of
χ²₁ (a bias the model misses cancels in them, so it is not taken for
noise; each difference weighted by what it says about ``ρ``), shrunk
towards 1 while few are known and kept within a factor 25 either way
(:data:`.noise_scale.NOISE_SCALE_RANGE`). The fit's standard error may understate the
window-to-window scatter (a noisy effort: ``ρ`` up to 25) or overstate it
(its shape allowance is common to a unit's windows: ``ρ`` 0.05-0.9 on the
model's simulator), and the factor differs between joints and duties. The
noise ``v`` is Student-t with ``ν = robust_dof``: a single bad window moves
the estimate little, and no observation is thrown away (Roth, Özkan &
Gustafsson 2013: the update uses ``R·max(1, (ν + d²)/(ν + 1))`` with ``d²``
the normalised innovation). A
window whose wear fit sits on the table's lower bound says only that the fit
found no clearance beyond a new nominal unit: a unit built tighter, or (far
more often on real data) a poor fit. Such a window is counted as censored and
not used; a tight unit is learnt once its lost motion has grown past the
bound.

The state is a Gaussian sum of unscented filters (:mod:`.wear_mixture`: why a
sum, its prior over ``θ``, pruning and merging, the iterated first update).

Persistent disagreement is never gated out (:mod:`.recovery`): a drift
within the gate releases the rate, a jump or outliers in a row spread the
components again over the prior range of ``θ``; both count as a recovery.
Both tests take the normalised innovation as its normal score
under the noise scale's own uncertainty: a Student-t of as many degrees of
freedom as the innovations ``ρ`` is learnt from (the prior's
:data:`.noise_scale.NOISE_PRIOR_WINDOWS` included), the prediction's share by
Satterthwaite's rule (:func:`_normal_score`), so a unit's first windows, whose
scatter ``ρ`` does not know yet, are not taken for a jump. Predictions made
while a respread settles (:data:`.trend_score.SCORE_AFTER` usable windows) are not scored.

Prior of a reducer met without state: with probability
``new_unit_probability`` it is new (``w ~ N(initial_wear,
initial_wear_std²)``), otherwise of unknown history (``w ~ N(used_wear,
used_wear_std²)``); ``b ~ N(0, as_built_std²)``, ``c ~ N(0, fit_bias_std²)``.
A lost motion beyond the as-built range makes the used hypothesis win at
once; a unit of 2 µm wear reads like a new unit built loose unless the
configuration says its history is unknown
(:meth:`EstimatorConfig.unknown_history`). ``w >= 0`` is enforced by
projecting each component's mean (Simon & Chia 2002).

Service time. A reducer met used whose operating time ``H`` before the twin's
first window is known (``service_time_s``: a robot's hour meter) starts from
the used hypothesis, and once the duty's rate ``r`` is known the estimator takes
``S(w) = e^θ·(r·H + a)`` as one pseudo-observation (:mod:`.service_time`):
the lost motion tells ``w``, so the hour meter tells ``θ``, which a short
recording cannot (measured: ``bench/bench_service_time.py``, README Figures).

Growth law. Beside the wear model, :class:`.growth.GrowthTrend` learns the
lost motion's growth against the Archard exposure from the windows
themselves (a power law with the physics as its prior). Each window's
predictive density under both models, as each predicted it
:data:`.trend_score.SCORE_LAG` windows before, is scored (prequential log score, Dawid
1984, from the :data:`.trend_score.SCORE_AFTER`-th usable window on; lagged because the
remaining life is an extrapolation); their difference gives the probability
that the observed law, not the model's curve, holds (prior
``trend_probability``). For a reducer that may have been used before the twin
started the law's exposure counts from the start, with two origins weighed by
their evidence (new, or used: :data:`.growth.START_PRIOR`). The remaining life is the
mixture of both predictions (:mod:`.life`), and so is the reported lost
motion (:meth:`WearEstimator.lost_motion`); the wear is the wear model's.

Only the curvature of ``h`` over the wear the windows span tells ``c`` from
``b``: for a window across which the lost motion grows by less than
:data:`.wear_mixture.BIAS_SEPARATION` of its sd, ``c`` is a consider state (Schmidt 1966:
its mean and variance stay, its covariances are updated), so a long
recording at one wear cannot walk the pair along their ridge.

Measured (``bench/bench_accuracy.py``, README Figures): ``c`` cannot be told
from ``b`` within a life, so its prior (``fit_bias_std``, 0.05 arcmin) sets
the width left in the wear and the remaining life. 72 windows over 60 % of
a life at 0.03 arcmin scatter, without a prior, determine ``c`` to 0.056-0.089
arcmin: no better than the prior. The prior fits the independent generator
(per-unit bias 0.035-0.055 arcmin RMS; P10-P90 coverage 76-85 %, seeds 1-4).
The project's own simulator biases its windows by 0.007-0.012 arcmin RMS, and
there the interval is too wide: coverage 97-99 %, NEES 0.14-0.17. With the
prior set to that bias (0.008 arcmin, an oracle): NEES 0.32-0.34, coverage
94-98 %; told besides that the unit is new (the used hypothesis of a reducer
met without state widens the wear's sd): NEES 0.53-0.82, coverage 93-98 %;
and without the rate's drift (``log_rate_scale_noise_density = 0``; that
simulator's rate is constant): coverage 87-89 %.
"""

from dataclasses import dataclass, replace
import hashlib
import json
import math

import numpy as np

from .duty_rate import DUTY_BATCH_WINDOWS, DutyRate
from .errors import InvalidInput
from .noise_scale import NoiseScale
from .params import _Validated, spec
from .recovery import Disagreement
from .service_time import implied_rate_scale, SERVICE_RATE_LIMIT
from .state_space import run_in_free_wear
from .trend_score import TrendScore
from .units import ARCMIN, HOUR, UM
from .wear_mixture import WearMixture

STATE_KIND = 'reducer_twin.wear_estimator'
"""Value of ``kind`` in a state dict."""

STATE_VERSION = 2
"""Version of the state dict layout; bumped on any incompatible change (1: ``[w, ln s]``)."""

N_STATE = 3
"""Dimension of the reducer's state ``[w, ln s, b]``."""


@dataclass(frozen=True)
class EstimatorConfig(_Validated):
    """
    Tuning of the wear estimator (SI units; defaults explained in the module).

    The default prior is a reducer met without state: new with probability
    ``new_unit_probability``, otherwise of unknown history.
    :meth:`unknown_history` gives the prior for a reducer known to be used.
    """

    _prefix = 'estimator'
    initial_wear: float = spec(0.0, 'm', 0.0, 1e-3, 'prior mean wear of a new reducer')
    initial_wear_std: float = spec(0.05 * UM, 'm', 0.0, 1e-3, 'prior sd of the wear of a new '
                                   'reducer', lo_open=True)
    new_unit_probability: float = spec(0.9, '', 0.0, 1.0, 'prior probability that a reducer '
                                       'met without state is new')
    used_wear: float = spec(10.0 * UM, 'm', 0.0, 1e-3, 'prior mean wear of a reducer of '
                            'unknown history')
    used_wear_std: float = spec(10.0 * UM, 'm', 0.0, 1e-3, 'prior sd of the wear of a reducer '
                                'of unknown history', lo_open=True)
    as_built_std: float = spec(1.0 * UM, 'm', 0.0, 1e-4, 'prior sd of the as-built offset b '
                               '(new lost motion referred to wear)', lo_open=True)
    initial_rate_scale: float = spec(1.0, '', 0.0, 1e3, 'prior median of the rate scale s',
                                     lo_open=True)
    initial_log_rate_scale_std: float = spec(2.0, '', 0.0, 5.0, 'prior sd of ln s',
                                             lo_open=True)
    trend_probability: float = spec(0.5, '', 0.0, 1.0, 'prior probability that the lost motion '
                                    'grows by the observed power law, not the model curve')
    fit_bias_std: float = spec(0.05 * ARCMIN, 'rad', 0.0, 1e-2, "prior sd of the window fit's "
                               'lost-motion bias c', lo_open=True)
    wear_noise_density: float = spec((0.05 * UM) ** 2 / (1000.0 * HOUR), 'm^2/s', 0.0, 1e-12,
                                     'process noise q_w on w per operating second')
    log_rate_scale_noise_density: float = spec(0.02 ** 2 / (1000.0 * HOUR), '1/s', 0.0, 1e-3,
                                               'random walk q_theta on ln s per operating second')
    min_lost_motion_std: float = spec(0.01 * ARCMIN, 'rad', 0.0, 1e-2,
                                      'floor of the lost-motion sd used in R', lo_open=True)
    robust_dof: float = spec(4.0, '', 1.0, 1e3, 'degrees of freedom of the Student-t noise')
    gate_nis: float = spec(16.0, '', 1.0, 1e6, 'NIS above which an observation is an outlier')
    max_consecutive_rejections: int = spec(5, '', 1, 10000,
                                           'outliers in a row before the rate is searched again',
                                           integer=True)
    duty_horizon_s: float = spec(1000.0 * HOUR, 's', 0.0, 1e10,
                                 'operating-time constant of the recent duty rate', lo_open=True)
    duty_min_windows: float = spec(50.0, '', 1.0, 1e9, 'fewest windows the recent duty rate '
                                   'averages over (time-compressed recordings)')
    service_time_s: float = spec(0.0, 's', 0.0, 1e10, 'operating time of a reducer met without '
                                 "state before the twin's first window (a robot's hour meter "
                                 'since the reducer was fitted); 0: not known')
    service_rate_log_std: float = spec(0.5, '', 0.0, 5.0, "sd of ln of the past duty's Archard "
                                       'rate over the duty the twin sees', lo_open=True)

    @classmethod
    def unknown_history(cls, **changes):
        """
        Return the tuning for a reducer known to be used, of unknown wear.

        Parameters
        ----------
        **changes
            Further fields to set.

        Returns
        -------
        EstimatorConfig
            ``new_unit_probability = 0``: the wear prior is ``used_wear ±
            used_wear_std``.

        """
        return cls(**{'new_unit_probability': 0.0, **changes})

    def fitted_new(self):
        """
        Return this tuning for a reducer fitted new (a recorded replacement).

        Known new (``new_unit_probability = 1``), whatever the configuration says of the
        unit the twin first met: its service time does not apply (``service_time_s = 0``).
        """
        return replace(self, new_unit_probability=1.0, service_time_s=0.0)


@dataclass(frozen=True)
class UpdateResult:
    """
    Outcome of one measurement update.

    Attributes
    ----------
    status : str
        ``'accepted'``, ``'rejected'`` (an outlier, NIS above the gate: used
        with the weight of the Student-t noise), ``'recovered'`` (persistent
        disagreement: the rate was searched again), ``'censored'`` (the
        window's wear fit on the table's lower bound: not used) or
        ``'skipped'`` (no lost motion in the window).
    innovation : float
        ``y = z - E[z]`` [rad] (NaN when skipped).
    nis : float
        Normalized innovation squared ``y²/S`` (NaN when skipped).

    """

    status: str
    innovation: float = math.nan
    nis: float = math.nan


def params_fingerprint(params):
    """
    Hash the reducer parameters so a state file of another reducer is detected.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    str
        sha256 hex digest of the canonical JSON of ``params.to_dict()``.

    """
    text = json.dumps(params.to_dict(), sort_keys=True, separators=(',', ':'))
    return hashlib.sha256(text.encode('utf-8')).hexdigest()


def lognormal_sd(mu, var):
    """
    Return the standard deviation of ``exp(X)``, ``X ~ N(mu, var)`` (a rate scale from ``ln s``).

    ``sqrt((exp(var) - 1)·exp(2·mu + var))``.
    """
    return math.sqrt(math.expm1(var) * math.exp(2.0 * mu + var))


def _normal_score(t, dof):
    """
    Return the normal score of a Student-t value of ``dof`` degrees of freedom (Wallace 1959).

    ``z = (8ν + 1)/(8ν + 3) · sqrt(ν·ln(1 + t²/ν))``, sign kept: for ``ν >= 3`` within
    0.02 of the exact score up to ``|t| = 4``, 0.06 up to 10; ``t`` itself as ``ν`` grows.
    """
    if not math.isfinite(dof) or dof > 1e6:
        return t
    z = (8.0 * dof + 1.0) / (8.0 * dof + 3.0) * math.sqrt(dof * math.log1p(t * t / dof))
    return math.copysign(z, t)


def _finite(value):
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


# --------------------------------------------------------------------------- filter


class WearEstimator:
    """
    The wear estimator: a :class:`.wear_mixture.WearMixture` and what judges its windows.

    The mixture (a Gaussian sum of unscented filters on ``x = [w, ln s, b, c]``) is
    predicted over each window's duty and corrected by its lost motion; around it, the
    noise scale, the growth law and its score, the tests of disagreement, the service
    time, the counters and the maintenance events (see the module).

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters (process and observation model).
    config : EstimatorConfig, optional
        Tuning; defaults if omitted.

    """

    def __init__(self, params, config=None):
        self.params = params
        self.config = config or EstimatorConfig()
        # A reducer with a known service time is used (however little): its wear is
        # told by its service time and rate once the duty is known (:meth:`_serviced`).
        serviced = self.config.service_time_s > 0.0
        p_new = 0.0 if serviced else self.config.new_unit_probability
        self._mix = WearMixture(params, self.config, p_new)
        self._scoring = TrendScore(p_new)
        self._service_pending = serviced
        self._service_verdict = None
        self._archard = 0.0
        self._observed_at = None
        self._window_increment = 0.0
        self._observed_exposure = None
        self._noise = NoiseScale()
        self._disagreement = Disagreement()
        self._exposure_s = 0.0
        self._exposure_since_reset_s = 0.0
        self._duty = DutyRate(self.config.duty_horizon_s, self.config.duty_min_windows)
        self._t_end = None
        self._counters = {'predictions': 0, 'updates': 0, 'rejected': 0, 'skipped': 0,
                          'censored': 0, 'recoveries': 0, 'consecutive_rejected': 0}
        self._events = []

    # filter steps ----------------------------------------------------------------------

    def predict(self, duty, fraction=1.0):
        """
        Propagate the state over (a fraction of) one window of operation.

        Parameters
        ----------
        duty : object
            With ``exposure_s`` [s] (operating seconds) and
            ``archard_increment`` [m] (run-in-free Archard wear at rate
            scale 1), both finite and >= 0.
        fraction : float
            Share of the window's exposure to predict over (the duty rate
            is counted when the last share is predicted).

        Raises
        ------
        InvalidInput
            If either value is missing, not finite or negative.

        """
        exposure = self._duty_value(duty, 'exposure_s', 's')
        increment = self._duty_value(duty, 'archard_increment', 'm')
        self._mix.predict(exposure * fraction, increment * fraction)
        self._count_duty(exposure, increment)

    def _count_duty(self, exposure, increment):
        self._counters['predictions'] += 1
        self._exposure_s += exposure
        self._exposure_since_reset_s += exposure
        self._archard += increment
        self._scoring.law.advance(self._archard)
        self._duty.add(exposure, increment)

    @staticmethod
    def _duty_value(duty, name, unit):
        value = getattr(duty, name, None)
        if not _finite(value) or float(value) < 0.0:
            raise InvalidInput(f'duty.{name} must be a finite number >= 0 {unit}, got {value!r}')
        return float(value)

    @property
    def service_pending(self):
        """Return whether a service time waits for the duty's rate to be taken."""
        return self._service_pending

    @property
    def service_verdict(self):
        """
        Return how the service time was taken: None before (or without one), else a tuple.

        ``(taken, rate_scale)``: whether it was taken and the rate scale it implies (the
        unit's mean run-in-free rate over its service relative to the model's at the duty
        seen); not taken beyond :data:`SERVICE_RATE_LIMIT`.
        """
        return self._service_verdict

    @property
    def noise_scale(self):
        """Return the learnt ratio ``ρ`` of the observed to the reported lost-motion variance."""
        return self._noise.value

    def update(self, features):
        """
        Correct the state with the lost motion observed in one window.

        Parameters
        ----------
        features : object
            With ``lost_motion`` [rad] and ``lost_motion_std`` [rad]; a
            non-finite value (no reversal in the window) skips the update.
            ``wear_fit`` at or below 0 marks a fit on the table's lower
            bound (censored: not used).

        Returns
        -------
        UpdateResult
            What happened to the observation.

        Raises
        ------
        InvalidInput
            If ``lost_motion_std`` is negative.

        """
        z = getattr(features, 'lost_motion', math.nan)
        std = getattr(features, 'lost_motion_std', math.nan)
        if not (_finite(z) and _finite(std)):
            self._counters['skipped'] += 1
            return UpdateResult('skipped')
        z, std = float(z), float(std)
        if std < 0.0:
            raise InvalidInput(f'features.lost_motion_std must be >= 0 rad, got {std!r}')
        fit = getattr(features, 'wear_fit', math.nan)
        if _finite(fit) and float(fit) <= 0.0:
            self._counters['censored'] += 1
            return UpdateResult('censored')
        sigma2 = max(std, self.config.min_lost_motion_std) ** 2
        if self._service_pending and self._counters['predictions'] >= DUTY_BATCH_WINDOWS:
            self._serviced()
        return self._update(z, sigma2)

    def _serviced(self):
        """
        Take the service time as what it says of the unit's wear and rate, once.

        Once the duty's rate ``r`` is known (:data:`.duty_rate.DUTY_BATCH_WINDOWS`
        windows on, once above zero), as :mod:`.service_time` says; not taken beyond
        :data:`.service_time.SERVICE_RATE_LIMIT` times the model's rate
        (:attr:`service_verdict` says which).
        """
        rate = self._duty.rate
        if not rate > 0.0:
            return          # no Archard exposure yet (a joint at rest): wait for it
        self._service_pending = False
        c = self.config
        past = rate * c.service_time_s
        # The state is at the window's middle (the exposure there, when stepping one).
        total = past + (self._archard if self._observed_at is None else self._observed_at)
        wp = self.params.wear
        # The rate the service time implies, from the wear the windows read so far.
        implied = implied_rate_scale(run_in_free_wear(max(self._x[0], 0.0), wp), total)
        taken = implied <= SERVICE_RATE_LIMIT * c.initial_rate_scale
        self._service_verdict = (taken, implied)
        if not taken:
            return
        self._mix.serviced(past, total, math.hypot(c.service_rate_log_std, self._duty.rel_std))
        self._mix.tidy()
        # The growth law counts from new too (its exponent prior the physics', as for a
        # unit the twin saw new), and both models are compared again from here on.
        self._scoring = TrendScore(1.0, origin=past)
        self._scoring.law.advance(self._archard)
        self._scoring.restart()

    def _update(self, z, sigma2):
        c = self.config
        nu = c.robust_dof
        rho, known = self._noise.fit()
        told = self._mix.update(z, rho, sigma2, self._window_increment)
        y, v_mix, nis, spread = told.y, told.variance, told.nis, told.spread
        R = rho * sigma2
        # The growth law sees the window as the wear model does: its noise, the Student-t
        # weight and the lost motion's growth within the window (the components' smear).
        self._score_trend(z, R + spread, R * max(1.0, (nu + nis) / (nu + 1.0)) + spread, rho)
        self._noise.add(y, v_mix, sigma2)
        self._counters['updates'] += 1
        # The tests of disagreement take the innovation as the normal score it has while
        # rho is known from few windows (a t of those degrees of freedom, Satterthwaite).
        e = _normal_score(y / math.sqrt(v_mix + R), known * ((v_mix + R) / R) ** 2)
        outlier = e * e > c.gate_nis
        if outlier:
            self._counters['rejected'] += 1
            self._counters['consecutive_rejected'] += 1
        else:
            self._counters['consecutive_rejected'] = 0
        action = self._disagreement.judge(e, outlier, self._counters['consecutive_rejected'],
                                          c.max_consecutive_rejections)
        if action == 'release':
            self._mix.release_rate()
            self._recovered()
        elif action == 'respread':
            self._respread(y, v_mix + R)
        self._mix.tidy()
        if action is not None:
            return UpdateResult('recovered', y, nis)
        return UpdateResult('rejected' if outlier else 'accepted', y, nis)

    def _score_trend(self, z, R_score, R, rho):
        """
        Score both models' predictions of ``z``, then add it to the growth trend.

        The predictions are those made :data:`.trend_score.SCORE_LAG` windows before, with the
        window's noise ``R_score`` (the noise scale's and the growth within the window
        included, no Student-t weight: the same for both models). ``R`` is the noise
        the growth law takes the window with (``rho`` and the Student-t weight in it);
        the law keeps ``R/rho`` and applies the latest ``rho`` to all its windows.
        """
        exposure = self._archard if self._observed_at is None else self._observed_at
        self._scoring.add(exposure, z, R_score, R, rho, self._model_predictive,
                          self.config.trend_probability)

    def _snapshot(self):
        """
        Return what a lagged prediction starts from.

        The wear model now, moment-matched (the mixture has collapsed to a few close
        components by the time windows are scored; one Gaussian keeps the state
        small); :meth:`.trend_score.TrendScore.after_window` adds where the growth law is.
        """
        x, P = self._mix.estimate()
        return {'archard': self._archard, 'exposure_s': self._exposure_s,
                'lw': np.zeros(1), 'm': x[None, :].copy(), 'P': P[None, :, :].copy()}

    def _model_predictive(self, snap):
        """
        Predictive mean of ``z`` under the wear model from ``snap`` (:meth:`_snapshot`).

        The snapshot (one moment-matched component) is predicted to the window's middle
        through the Archard increment and the operation since, with its process noise.

        Returns
        -------
        tuple of float
            The mean [rad] and the variance without the window's noise [rad²].

        """
        at = self._archard if self._observed_at is None else self._observed_at
        now = self._exposure_s if self._observed_exposure is None else self._observed_exposure
        return self._mix.predictive(snap['m'][0], snap['P'][0], at - snap['archard'],
                                    now - snap['exposure_s'])

    def _respread(self, y, s_mix):
        """
        Search the rate again over the prior's range after persistent disagreement.

        The wear's variance is raised so that the innovation ``y`` (of predicted
        variance ``s_mix``) is one sd (:func:`.recovery.respread`). The predictions
        made before (:meth:`_snapshot`) were of another reducer (a jump, a rate many
        times the model's): both models are scored again only on predictions made
        :data:`.trend_score.SCORE_AFTER` usable windows from here on.
        """
        # Nor are those it makes while the data choose the rate again (their wear was
        # 12-31 um on a unit at 0.5 after a respread on two noisy windows: the growth law
        # won the score by 13 nats on them, and the remaining life came out 40 % short).
        self._scoring.restart()
        self._mix.respread(y, s_mix)
        self._recovered()

    def _recovered(self):
        """Count a recovery; the disagreement starts over."""
        self._disagreement.clear()
        self._counters['recoveries'] += 1
        self._counters['consecutive_rejected'] = 0

    @property
    def _x(self):
        return self._mix.estimate()[0]

    @property
    def _Px(self):
        return self._mix.estimate()[1]

    def step(self, features):
        """
        Predict to the window's middle, update with it, predict to its end.

        Parameters
        ----------
        features : object
            WindowFeatures-like: ``t_end`` [s], ``duty``, ``lost_motion``
            [rad], ``lost_motion_std`` [rad], optionally ``wear_fit`` [m].

        Returns
        -------
        UpdateResult
            Outcome of the update.

        """
        duty = features.duty
        exposure = self._duty_value(duty, 'exposure_s', 's')
        increment = self._duty_value(duty, 'archard_increment', 'm')
        if not _finite(getattr(features, 'lost_motion', math.nan)):
            # Nothing to apply at the middle (no reversal in the window): one step.
            self._mix.predict(exposure, increment)
            result = self.update(features)
        else:
            self._mix.predict(0.5 * exposure, 0.5 * increment)
            self._observed_at = self._archard + 0.5 * increment
            self._observed_exposure = self._exposure_s + 0.5 * exposure
            self._window_increment = increment
            try:
                result = self.update(features)
            finally:
                self._observed_at = self._observed_exposure = None
                self._window_increment = 0.0
            self._mix.predict(0.5 * exposure, 0.5 * increment)
        self._count_duty(exposure, increment)
        self._scoring.after_window(_finite(getattr(features, 'lost_motion', math.nan)),
                                   self._snapshot)
        t_end = getattr(features, 't_end', None)
        if _finite(t_end):
            self._t_end = float(t_end)
        return result

    def reset(self, reason):
        """
        Return to the prior of a new reducer after a maintenance event.

        Counters and total exposure are kept; the event is logged.

        Parameters
        ----------
        reason : str
            What happened (e.g. ``'reducer replaced'``).

        Raises
        ------
        InvalidInput
            If ``reason`` is not a non-empty string.

        """
        if not isinstance(reason, str) or not reason.strip():
            raise InvalidInput(f'reset reason must be a non-empty string, got {reason!r}')
        self._mix = WearMixture(self.params, self.config, 1.0)
        self._scoring = TrendScore(1.0)
        self._service_pending = False
        self._service_verdict = None
        self._archard = 0.0
        self._noise = NoiseScale()
        self._disagreement.clear()
        self._exposure_since_reset_s = 0.0
        self._counters['consecutive_rejected'] = 0
        self._events.append({'exposure_s': self._exposure_s, 'reason': reason})

    # read-only views ------------------------------------------------------------------

    @property
    def x(self):
        """State mean ``[w [m], ln s, b [m]]`` of the mixture (copy)."""
        return self._x[:N_STATE].copy()

    @property
    def P(self):
        """State covariance of the mixture (copy)."""
        return self._Px[:N_STATE, :N_STATE].copy()

    @property
    def archard_exposure(self):
        """Archard exposure since the estimator started (or was reset) [m], ``Σ Δa``."""
        return self._archard

    @property
    def trend_probability(self):
        """
        Probability that the observed growth law, not the model's curve, holds.

        ``p0`` (``config.trend_probability``) moved by the prequential log-score
        difference of the two models. For a reducer used before the twin started
        the law counts its exposure from the start (:mod:`.growth`, two origins).
        """
        return self._scoring.probability(self.config.trend_probability)

    @property
    def forecast_scale(self):
        """
        Factor (>= 1) by which both models' predictions of the windows fell short.

        Of the predictions made :data:`.trend_score.SCORE_LAG` windows ahead
        (:meth:`.trend_score.TrendScore.forecast_scale`): above 1 where the lost motion
        grows by a law neither the model's curve nor the power law follows. The
        remaining life takes the variance of ``ln s`` times it
        (:meth:`.pipeline.EstimatorStage.record`).
        """
        return self._scoring.forecast_scale()

    def growth_trend(self):
        """
        Return the observed growth law now.

        The law is fitted to the windows' readings ``z``, which carry the window
        fit's bias ``c``; the unit's own lost motion is ``z - c``. Within the law
        ``c`` cannot be told from ``β`` (both are constant), so the windows never
        learn it: the law of the unit has ``β - c`` with ``c`` at its prior
        (``fit_bias_std``), as the wear model's ``h(w + b)`` has. Without it, a unit
        that followed the law was reported as sure of its lost motion as the
        windows' scatter allows, however biased the fit.

        Returns
        -------
        tuple
            ``(probability, mean, cov, exposure)``: :attr:`trend_probability`,
            the mean ``[β [rad], k [rad], g]`` of the unit's power law
            ``LM = β + k·(A/A_now)^g`` and its covariance, and ``A_now`` [m].

        """
        mean, cov = self._scoring.law.summary()
        cov[0, 0] += self.config.fit_bias_std ** 2
        return self.trend_probability, mean, cov, self._scoring.law.exposure

    @property
    def components(self):
        """Return the number of Gaussian components now."""
        return self._mix.size

    @property
    def wear(self):
        """Estimated combined wear since new [m]."""
        return float(self._x[0])

    @property
    def wear_std(self):
        """Return the standard deviation of the wear estimate [m]."""
        return math.sqrt(max(self._Px[0, 0], 0.0))

    @property
    def rate_scale(self):
        """Median of the rate scale, ``exp(E[ln s])``."""
        return math.exp(self._x[1])

    @property
    def rate_scale_std(self):
        """Return the standard deviation of the (log-normal) rate scale."""
        return lognormal_sd(self._x[1], self._Px[1, 1])

    @property
    def baseline(self):
        """Estimated as-built offset ``b`` [m]."""
        return float(self._x[2])

    @property
    def lost_motion_new(self):
        """Estimated lost motion of this unit when new, ``h(b)`` [rad]."""
        return float(self._mix.h(self._x[2]))

    def lost_motion(self, trend=None):
        """
        Return the estimated lost motion of the unit now and its sd [rad].

        The wear model's ``h(w + b)`` over the mixture, mixed with the observed
        growth law's ``β + k`` with the probability that the law holds
        (:attr:`trend_probability`).

        Parameters
        ----------
        trend : tuple, optional
            :meth:`growth_trend`, when asked for already (the same numbers).

        Returns
        -------
        tuple of float
            Mean and standard deviation.

        """
        mean, var = self._mix.lost_motion()
        p = self.trend_probability
        if p > 0.0:
            m, cov = self.growth_trend()[1:3] if trend is None else trend[1:3]
            t_mean, t_var = m[0] + m[1], cov[0, 0] + cov[1, 1] + 2.0 * cov[0, 1]
            mixed = p * t_mean + (1.0 - p) * mean
            var = p * (t_var + (t_mean - mixed) ** 2) + (1.0 - p) * (var + (mean - mixed) ** 2)
            mean = mixed
        return mean, math.sqrt(max(var, 0.0))

    @property
    def exposure_s(self):
        """Total operating seconds seen [s] (kept across resets)."""
        return self._exposure_s

    @property
    def exposure_since_reset_s(self):
        """Operating seconds of the current reducer [s]."""
        return self._exposure_since_reset_s

    @property
    def duty_rate(self):
        """Return the run-in-free Archard rate of the recent duty [m per operating second]."""
        return self._duty.rate

    @property
    def duty_rate_rel_std(self):
        """Relative standard error of the recent duty rate (:attr:`.DutyRate.rel_std`)."""
        return self._duty.rel_std

    @property
    def t_end(self):
        """Stream time of the last window stepped [s], or None."""
        return self._t_end

    @property
    def updates(self):
        """Count the measurement updates, outliers and recoveries included."""
        return self._counters['updates']

    @property
    def rejected(self):
        """Count the outliers (NIS above the gate; used with the Student-t weight)."""
        return self._counters['rejected']

    @property
    def counters(self):
        """Return a copy of all counters by name."""
        return dict(self._counters)

    @property
    def events(self):
        """Maintenance events, ``[{'exposure_s', 'reason'}]`` (copy)."""
        return [dict(e) for e in self._events]

    # persistence ----------------------------------------------------------------------

    def state_dict(self):
        """
        Return everything needed to continue exactly, as plain JSON-able data.

        See :func:`.estimator_state.estimator_state`.
        """
        from .estimator_state import estimator_state
        return estimator_state(self)

    @classmethod
    def from_state(cls, params, d, config=None):
        """
        Restore an estimator exactly from :meth:`state_dict` output.

        See :func:`.estimator_state.restore_estimator` (it raises
        :class:`~.errors.StateFileError` for a state of another kind, version or
        reducer, or a malformed one).
        """
        from .estimator_state import restore_estimator
        return restore_estimator(params, d, config)
