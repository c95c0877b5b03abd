"""
State estimator of combined wear and of the field/lab wear-rate mismatch.

progpy vocabulary: the *model* is the Archard rate of :mod:`.wear` (process)
and the lost-motion table of :mod:`.transmission_error` (observation); this
module is the *state estimator*; :mod:`.life` is the *predictor*.

State ``x = [w, θ]``: ``w`` the combined wear of disc and pins [m] (the two
cannot be separated from the signals, physics notes section 4) and
``θ = ln s`` with ``s`` the multiplier on the Archard rate (field data wear
about 10x slower than the paper's lab scenario, physics notes section 5).

Process model, one window ``k`` of encoder data (physics notes section 5)::

    w[k+1] = W(S(w[k]) + exp(θ[k])·Δa[k])        θ[k+1] = θ[k]

``Δa`` is ``duty.archard_increment``: ∫ wear_rate(T, ω, w=0) dt of the
observed torque/speed history, at rate scale 1 and without run-in. ``S`` is the
run-in-free wear ``S(w) = ∫ dw/g(w)`` with ``g = (Rrms(w)/Rrms0)^1.589``
(:func:`.wear._run_in_map`) and ``W`` its inverse, so the step is exact for
``dw = s·g(w)·da`` (to first order ``Δw = s·Δa·g(w)``). Both maps are extended
with slope 1 to ``w < 0`` (``g(0) = 1``), which keeps sigma points below zero
meaningful. Process noise ``Q = diag(q_w, q_θ)·Δe`` with ``Δe`` the operating
seconds of the window (idle windows add no uncertainty):

* ``q_w`` (default ``(0.2 µm)²`` per 1000 h): unmodelled wear, e.g. a
  contamination episode, that the Archard rate of the observed duty misses.
  Small, because systematic rate errors belong to ``s``.
* ``q_θ`` (default ``0.05²`` per 1000 h): slow drift of the mismatch
  (lubricant ageing, temperature). Over the 6000 h rated life the prior on
  ``θ`` widens by only 0.12, so the filter keeps a long memory of the rate
  but can follow a drift of a few per cent per 1000 h.

Observation: ``z = LM(w) + v``, ``v ~ N(0, R)``, ``LM`` the catalogue lost
motion at ±3 % of rated torque (``model_tables(params).lost_motion``),
``R = max(lost_motion_std, min_lost_motion_std)²``. The loaded mean-TE
offset is not used: it needs a per-unit baseline at a known torque, which the
features do not carry yet.

Why an unscented filter (Julier & Uhlmann 1997; scaled points of Wan & van
der Merwe 2000, ``α = 1, β = 2, κ = 3 - n``): the measurement is monotone but
curved most where the filter starts (``dLM/dw`` falls from 0.30 to 0.16
arcmin/µm over the first 4 µm) and ``exp(θ)`` with a prior sd of 0.7 has a
mean 28 % above ``exp(E[θ])``. An EKF drops both second-order terms and needs
the derivative of a piecewise-linear table; the UKF needs neither and costs
five table look-ups. The prediction is nearly linear given the observed
exposure, so the two filters agree late in life. ``α = 1`` keeps all weights
positive and the sigma points at ``±√3σ``, where a Gaussian's fourth moment
is matched.

Constraints: ``s > 0`` holds by construction (``θ`` is estimated). ``w >= 0``
is enforced by projecting the mean after each step (estimate projection,
Simon & Chia 2002), leaving ``P`` unchanged (conservative).

Outliers: the normalized innovation squared ``NIS = y²/S`` is tested against
``gate_nis`` (default 16, i.e. 4σ, false rejection 6e-5 per observation);
rejected updates are counted. After ``max_consecutive_rejections`` in a row
the estimate, not the data, is taken to be wrong: ``P`` is inflated so that the
innovation sits on the gate and the observation is used (counted as a
recovery), so the filter can never lock itself out.

The filter is filterpy's ``UnscentedKalmanFilter``, wrapped and not exposed.
Its state is fully ``(x, P)``: sigma points are redrawn before each update, so
a restored filter continues bit-identically.
"""

from dataclasses import asdict, dataclass, fields
import errno
from functools import lru_cache
import hashlib
import json
import math
import os
from pathlib import Path
import tempfile

import numpy as np

