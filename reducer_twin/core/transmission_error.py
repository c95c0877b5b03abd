"""
Transmission error of the whole reducer as a function of angle, torque and wear.

``TE = theta_out - theta_in/i`` [rad]. Three parts add up:

* the loaded cycloid mesh: the discs turn back by ``beta(psi, T, w)`` until
  the pin contacts carry the torque (:mod:`.contact`); wear enters as extra
  normal clearance, so a normal clearance ``e_n`` at the governing contact
  maps to ``xi = e_n/l_eff`` of output rotation. This replaces the printed
  eqs 12-15, which divide a length by a ratio (physics notes section 2);
* a series compliance (bearings, shafts, first stage) chosen so the whole
  reducer has the catalogue torsional rigidity; it adds ``-T/k_s``, no ripple;
* manufacturing-error harmonics at 1x, 2x and Zp x the output frequency,
  which dominate the measured TE of real reducers (physics notes section 4).

Lost motion follows the catalogue definition: the play of the mesh between
plus and minus 3 % of rated torque, ``2·mean(beta(T3))``; the linear elastic
windup of the series compliance has no play and is not part of it.
"""

from functools import lru_cache

import numpy as np

from .contact import _engagement_rotation
from .geometry import flank_phases, lever_arms_cs, normal_clearance_cs
from .kinematics import eccentric_angle, effective_lever_radius, total_ratio
from .table_store import digest, stored_table

_PHASE_SAMPLES = 48
_CHUNK = 2048


def mesh_rotation(psi, torque, wear, params):
    """
    Output rotation taken up by the loaded mesh, signed like the torque.

    Same model as :func:`.contact.solve_mesh` without the force bookkeeping.

    Parameters
    ----------
    psi : array_like, shape (N,)
        Eccentric angle [rad].
    torque : float or array_like
        Output torque [N·m].
    wear : float or array_like
        Combined wear [m].
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    ndarray, shape (N,)
        beta [rad].

    """
    g = params.geometry
    psi = np.atleast_1d(np.asarray(psi, dtype=float))
    n = psi.shape[0]
    torque = np.broadcast_to(np.asarray(torque, dtype=float), (n,))
    wear = np.broadcast_to(np.asarray(wear, dtype=float), (n,))
    sign = np.where(torque < 0.0, -1.0, 1.0)
    beta = np.empty(n)
    k_n = params.rating.contact_stiffness
    # Chunks that stay in cache: about twice as fast as one large array.
    for lo in range(0, n, _CHUNK):
        sl = slice(lo, lo + _CHUNK)
        _, cos_phi, sin_phi = flank_phases(psi[sl] * sign[sl], g)
        lever = np.where(sin_phi > 0.0, lever_arms_cs(cos_phi, sin_phi, g), 0.0)
        clear = normal_clearance_cs(cos_phi, g, wear[sl, None])
        beta[sl] = _engagement_rotation(lever, clear, np.abs(torque[sl]) / k_n)
    return beta * sign


def _phase_grid(geometry):
    """Eccentric angles spanning one mesh period (the mesh repeats every 2·pi/Zp)."""
    return np.linspace(0.0, 2.0 * np.pi / geometry.z_pins, _PHASE_SAMPLES, endpoint=False)


def mean_mesh_rotation(torque, wear, params):
    """
    Mesh rotation averaged over one mesh period.

    Parameters
    ----------
    torque : float
        Output torque [N·m].
    wear : float
        Combined wear [m].
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    float
        Mean beta [rad].

    """
    return float(mesh_rotation(_phase_grid(params.geometry), torque, wear, params).mean())


