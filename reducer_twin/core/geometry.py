"""
Cycloid profile and per-pin contact geometry.

Conventions: ``phi`` is the meshing phase of a pin, its angle from the
direction of the crank eccentricity; the pin at ``phi = 0`` sits at the
bottom of a tooth space. ``S = 1 + K1² - 2·K1·cos(phi)`` throughout (the
printed eq 16 has ``cos(Zc·theta)`` there, which misses 39 of 40 pins; see
physics notes section 2).
"""

import numpy as np

from .kinematics import effective_lever_radius


def profile(theta, geometry, wear=0.0, modified=True):
    """
    Compute points of the cycloid disc outline: eq 16 in its consistent form.

    Parameters
    ----------
    theta : array_like
        Profile parameter [rad]; ``0 .. 2·pi·Zc`` covers the whole disc.
    geometry : Geometry
        Reducer geometry.
    wear : float or array_like
        Normal wear depth of the disc flank, h_Ic [m].
    modified : bool
        Apply the shift and equidistant modifications.

    Returns
    -------
    x, y : ndarray
        Profile coordinates in the disc frame [m]; the disc centre is the
        origin and the housing centre sits at ``(-a, 0)`` when the
        eccentricity points along +x.

    """
    g = geometry
    theta = np.asarray(theta, dtype=float)
    i_h = g.z_pins / g.z_cycloid
    k1 = g.k1
    rp = g.pin_circle_radius + (g.shift_modification if modified else 0.0)
    rr = g.pin_radius + (g.equidistant_modification if modified else 0.0) + wear
    s_inv = 1.0 / np.sqrt(1.0 + k1 * k1 - 2.0 * k1 * np.cos(theta))
    c1, s1 = np.cos((1.0 - i_h) * theta), np.sin((1.0 - i_h) * theta)
    c2, s2 = np.cos(i_h * theta), np.sin(i_h * theta)
    x = rp * c1 - g.eccentricity * c2 + rr * s_inv * (k1 * c2 - c1)
    y = rp * s1 + g.eccentricity * s2 - rr * s_inv * (k1 * s2 + s1)
    return x, y


def pin_centres(geometry):
    """
    Pin centres in the disc frame when the eccentricity points along +x.

    Parameters
    ----------
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    ndarray, shape (Zp, 2)
        Pin centre coordinates [m].

    """
    g = geometry
    phi = 2.0 * np.pi * np.arange(g.z_pins) / g.z_pins
    return np.stack([g.pin_circle_radius * np.cos(phi) - g.eccentricity,
                     g.pin_circle_radius * np.sin(phi)], axis=1)


def pin_phases(psi, geometry):
    """
    Meshing phase of every pin against every disc.

    Disc ``k`` of ``n_discs`` has its eccentric turned by ``2·pi·k/n_discs``.

    Parameters
    ----------
    psi : array_like, shape (N,)
        Eccentric angle [rad].
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    ndarray, shape (N, n_discs·Zp)
        Phases wrapped to ``[0, 2·pi)`` [rad].

    """
    g = geometry
    psi = np.atleast_1d(np.asarray(psi, dtype=float))
    base = 2.0 * np.pi * np.arange(g.z_pins) / g.z_pins
    offsets = 2.0 * np.pi * np.arange(g.n_discs) / g.n_discs
    grid = (base[None, :] + offsets[:, None]).ravel()
    return np.mod(grid[None, :] - psi[:, None], 2.0 * np.pi)