from .errors import InvalidInput, StateFileError
from .params import _Validated, spec
from .transmission_error import model_tables
from .units import ARCMIN, HOUR, UM
from .wear import _run_in_map, run_in_factor

STATE_KIND = 'reducer_twin.wear_estimator'
"""Value of ``kind`` in a state dict."""

STATE_VERSION = 1
"""Version of the state dict layout; bumped on any incompatible change."""

SIGMA_ALPHA, SIGMA_BETA, SIGMA_KAPPA = 1.0, 2.0, 1.0
"""Scaled sigma-point parameters (Wan & van der Merwe 2000) for ``n = 2``."""


@dataclass(frozen=True)
class EstimatorConfig(_Validated):
    """
    Tuning of the wear estimator (SI units; defaults explained in the module).

    The prior is a new reducer: ``w = 0`` with sd ``initial_wear_std`` (the
    as-built lost-motion scatter referred to wear) and ``ln s ~ N(ln s0, σ²)``.
    """

    _prefix = 'estimator'
    initial_wear: float = spec(0.0, 'm', 0.0, 1e-3, 'prior mean of the combined wear')
    initial_wear_std: float = spec(0.5 * UM, 'm', 0.0, 1e-3, 'prior sd of the combined wear',
                                   lo_open=True)
    initial_rate_scale: float = spec(1.0, '', 0.0, 1e3, 'prior median of the rate scale s',
                                     lo_open=True)
    initial_log_rate_scale_std: float = spec(0.7, '', 0.0, 5.0, 'prior sd of ln s',
                                             lo_open=True)
    wear_noise_density: float = spec((0.2 * UM) ** 2 / (1000.0 * HOUR), 'm^2/s', 0.0, 1e-12,
                                     'process noise q_w on w per operating second')
    log_rate_scale_noise_density: float = spec(0.05 ** 2 / (1000.0 * HOUR), '1/s', 0.0, 1e-3,
                                               'random walk q_theta on ln s per operating second')
    min_lost_motion_std: float = spec(0.02 * ARCMIN, 'rad', 0.0, 1e-2,
                                      'floor of the lost-motion sd used in R', lo_open=True)
    gate_nis: float = spec(16.0, '', 1.0, 1e6, 'NIS above which an update is rejected')
    max_consecutive_rejections: int = spec(10, '', 1, 10000,
                                           'rejections in a row before covariance inflation',
                                           integer=True)
    duty_horizon_s: float = spec(1000.0 * HOUR, 's', 0.0, 1e10,
                                 'operating-time constant of the recent duty rate', lo_open=True)


@dataclass(frozen=True)
class UpdateResult:
    """
    Outcome of one measurement update.

    Attributes
    ----------
    status : str
        ``'accepted'``, ``'rejected'`` (gated out), ``'recovered'``
        (accepted after covariance inflation) or ``'skipped'`` (NaN).
    innovation : float
        ``y = z - E[LM(w)]`` [rad] (NaN when skipped).
    nis : float
        Normalized innovation squared ``y²/S`` (NaN when skipped).

    """

    status: str
    innovation: float = math.nan
    nis: float = math.nan


# --------------------------------------------------------------------------- model


def run_in_free_wear(wear, wear_params):
    """
    Map wear to run-in-free wear, ``S(w) = ∫0^w dw'/g(w')`` [m].

    ``g = (Rrms(w)/Rrms0)^1.589`` (:mod:`.wear`, eq 7); tabulated by
    :func:`.wear._run_in_map`, extended with slope 1 below zero and with the
    last slope beyond the table.

    Parameters
    ----------
    wear : array_like
        Combined wear w [m].
    wear_params : Wear
        Wear parameters.

    Returns
    -------
    ndarray
        S(w) [m], strictly increasing.

    """
    grid_w, grid_s = _run_in_map(wear_params)
    w = np.asarray(wear, dtype=float)
    s = np.interp(w, grid_w, grid_s)
    s = np.where(w < 0.0, w, s)
    g_end = float(run_in_factor(grid_w[-1], wear_params)) ** wear_params.roughness_exponent
    return np.where(w > grid_w[-1], grid_s[-1] + (w - grid_w[-1]) / g_end, s)