@lru_cache(maxsize=64)
def series_stiffness(geometry, rating):
    """
    Stiffness in series with the mesh that gives the catalogue rigidity.

    The whole reducer's secant rigidity between 50 % and 100 % of rated
    torque, ``0.5·T0/(theta(T0) - theta(T0/2))``, equals the catalogue
    ``torsional_rigidity`` when ``1/k_s = 1/k_cat - Δbeta/(0.5·T0)``.

    Parameters
    ----------
    geometry : Geometry
        Reducer geometry (new, unworn).
    rating : Rating
        Ratings (rated torque, rigidity, contact stiffness).

    Returns
    -------
    float
        k_s [N·m/rad]; ``inf`` if the mesh alone is already as soft.

    """
    from .params import ReducerParams
    params = ReducerParams(geometry=geometry, rating=rating)
    t0 = rating.rated_torque
    d_beta = mean_mesh_rotation(t0, 0.0, params) - mean_mesh_rotation(0.5 * t0, 0.0, params)
    compliance = 0.5 * t0 / rating.torsional_rigidity - d_beta
    return 0.5 * t0 / compliance if compliance > 0.0 else float('inf')


def manufacturing_te(output_angle, params):
    """
    TE of the manufacturing-error harmonics [rad].

    Parameters
    ----------
    output_angle : array_like
        Output angle [rad].
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    ndarray
        TE contribution [rad], zero mean over a revolution.

    """
    m = params.manufacturing
    z = params.geometry.z_pins
    th = np.asarray(output_angle, dtype=float)
    return (m.order1_amplitude * np.sin(th + m.order1_phase)
            + m.order2_amplitude * np.sin(2.0 * th + m.order2_phase)
            + m.crank_amplitude * np.sin(z * th + m.crank_phase))


def transmission_error(input_angle, torque, wear, params, manufacturing=True):
    """
    Transmission error ``theta_out - theta_in/i`` of the whole reducer [rad].

    Parameters
    ----------
    input_angle : array_like, shape (N,)
        Input (motor) angle [rad].
    torque : float or array_like
        Output torque transmitted [N·m]; positive drives the output forward
        (the output lags, TE < 0).
    wear : float or array_like
        Combined wear [m].
    params : ReducerParams
        Reducer parameters.
    manufacturing : bool
        Include the manufacturing-error harmonics.

    Returns
    -------
    ndarray, shape (N,)
        TE [rad].

    """
    g = params.geometry
    out_nominal = np.atleast_1d(np.asarray(input_angle, dtype=float)) / total_ratio(g)
    torque = np.broadcast_to(np.asarray(torque, dtype=float), out_nominal.shape)
    beta = mesh_rotation(eccentric_angle(out_nominal, g), torque, wear, params)
    te = -(beta + torque / series_stiffness(g, params.rating))
    if manufacturing:
        te = te + manufacturing_te(out_nominal, params)
    return te


def lost_motion(wear, params, torque=None):
    """
    Lost motion: mesh play between plus and minus the test torque [rad].

    Parameters
    ----------
    wear : float or array_like
        Combined wear [m].
    params : ReducerParams
        Reducer parameters.
    torque : float, optional
        Test torque [N·m]; default 3 % of rated torque (catalogue).

    Returns
    -------
    float or ndarray
        Lost motion [rad]; tends to slope ``2/r_eff`` per metre of wear.

    """
    if torque is None:
        torque = params.rating.lost_motion_torque_fraction * params.rating.rated_torque
    w = np.asarray(wear, dtype=float)
    grid = _phase_grid(params.geometry)
    flat = w.ravel()
    psi = np.tile(grid, flat.size)
    beta = mesh_rotation(psi, abs(torque), np.repeat(flat, grid.size), params)
    lm = 2.0 * beta.reshape(flat.size, grid.size).mean(axis=1)
    return float(lm[0]) if w.ndim == 0 else lm.reshape(w.shape)


def hysteresis(wear, torque, params):
    """
    Width of the TE hysteresis at ``±|torque|`` as encoders see it [rad].

    ``TE(-|T|) - TE(+|T|) = 2·(mean beta(|T|) + |T|/k_s)``: lost motion at
    that torque plus the elastic windup. This is the observation model of the
    wear estimator.

    Parameters
    ----------
    wear : float or array_like
        Combined wear [m].
    torque : float
        Torque magnitude at which forward and reverse are compared [N·m].
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    float or ndarray
        Hysteresis width [rad].

    """
    k_s = series_stiffness(params.geometry, params.rating)
    return lost_motion(wear, params, torque=abs(torque)) + 2.0 * abs(torque) / k_s


