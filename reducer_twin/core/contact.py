"""
Loaded contact of all pins with both discs, and Hertz line contact.

Model (physics notes section 3): the discs turn together by ``beta`` about
the output with the input held; pin ``i`` closes its normal clearance
``Δ_i`` when ``beta·l_i > Δ_i`` and then pushes back with the secant Hertz
stiffness ``k_n``: ``F_i = k_n·max(beta·l_i - Δ_i, 0)``. Torque balance
``Σ F_i·l_i = T`` is piecewise linear in ``beta``; it is solved exactly by
Newton steps from the right (exact for a convex piecewise-linear
function), vectorised over samples.
"""

from dataclasses import dataclass

import numpy as np

from .geometry import equivalent_radius, flank_phases, lever_arms_cs, normal_clearance_cs


LOADED_FORCE = 1e-6
"""A contact force above this counts as loaded [N]; below is solver rounding (~1e-12 N)."""


@dataclass(frozen=True)
class LoadedMesh:
    """
    Solution of the loaded mesh for N samples.

    Attributes
    ----------
    beta : ndarray, shape (N,)
        Output rotation taken up by the mesh (clearance plus contact
        deflection), signed like the torque [rad].
    forces : ndarray, shape (N, M)
        Normal force of each contact on the loaded flanks [N],
        ``M = n_discs·(Zp//2 + 1)``; the other flanks carry none.
    phases : ndarray, shape (N, M)
        Meshing phase of each of those contacts [rad].

    """

    beta: np.ndarray
    forces: np.ndarray
    phases: np.ndarray

    @property
    def loaded_pins(self):
        """Count the contacts that carry load (above 1 µN, not rounding), per sample."""
        return np.count_nonzero(self.forces > LOADED_FORCE, axis=1)

    @property
    def max_force(self):
        """Return the largest pin force per sample [N]."""
        return self.forces.max(axis=1)


def solve_mesh(psi, torque, params, wear=0.0):
    """
    Solve the load sharing of all pin contacts (piecewise-linear, exact).

    Parameters
    ----------
    psi : array_like, shape (N,)
        Eccentric angle [rad].
    torque : float or array_like, shape (N,)
        Output torque carried by the mesh [N·m]; its sign picks the flanks.
    params : ReducerParams
        Reducer parameters.
    wear : float or array_like, shape (N,)
        Combined uniform normal wear of flanks and pins [m].

    Returns
    -------
    LoadedMesh
        Rotation, forces and phases per sample.

    """
    g = params.geometry
    k_n = params.rating.contact_stiffness
    psi = np.atleast_1d(np.asarray(psi, dtype=float))
    n = psi.shape[0]
    torque = np.broadcast_to(np.asarray(torque, dtype=float), (n,))
    wear = np.broadcast_to(np.asarray(wear, dtype=float), (n,))
    sign = np.where(torque < 0.0, -1.0, 1.0)
    # The mesh is mirror-symmetric (phi -> -phi): a negative torque loads the
    # mirrored flanks, i.e. the positive flanks at eccentric angle -psi.
    phi, cos_phi, sin_phi = flank_phases(psi * sign, g)
    lever = np.where(sin_phi > 0.0, lever_arms_cs(cos_phi, sin_phi, g), 0.0)
    clear = normal_clearance_cs(cos_phi, g, wear[:, None])
    beta = _engagement_rotation(lever, clear, np.abs(torque) / k_n)
    forces = np.where(lever > 0.0, k_n * np.maximum(beta[:, None] * lever - clear, 0.0), 0.0)
    phases = np.mod(phi * sign[:, None], 2.0 * np.pi)
    return LoadedMesh(beta=beta * sign, forces=forces, phases=phases)