def wear_from_run_in_free(free_wear, wear_params):
    """
    Invert :func:`run_in_free_wear`: ``W(S) = w`` [m].

    Parameters
    ----------
    free_wear : array_like
        Run-in-free wear S [m].
    wear_params : Wear
        Wear parameters.

    Returns
    -------
    ndarray
        Combined wear w [m].

    """
    grid_w, grid_s = _run_in_map(wear_params)
    s = np.asarray(free_wear, dtype=float)
    w = np.interp(s, grid_s, grid_w)
    w = np.where(s < 0.0, s, w)
    g_end = float(run_in_factor(grid_w[-1], wear_params)) ** wear_params.roughness_exponent
    return np.where(s > grid_s[-1], grid_w[-1] + (s - grid_s[-1]) * g_end, w)


class LostMotionCurve:
    """
    Lost motion at the catalogue test torque as a function of wear.

    The nodes of ``model_tables(params)`` (bilinear in the table, hence
    piecewise linear in ``w`` at fixed torque), evaluated with ``np.interp``
    and extended linearly beyond both ends so that sigma points outside the
    table still see a monotone model.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.

    """

    def __init__(self, params):
        tables = model_tables(params)
        self.wear = np.array(tables.wear, dtype=float)
        self.lost_motion = np.asarray(tables.lost_motion(self.wear), dtype=float)
        dw_new = self.wear[1] - self.wear[0]
        dw_end = self.wear[-1] - self.wear[-2]
        self.slope_new = (self.lost_motion[1] - self.lost_motion[0]) / dw_new
        self.slope_end = (self.lost_motion[-1] - self.lost_motion[-2]) / dw_end

    def __call__(self, wear):
        """
        Evaluate the lost motion [rad].

        Parameters
        ----------
        wear : array_like
            Combined wear [m].

        Returns
        -------
        ndarray
            Lost motion [rad].

        """
        w = np.asarray(wear, dtype=float)
        lm = np.interp(w, self.wear, self.lost_motion)
        return (lm + self.slope_new * np.minimum(w - self.wear[0], 0.0)
                + self.slope_end * np.maximum(w - self.wear[-1], 0.0))


@lru_cache(maxsize=16)
def lost_motion_curve(params):
    """
    Return the cached :class:`LostMotionCurve` of a parameter set.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    LostMotionCurve
        Observation model ``h(w)``.

    """
    return LostMotionCurve(params)


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


def prior(config):
    """
    Return the new-reducer prior ``(x0, P0)``.

    Parameters
    ----------
    config : EstimatorConfig
        Estimator tuning.

    Returns
    -------
    tuple of ndarray
        ``x0 = [w0, ln s0]`` ([m], [-]) and diagonal ``P0``.

    """
    x0 = np.array([config.initial_wear, math.log(config.initial_rate_scale)])
    P0 = np.diag([config.initial_wear_std ** 2, config.initial_log_rate_scale_std ** 2])
    return x0, P0


def process_noise(exposure_s, config):
    """
    Return ``Q = diag(q_w, q_θ)·Δe`` for one window.

    Parameters
    ----------
    exposure_s : float
        Operating seconds of the window Δe [s].
    config : EstimatorConfig
        Estimator tuning.

    Returns
    -------
    ndarray, shape (2, 2)
        Q ([m²], [-]).

    """
    return np.diag([config.wear_noise_density * exposure_s,
                    config.log_rate_scale_noise_density * exposure_s])


def _finite(value):
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


# --------------------------------------------------------------------------- filter