def mean_te(wear, torque, params):
    """
    Compute the loaded mean TE over a mesh period, without manufacturing errors.

    Parameters
    ----------
    wear : float
        Combined wear [m].
    torque : float
        Output torque [N·m].
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    float
        Mean TE [rad].

    """
    k_s = series_stiffness(params.geometry, params.rating)
    return -(mean_mesh_rotation(torque, wear, params) + torque / k_s)


def mesh_te_ripple(wear, torque, params, samples=256):
    """
    Compute the peak-to-peak TE of the loaded mesh over one mesh period [rad].

    Parameters
    ----------
    wear : float
        Combined wear [m].
    torque : float
        Output torque [N·m].
    params : ReducerParams
        Reducer parameters.
    samples : int
        Eccentric angles per mesh period.

    Returns
    -------
    float
        Peak-to-peak ripple [rad] (sub-arcsecond: not a wear indicator).

    """
    psi = np.linspace(0.0, 2.0 * np.pi / params.geometry.z_pins, samples, endpoint=False)
    beta = mesh_rotation(psi, torque, wear, params)
    return float(beta.max() - beta.min())


def wear_to_te(clearance, lever=None, geometry=None):
    """
    Consistent replacement of eqs 12-14: normal clearance to output rotation.

    ``xi = e_n/l_eff`` [rad]; with no lever given, the longest lever arm
    ``r_eff`` (the contact that engages first at large wear) is used.

    Parameters
    ----------
    clearance : array_like
        Normal clearance e_n at the contact [m] (flank wear plus pin radius
        loss; eq 13's ``2h`` is a diametral change).
    lever : array_like, optional
        Lever arm of that contact [m].
    geometry : Geometry, optional
        Needed when ``lever`` is omitted.

    Returns
    -------
    ndarray
        Output rotation [rad].

    """
    if lever is None:
        lever = effective_lever_radius(geometry)
    return np.asarray(clearance, dtype=float) / lever