def _engagement_rotation(lever, clear, compliance_torque, max_iter=60):
    """
    Rotation at which ``f(beta) = Σ max(beta·l - Δ, 0)·l`` reaches the target.

    ``f`` is convex, increasing and piecewise linear in ``beta``. Newton's
    method started to the right of the root (at the all-pins-engaged
    solution, which bounds the root because ``max(x, 0) >= x``) decreases
    monotonically and lands exactly on the root once it reaches the root's
    linear piece, so the result is exact, not an approximation, and needs
    no sort.

    Parameters
    ----------
    lever : ndarray, shape (N, M)
        Lever arms; only positive ones can engage [m].
    clear : ndarray, shape (N, M)
        Normal clearances [m].
    compliance_torque : ndarray, shape (N,)
        Target ``|T|/k_n`` [m²].
    max_iter : int
        Safety cap on Newton steps (a handful are used in practice).

    Returns
    -------
    ndarray, shape (N,)
        Rotation beta [rad].

    """
    lp = np.where(lever > 0.0, lever, 0.0)
    l2 = lp * lp
    dl = clear * lp
    with np.errstate(divide='ignore', invalid='ignore'):
        first = np.where(lp > 0.0, clear / lp, np.inf).min(axis=1)
    gate = np.where(lp > 0.0, clear, np.inf)
    beta = np.maximum((compliance_torque + dl.sum(axis=1)) / l2.sum(axis=1), first)
    engaged = np.empty(lp.shape, dtype=bool)
    buf = np.empty_like(lp)
    for _ in range(max_iter):
        np.greater(beta[:, None] * lp, gate, out=engaged)
        slope = np.multiply(engaged, l2, out=buf).sum(axis=1)
        offset = np.multiply(engaged, dl, out=buf).sum(axis=1)
        with np.errstate(divide='ignore', invalid='ignore'):
            new = np.where(slope > 0.0, (compliance_torque + offset) / slope, first)
        new = np.maximum(new, first)
        if not np.any(new < beta - 1e-15 * np.maximum(1.0, np.abs(beta))):
            break
        beta = np.minimum(new, beta)
    return beta


def hertz_half_width(force, width, radius, modulus):
    """
    Half-width of a Hertz line contact, ``a = 1.128·sqrt(F·R*/(b·E*))`` (eq 5).

    The printed eq 5 has ``E*`` in the numerator; this is the dimensionally
    consistent form (Johnson, Contact Mechanics, eq 4.43b:
    ``a² = 4·P·R/(pi·E*)`` with ``P = F/b``).

    Parameters
    ----------
    force : array_like
        Normal force [N].
    width : float
        Contact width b [m].
    radius : array_like
        Equivalent radius R* [m].
    modulus : float
        Equivalent modulus E* [Pa].

    Returns
    -------
    ndarray
        Half-width a [m].

    """
    return np.sqrt(4.0 / np.pi * np.asarray(force) * np.asarray(radius) / (width * modulus))


def hertz_mean_pressure(force, width, half_width):
    """
    Mean contact pressure ``p = F/(2·a·b)`` (eq 6).

    Parameters
    ----------
    force : array_like
        Normal force [N].
    width : float
        Contact width b [m].
    half_width : array_like
        Hertz half-width a [m].

    Returns
    -------
    ndarray
        Mean pressure [Pa] (the peak is ``4/pi`` times larger).

    """
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.where(half_width > 0, np.asarray(force) / (2.0 * half_width * width), 0.0)


def hertz_peak_pressure(force, width, half_width):
    """
    Peak Hertz pressure of a line contact, ``p0 = 2·F/(pi·a·b)`` (Johnson eq 4.45).

    Parameters
    ----------
    force : array_like
        Normal force [N].
    width : float
        Contact width b [m].
    half_width : array_like
        Hertz half-width a [m].

    Returns
    -------
    ndarray
        Peak pressure [Pa].

    """
    return 4.0 / np.pi * hertz_mean_pressure(force, width, half_width)


def contact_summary(mesh, params):
    """
    Hertz quantities of the most loaded contact of each sample.

    Parameters
    ----------
    mesh : LoadedMesh
        Output of :func:`solve_mesh`.
    params : ReducerParams
        Reducer parameters.

    Returns
    -------
    dict
        ``max_force`` [N], ``half_width`` [m], ``peak_pressure`` [Pa],
        ``equivalent_radius`` [m] at the contact with the highest peak
        pressure, and ``loaded_pins`` per sample.

    """
    g = params.geometry
    e_star = params.materials.effective_modulus
    r_star = equivalent_radius(mesh.phases, g)
    half = hertz_half_width(mesh.forces, g.disc_width, r_star, e_star)
    peak = hertz_peak_pressure(mesh.forces, g.disc_width, half)
    k = np.argmax(peak, axis=1)[:, None]
    return {
        'max_force': mesh.max_force,
        'half_width': np.take_along_axis(half, k, axis=1)[:, 0],
        'peak_pressure': np.take_along_axis(peak, k, axis=1)[:, 0],
        'equivalent_radius': np.take_along_axis(r_star, k, axis=1)[:, 0],
        'loaded_pins': mesh.loaded_pins,
    }