class WearEstimator:
    """
    Unscented Kalman filter on ``x = [w, ln s]`` (see the module docstring).

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters (process and observation model).
    config : EstimatorConfig, optional
        Tuning; defaults if omitted.

    """

    def __init__(self, params, config=None):
        # Imported here: filterpy pulls in scipy.stats (~1 s), which life.py does not need.
        from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter
        self.params = params
        self.config = config or EstimatorConfig()
        self._h = lost_motion_curve(params)
        points = MerweScaledSigmaPoints(2, alpha=SIGMA_ALPHA, beta=SIGMA_BETA, kappa=SIGMA_KAPPA)
        self._ukf = UnscentedKalmanFilter(dim_x=2, dim_z=1, dt=1.0, hx=self._hx, fx=self._fx,
                                          points=points)
        self._ukf.x, self._ukf.P = prior(self.config)
        self._exposure_s = 0.0
        self._exposure_since_reset_s = 0.0
        self._duty_increment = 0.0
        self._duty_exposure = 0.0
        self._t_end = None
        self._counters = {'predictions': 0, 'updates': 0, 'rejected': 0, 'skipped': 0,
                          'recoveries': 0, 'consecutive_rejected': 0}
        self._events = []

    # model functions handed to filterpy -------------------------------------------------

    def _fx(self, x, dt, increment=0.0):
        """Propagate one sigma point: ``w' = W(S(w) + e^θ·Δa)``, ``θ' = θ``."""
        wp = self.params.wear
        free = run_in_free_wear(x[0], wp) + math.exp(x[1]) * increment
        return np.array([float(wear_from_run_in_free(free, wp)), x[1]])

    def _hx(self, x):
        """Observe one sigma point: ``z = LM(w)``."""
        return np.array([float(self._h(x[0]))])

    # filter steps -----------------------------------------------------------------------

    def predict(self, duty):
        """
        Propagate the state over one window of operation.

        Parameters
        ----------
        duty : object
            With ``exposure_s`` [s] (operating seconds) and
            ``archard_increment`` [m] (run-in-free Archard wear at rate
            scale 1), both finite and >= 0.

        Raises
        ------
        InvalidInput
            If either value is missing, not finite or negative.

        """
        exposure = self._duty_value(duty, 'exposure_s', 's')
        increment = self._duty_value(duty, 'archard_increment', 'm')
        self._counters['predictions'] += 1
        self._exposure_s += exposure
        self._exposure_since_reset_s += exposure
        decay = math.exp(-exposure / self.config.duty_horizon_s)
        self._duty_increment = decay * self._duty_increment + increment
        self._duty_exposure = decay * self._duty_exposure + exposure
        if exposure == 0.0 and increment == 0.0:
            return
        self._ukf.Q = process_noise(exposure, self.config)
        self._ukf.predict(dt=exposure, increment=increment)
        self._finish()

    @staticmethod
    def _duty_value(duty, name, unit):
        value = getattr(duty, name, None)
        if not _finite(value) or float(value) < 0.0:
            raise InvalidInput(f'duty.{name} must be a finite number >= 0 {unit}, got {value!r}')
        return float(value)

    def update(self, features):
        """
        Correct the state with the lost motion observed in one window.

        Parameters
        ----------
        features : object
            With ``lost_motion`` [rad] and ``lost_motion_std`` [rad]; a
            non-finite value (no reversal in the window) skips the update.

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
        R = max(std, self.config.min_lost_motion_std) ** 2
        ukf = self._ukf
        x0, P0 = ukf.x.copy(), ukf.P.copy()
        y, nis = self._correct(z, R)
        if nis <= self.config.gate_nis:
            self._counters['updates'] += 1
            self._counters['consecutive_rejected'] = 0
            return UpdateResult('accepted', y, nis)
        ukf.x, ukf.P = x0, P0
        self._counters['rejected'] += 1
        self._counters['consecutive_rejected'] += 1
        if self._counters['consecutive_rejected'] < self.config.max_consecutive_rejections:
            return UpdateResult('rejected', y, nis)
        # The estimate, not the data, is wrong: inflate P until y sits on the gate.
        s_pred = ukf.S[0, 0] - R
        factor = (y * y / self.config.gate_nis - R) / s_pred if s_pred > 0.0 else 1.0
        ukf.P = P0 * max(factor, 1.0)
        y, nis = self._correct(z, R)
        self._counters['recoveries'] += 1
        self._counters['updates'] += 1
        self._counters['consecutive_rejected'] = 0
        return UpdateResult('recovered', y, nis)

    def _correct(self, z, R):
        """Run filterpy's update from freshly drawn sigma points; return ``(y, NIS)``."""
        ukf = self._ukf
        ukf.sigmas_f = ukf.points_fn.sigma_points(ukf.x, ukf.P)
        ukf.update(np.array([z]), R=np.array([[R]]))
        y = float(ukf.y[0])
        nis = y * y / float(ukf.S[0, 0])
        self._finish()
        return y, nis

    def _finish(self):
        """Symmetrize P and project the mean onto ``w >= 0``."""
        ukf = self._ukf
        ukf.P = 0.5 * (ukf.P + ukf.P.T)
        if ukf.x[0] < 0.0:
            ukf.x = np.array([0.0, ukf.x[1]])

    def step(self, features):
        """
        Predict over the window of ``features.duty``, then update with it.

        Parameters
        ----------
        features : object
            WindowFeatures-like: ``t_end`` [s], ``duty``, ``lost_motion``
            [rad], ``lost_motion_std`` [rad].

        Returns
        -------
        UpdateResult
            Outcome of the update.

        """
        self.predict(features.duty)
        result = self.update(features)
        t_end = getattr(features, 't_end', None)
        if _finite(t_end):
            self._t_end = float(t_end)
        return result

    def reset(self, reason):
        """
        Return to the new-reducer prior after a maintenance event.

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
        self._ukf.x, self._ukf.P = prior(self.config)
        self._exposure_since_reset_s = 0.0
        self._counters['consecutive_rejected'] = 0
        self._events.append({'exposure_s': self._exposure_s, 'reason': reason})

    # read-only views ------------------------------------------------------------------

    @property
    def x(self):
        """State mean ``[w [m], ln s]`` (copy)."""
        return self._ukf.x.copy()

    @property
    def P(self):
        """State covariance (copy)."""
        return self._ukf.P.copy()

    @property
    def wear(self):
        """Estimated combined wear [m]."""
        return float(self._ukf.x[0])

    @property
    def wear_std(self):
        """Return the standard deviation of the wear estimate [m]."""
        return math.sqrt(self._ukf.P[0, 0])

    @property
    def rate_scale(self):
        """Median of the rate scale, ``exp(E[ln s])``."""
        return math.exp(self._ukf.x[1])

    @property
    def rate_scale_std(self):
        """Return the standard deviation of the (log-normal) rate scale."""
        mu, var = self._ukf.x[1], self._ukf.P[1, 1]
        return math.sqrt(math.expm1(var) * math.exp(2.0 * mu + var))

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
        """
        Run-in-free Archard rate of the recent duty [m per operating second].

        Ratio of exponentially weighted sums of ``Δa`` and ``Δe``, time
        constant ``duty_horizon_s`` of operation; 0 before any exposure.
        """
        if self._duty_exposure <= 0.0:
            return 0.0
        return self._duty_increment / self._duty_exposure

    @property
    def t_end(self):
        """Stream time of the last window stepped [s], or None."""
        return self._t_end

    @property
    def updates(self):
        """Count the accepted measurement updates, recoveries included."""
        return self._counters['updates']

    @property
    def rejected(self):
        """Count the measurement updates rejected by the gate."""
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

        Returns
        -------
        dict
            ``kind``, ``version``, ``params_sha256``, ``config``, ``x``, ``P``,
            exposures, duty sums, ``t_end``, ``counters``, ``events``.

        """
        return {
            'kind': STATE_KIND,
            'version': STATE_VERSION,
            'params_sha256': params_fingerprint(self.params),
            'config': asdict(self.config),
            'x': [float(v) for v in self._ukf.x],
            'P': [[float(v) for v in row] for row in self._ukf.P],
            'exposure_s': self._exposure_s,
            'exposure_since_reset_s': self._exposure_since_reset_s,
            'duty_increment': self._duty_increment,
            'duty_exposure': self._duty_exposure,
            't_end': self._t_end,
            'counters': dict(self._counters),
            'events': [dict(e) for e in self._events],
        }

    @classmethod
    def from_state(cls, params, d, config=None):
        """
        Restore an estimator exactly from :meth:`state_dict` output.

        Parameters
        ----------
        params : ReducerParams
            Parameters of the reducer; must be those the state was made with.
        d : mapping
            A state dict.
        config : EstimatorConfig, optional
            Tuning; by default the one stored in the state.

        Returns
        -------
        WearEstimator
            The restored estimator.

        Raises
        ------
        StateFileError
            If the state is of another kind or version, belongs to other
            reducer parameters or is malformed.

        """
        if not isinstance(d, dict) or d.get('kind') != STATE_KIND:
            kind = d.get('kind') if isinstance(d, dict) else type(d).__name__
            raise StateFileError(f'state kind must be {STATE_KIND!r}, got {kind!r}')
        if d.get('version') != STATE_VERSION:
            raise StateFileError(
                f'state version must be {STATE_VERSION}, got {d.get("version")!r}')
        expected = params_fingerprint(params)
        if d.get('params_sha256') != expected:
            raise StateFileError(
                'state belongs to other reducer parameters: params_sha256 must be '
                f'{expected}, got {d.get("params_sha256")!r}')
        try:
            if config is None:
                names = {f.name for f in fields(EstimatorConfig)}
                config = EstimatorConfig(**{k: v for k, v in d['config'].items() if k in names})
            est = cls(params, config)
            x = np.array(d['x'], dtype=float)
            P = np.array(d['P'], dtype=float)
            if x.shape != (2,) or P.shape != (2, 2):
                raise ValueError(f'x must have shape (2,) and P (2, 2), got {x.shape}, {P.shape}')
            if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P))):
                raise ValueError('x and P must be finite')
            counters = {k: int(d['counters'][k]) for k in est._counters}
            events = [{'exposure_s': float(e['exposure_s']), 'reason': str(e['reason'])}
                      for e in d['events']]
            names = ('exposure_s', 'exposure_since_reset_s', 'duty_increment', 'duty_exposure')
            scalars = {k: float(d[k]) for k in names}
            t_end = None if d['t_end'] is None else float(d['t_end'])
        except (KeyError, TypeError, ValueError, AttributeError) as err:
            raise StateFileError(f'state is malformed: {type(err).__name__}: {err}') from err
        est._ukf.x, est._ukf.P = x, P
        est._exposure_s = scalars['exposure_s']
        est._exposure_since_reset_s = scalars['exposure_since_reset_s']
        est._duty_increment = scalars['duty_increment']
        est._duty_exposure = scalars['duty_exposure']
        est._t_end = t_end
        est._counters = counters
        est._events = events
        return est

    def save(self, path):
        """
        Write the state atomically, keeping the previous good file as ``<path>.bak``.

        The file holds ``{'format', 'sha256', 'state'}`` with the sha256 of
        the canonical JSON of the state. It is written to a temporary file in
        the same directory, fsynced and moved over ``path`` with
        ``os.replace``; a crash leaves either the old or the new file.

        Parameters
        ----------
        path : str or Path
            Destination file.

        Raises
        ------
        StateFileError
            If the file cannot be written.

        """
        write_state_file(path, encode_state(self.state_dict()))

    @classmethod
    def load(cls, path, params, config=None):
        """
        Read a state file written by :meth:`save` and restore the estimator.

        Parameters
        ----------
        path : str or Path
            State file.
        params : ReducerParams
            Parameters of the reducer.
        config : EstimatorConfig, optional
            Tuning; by default the one stored in the state.

        Returns
        -------
        WearEstimator
            The restored estimator.

        Raises
        ------
        StateFileError
            If the file is missing, truncated, corrupt (checksum), of another
            version or of another reducer.

        """
        path = Path(path)
        try:
            data = path.read_bytes()
        except OSError as err:
            raise StateFileError(f'cannot read estimator state {path}: {err}') from err
        state = decode_state(data, path)
        try:
            return cls.from_state(params, state, config)
        except StateFileError as err:
            raise StateFileError(f'{path}: {err}') from err