def flank_phases(psi, geometry):
    """
    Phases of the contacts that can carry a positive torque, all discs.

    Only pins with ``0 < phi < pi`` push a positive torque; at eccentric
    angle ``psi`` the phases of disc ``k`` are ``r_k + m·δ`` with
    ``δ = 2·pi/Zp`` and ``r_k = (2·pi·k/n_discs - psi) mod δ``, so cosines
    and sines follow from one sine/cosine per disc by the angle-addition
    identities (no trigonometry per pin).

    Parameters
    ----------
    psi : array_like, shape (N,)
        Eccentric angle [rad].
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    phi, cos_phi, sin_phi : ndarray, shape (N, n_discs·(Zp//2 + 1))
        Phases [rad] and their cosines and sines; entries with
        ``sin_phi <= 0`` are placeholders that can never engage.

    """
    g = geometry
    psi = np.atleast_1d(np.asarray(psi, dtype=float))
    delta = 2.0 * np.pi / g.z_pins
    steps = np.arange(g.z_pins // 2 + 1) * delta
    cm, sm = np.cos(steps), np.sin(steps)
    parts = []
    for k in range(g.n_discs):
        r = np.mod(2.0 * np.pi * k / g.n_discs - psi, delta)
        cr, sr = np.cos(r)[:, None], np.sin(r)[:, None]
        parts.append((r[:, None] + steps, cr * cm - sr * sm, sr * cm + cr * sm))
    phi, cos_phi, sin_phi = (np.concatenate(x, axis=1) for x in zip(*parts))
    return phi, cos_phi, sin_phi


def lever_arms(phi, geometry):
    """
    Lever arm of each pin's normal force about the output, input held.

    ``l = r_eff·sin(phi)/sqrt(S)`` (physics notes section 3); positive for
    pins that carry a positive output torque.

    Parameters
    ----------
    phi : array_like
        Meshing phases [rad].
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    ndarray
        Lever arms [m], same shape as ``phi``.

    """
    return lever_arms_cs(np.cos(phi), np.sin(phi), geometry)


def lever_arms_cs(cos_phi, sin_phi, geometry):
    """
    Lever arms from the cosine and sine of the phases (see :func:`lever_arms`).

    Parameters
    ----------
    cos_phi, sin_phi : ndarray
        Cosine and sine of the meshing phases.
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    ndarray
        Lever arms [m].

    """
    k1 = geometry.k1
    s = 1.0 + k1 * k1 - 2.0 * k1 * cos_phi
    return effective_lever_radius(geometry) * sin_phi / np.sqrt(s)


def normal_clearance(phi, geometry, wear=0.0):
    """
    Compute the normal clearance between a pin and the modified, worn flank.

    ``Δ = Δrrp - ΔRp·(1 - K1·cos(phi))/sqrt(S) + w`` with ``w`` the combined
    wear of flank and pin (physics notes section 3; within 0.7 µm of the
    exact eq-16 geometry, see the tests).

    Parameters
    ----------
    phi : array_like
        Meshing phases [rad].
    geometry : Geometry
        Reducer geometry.
    wear : float or array_like
        Combined normal wear h_c + h_p [m], broadcast against ``phi``.

    Returns
    -------
    ndarray
        Clearance [m].

    """
    return normal_clearance_cs(np.cos(phi), geometry, wear)


def normal_clearance_cs(cos_phi, geometry, wear=0.0):
    """
    Compute the normal clearance from the cosine of the phases.

    Parameters
    ----------
    cos_phi : ndarray
        Cosine of the meshing phases.
    geometry : Geometry
        Reducer geometry.
    wear : float or array_like
        Combined normal wear [m], broadcast against ``cos_phi``.

    Returns
    -------
    ndarray
        Clearance [m].

    """
    g = geometry
    k1 = g.k1
    s = 1.0 + k1 * k1 - 2.0 * k1 * cos_phi
    return (g.equidistant_modification
            - g.shift_modification * (1.0 - k1 * cos_phi) / np.sqrt(s) + wear)


def flank_curvature_radius(phi, geometry):
    """
    Compute the curvature radius of the flank where it meets the pin at ``phi``.

    The pin-centre curve has ``rho0 = Rp·S^1.5 / (K1·(1+Zp)·cos(phi) -
    (1 + Zp·K1²))``; the flank is its inner offset by the pin radius, so its
    signed radius is ``-(rho0 + rrp)``: positive for a convex flank,
    negative for a concave one.

    Parameters
    ----------
    phi : array_like
        Meshing phases [rad].
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    ndarray
        Signed curvature radius R2 [m].

    """
    g = geometry
    k1 = g.k1
    s = 1.0 + k1 * k1 - 2.0 * k1 * np.cos(phi)
    denom = k1 * (1.0 + g.z_pins) * np.cos(phi) - (1.0 + g.z_pins * k1 * k1)
    with np.errstate(divide='ignore'):
        rho0 = g.pin_circle_radius * s ** 1.5 / denom
    return -(rho0 + g.pin_radius)


def equivalent_radius(phi, geometry):
    """
    Compute the equivalent radius ``R* = R1·R2/(R1 + R2)`` of a contact (eq 5).

    Parameters
    ----------
    phi : array_like
        Meshing phases [rad].
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    ndarray
        R* [m]; ``inf`` where the flank is flat.

    """
    r1 = geometry.pin_radius
    r2 = flank_curvature_radius(phi, geometry)
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.where(np.isfinite(r2), r1 * r2 / (r1 + r2), r1)