class ModelTables:
    """
    Tabulated mean mesh rotation for fast observation models.

    ``beta_mean(|T|, w)`` on a grid (mesh ripple is below 0.3 arcsec, so
    the period mean is what windows of encoder data see), interpolated
    bilinearly. Built once per parameter set (:func:`model_tables`).

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.
    max_wear : float
        Largest tabulated wear [m].
    max_torque : float, optional
        Largest tabulated torque [N·m] (default 3 x rated).

    """

    def __init__(self, params, max_wear=150e-6, max_torque=None):
        self.params = params
        t0 = params.rating.rated_torque
        max_torque = 3.0 * t0 if max_torque is None else max_torque
        # Dense where the contacts engage one after another: low torque, low wear.
        self.torque = np.unique(np.concatenate([
            np.geomspace(1e-3 * t0, 0.02 * t0, 40), np.linspace(0.0, 0.1 * t0, 121),
            np.linspace(0.1 * t0, max_torque, 60)]))
        self.wear = np.unique(np.concatenate([
            np.linspace(0.0, 6e-6, 61), np.linspace(6e-6, max_wear, int(round(
                (max_wear - 6e-6) / 1e-6)) + 1)]))
        self.beta = _cached_table(params, self.torque, self.wear)
        self.series_stiffness = series_stiffness(params.geometry, params.rating)
        self.lm_torque = params.rating.lost_motion_torque_fraction * t0

    def beta_mean(self, torque_abs, wear):
        """
        Interpolate the mean mesh rotation at ``|T|`` and ``w`` [rad].

        Parameters
        ----------
        torque_abs : array_like
            Torque magnitude [N·m], clipped to the table.
        wear : array_like
            Combined wear [m], clipped to the table.

        Returns
        -------
        ndarray
            Mean beta [rad].

        """
        t = np.clip(np.asarray(torque_abs, dtype=float), self.torque[0], self.torque[-1])
        w = np.clip(np.asarray(wear, dtype=float), self.wear[0], self.wear[-1])
        i = np.clip(np.searchsorted(self.torque, t, side='right') - 1, 0, self.torque.size - 2)
        j = np.clip(np.searchsorted(self.wear, w, side='right') - 1, 0, self.wear.size - 2)
        ft = (t - self.torque[i]) / (self.torque[i + 1] - self.torque[i])
        fw = (w - self.wear[j]) / (self.wear[j + 1] - self.wear[j])
        b = self.beta
        return ((1 - ft) * (1 - fw) * b[i, j] + ft * (1 - fw) * b[i + 1, j]
                + (1 - ft) * fw * b[i, j + 1] + ft * fw * b[i + 1, j + 1])

    def mean_te(self, torque, wear):
        """
        Period-mean TE without manufacturing errors, ``-(beta + T/k_s)`` [rad].

        Parameters
        ----------
        torque : array_like
            Signed output torque [N·m].
        wear : array_like
            Combined wear [m].

        Returns
        -------
        ndarray
            Mean TE [rad].

        """
        torque = np.asarray(torque, dtype=float)
        sign = np.where(torque < 0.0, -1.0, 1.0)
        return -(sign * self.beta_mean(np.abs(torque), wear) + torque / self.series_stiffness)

    def hysteresis(self, torque_abs, wear):
        """
        Hysteresis width ``TE(-|T|) - TE(+|T|)`` [rad] (see :func:`hysteresis`).

        Parameters
        ----------
        torque_abs : array_like
            Torque magnitude [N·m].
        wear : array_like
            Combined wear [m].

        Returns
        -------
        ndarray
            Width [rad].

        """
        torque_abs = np.abs(np.asarray(torque_abs, dtype=float))
        return 2.0 * (self.beta_mean(torque_abs, wear) + torque_abs / self.series_stiffness)

    def lost_motion(self, wear):
        """
        Lost motion at the catalogue test torque [rad] (see :func:`lost_motion`).

        Parameters
        ----------
        wear : array_like
            Combined wear [m].

        Returns
        -------
        ndarray
            Lost motion [rad].

        """
        return 2.0 * self.beta_mean(self.lm_torque, wear)

    def wear_for_lost_motion(self, lost_motion_rad):
        """
        Invert :meth:`lost_motion`: the wear at which lost motion is reached [m].

        Parameters
        ----------
        lost_motion_rad : array_like
            Lost motion [rad].

        Returns
        -------
        ndarray
            Wear [m]; clipped to the table range.

        """
        lm = self.lost_motion(self.wear)
        return np.interp(lost_motion_rad, lm, self.wear)


def table_key(params, torque, wear):
    """
    Return the key of a rotation table: a digest of everything it depends on.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.
    torque, wear : ndarray
        Grid nodes [N·m], [m].

    Returns
    -------
    str
        24 hexadecimal digits.

    """
    return digest(params, _PHASE_SAMPLES, torque.tobytes(), wear.tobytes(), TABLE_VERSION)


def _cached_table(params, torque, wear):
    """
    Compute the period-mean rotation on a grid, or take it from the table store.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters.
    torque, wear : ndarray
        Grid nodes [N·m], [m].

    Returns
    -------
    ndarray, shape (len(torque), len(wear))
        Mean beta [rad].

    """
    def build():
        grid = _phase_grid(params.geometry)
        tt, ww = np.meshgrid(torque, wear, indexing='ij')
        psi = np.tile(grid, tt.size)
        beta = mesh_rotation(psi, np.repeat(tt.ravel(), grid.size),
                             np.repeat(ww.ravel(), grid.size), params)
        return beta.reshape(tt.size, grid.size).mean(axis=1).reshape(tt.shape)

    return stored_table(table_key(params, torque, wear), (torque.size, wear.size), build)


TABLE_VERSION = 2
"""Bump when the table's content changes for the same parameters."""


@lru_cache(maxsize=16)
def model_tables(params):
    """
    Return the cached :class:`ModelTables` of a parameter set.

    Parameters
    ----------
    params : ReducerParams
        Reducer parameters (hashable, frozen).

    Returns
    -------
    ModelTables
        Tables for these parameters.

    """
    return ModelTables(params)