@dataclass(frozen=True)
class LoadedState:
    """
    Result of :func:`load_with_fallback`.

    Attributes
    ----------
    estimator : WearEstimator
        The restored estimator.
    path : Path
        The file actually used.
    used_backup : bool
        True when the primary file failed and ``<path>.bak`` was used.
    primary_error : str or None
        Why the primary file was not used.

    """

    estimator: WearEstimator
    path: Path
    used_backup: bool
    primary_error: str = None


def backup_path(path):
    """
    Return the backup file of a state file, ``<path>.bak``.

    Parameters
    ----------
    path : str or Path
        State file.

    Returns
    -------
    Path
        Backup file.

    """
    path = Path(path)
    return path.with_name(path.name + '.bak')


def load_with_fallback(path, params, config=None):
    """
    Load a state file, falling back to ``<path>.bak`` if the primary fails.

    Never starts from zeros silently: if neither file is usable the error
    names both reasons, and the caller decides whether to start afresh.

    Parameters
    ----------
    path : str or Path
        Primary state file.
    params : ReducerParams
        Parameters of the reducer.
    config : EstimatorConfig, optional
        Tuning; by default the one stored in the state.

    Returns
    -------
    LoadedState
        The estimator and which file it came from.

    Raises
    ------
    StateFileError
        If neither the primary nor the backup file can be used.

    """
    path = Path(path)
    try:
        return LoadedState(WearEstimator.load(path, params, config), path, False, None)
    except StateFileError as primary:
        backup = backup_path(path)
        try:
            est = WearEstimator.load(backup, params, config)
        except StateFileError as secondary:
            raise StateFileError(
                f'no usable estimator state: {primary}; backup: {secondary}') from primary
        return LoadedState(est, backup, True, str(primary))


def canonical_json(state):
    """
    Serialize a state dict canonically (sorted keys, no spaces, no NaN).

    Parameters
    ----------
    state : dict
        A state dict.

    Returns
    -------
    str
        JSON text; floats are written with ``repr`` and read back exactly.

    """
    return json.dumps(state, sort_keys=True, separators=(',', ':'), allow_nan=False)


def encode_state(state):
    """
    Wrap a state dict with its checksum as the bytes of a state file.

    Parameters
    ----------
    state : dict
        A state dict.

    Returns
    -------
    bytes
        UTF-8 JSON ``{'format', 'sha256', 'state'}``.

    """
    body = canonical_json(state)
    digest = hashlib.sha256(body.encode('utf-8')).hexdigest()
    # One key a line, the state as its canonical text: json's indenting encoder is the pure
    # Python one, which leaves reference cycles behind on every call (an estimator writes
    # its file after every window) and costs several times the C encoder's time.
    text = (f'{{\n "format": {json.dumps(STATE_KIND + ".file")},\n "sha256": "{digest}",\n'
            f' "state": {body}\n}}\n')
    return text.encode('utf-8')


def decode_state(data, path='<bytes>'):
    """
    Check a state file's format and checksum and return its state dict.

    Parameters
    ----------
    data : bytes
        File content.
    path : str or Path
        File name, for messages.

    Returns
    -------
    dict
        The state dict.

    Raises
    ------
    StateFileError
        If the content is not JSON, not a state file or fails its checksum.

    """
    try:
        wrapper = json.loads(data.decode('utf-8'))
    except (UnicodeDecodeError, ValueError) as err:
        raise StateFileError(
            f'{path} is not valid JSON (truncated or corrupt?): {err}') from err
    if not isinstance(wrapper, dict) or wrapper.get('format') != STATE_KIND + '.file':
        found = wrapper.get('format') if isinstance(wrapper, dict) else type(wrapper).__name__
        raise StateFileError(
            f'{path}: format must be {STATE_KIND + ".file"!r}, got {found!r}')
    state = wrapper.get('state')
    try:
        digest = hashlib.sha256(canonical_json(state).encode('utf-8')).hexdigest()
    except (TypeError, ValueError) as err:
        raise StateFileError(f'{path}: state cannot be serialized: {err}') from err
    if digest != wrapper.get('sha256'):
        raise StateFileError(
            f'{path}: checksum mismatch, sha256 of the state must be '
            f'{wrapper.get("sha256")!r}, got {digest!r} (file corrupt or edited)')
    return state


def write_state_file(path, data):
    """
    Write encoded state bytes atomically, keeping the previous good file as ``.bak``.

    Parameters
    ----------
    path : str or Path
        Destination file.
    data : bytes
        Output of :func:`encode_state`.

    Raises
    ------
    StateFileError
        If the file cannot be written.

    """
    path = Path(path)
    backup = backup_path(path)
    try:
        if path.exists():
            previous = path.read_bytes()
            try:
                decode_state(previous, path)
            except StateFileError:
                pass  # never replace a good backup by a corrupt primary
            else:
                _atomic_write(backup, previous)
        _atomic_write(path, data)
    except OSError as err:
        if err.errno in (errno.ENOSPC, errno.EDQUOT):
            try:
                stats = os.statvfs(path.parent)
                free = f', {stats.f_bavail * stats.f_frsize:,} free'
            except OSError:
                free = ''
            raise StateFileError(
                f'{"disk quota exceeded" if err.errno == errno.EDQUOT else "no space left"} '
                f'writing the estimator state {path}: {len(data):,} bytes needed{free}; the '
                'previous state file is kept') from err
        raise StateFileError(f'cannot write estimator state to {path}: {err}') from err


def _atomic_write(path, data):
    """Write bytes to ``path`` through a fsynced temporary file and ``os.replace``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', suffix='.tmp', dir=path.parent)
    try:
        with os.fdopen(fd, 'wb') as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    try:
        dir_fd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dir_fd)
    except OSError:
        pass
    finally:
        os.close(dir_fd)
