"""
Kinematics of a two-stage RV reducer (paper Table 4).

Stage 1 is an involute sun/planet pair, stage 2 the cycloid/pin mesh whose
cranks are the planet shafts. With the pin housing fixed and the output
taken from the crank carrier the total ratio is ``i = 1 + (Zpl/Zs)·Zp``.
"""

from dataclasses import dataclass
import math


def total_ratio(geometry):
    """
    Total reduction ratio input/output, ``i = 1 + (Zpl/Zs)·Zp``.

    Parameters
    ----------
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    float
        Ratio (81 for the RV-80E of paper Table 4).

    """
    return 1.0 + geometry.z_planet / geometry.z_sun * geometry.z_pins


def effective_lever_radius(geometry):
    """
    Radius that turns pin-contact normal motion into output rotation.

    ``r_eff = a·i·Zs/Zpl`` with the input held (physics notes section 3).

    Parameters
    ----------
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    float
        r_eff [m] (89.1 mm for the RV-80E).

    """
    return geometry.eccentricity * total_ratio(geometry) * geometry.z_sun / geometry.z_planet


def eccentric_angle(output_angle, geometry):
    """
    Absolute angle of the crank eccentricity for a given output angle.

    The eccentric turns ``-Zc`` times per output revolution; the sign is a
    convention (the mesh is symmetric), so it is taken positive here.

    Parameters
    ----------
    output_angle : array_like
        Output (carrier) angle [rad].
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    ndarray
        Eccentric angle psi [rad].

    """
    return geometry.z_cycloid * output_angle


def mesh_pass_rate(output_speed, geometry):
    """
    Meshing passes per second seen by one cycloid tooth, n in eq 9.

    The disc turns ``Zp`` times per output revolution relative to its
    eccentric, so each tooth meets a pin ``Zp·|w_out|/(2 pi)`` times a second.

    Parameters
    ----------
    output_speed : array_like
        Output speed [rad/s] (sign ignored).
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    ndarray
        Passes per second [1/s] (10 Hz at 90 deg/s for the RV-80E).

    """
    return geometry.z_pins * abs(output_speed) / (2.0 * math.pi)


@dataclass(frozen=True)
class SpeedTable:
    """Speeds of the key parts for one input speed (paper Table 4), rad/s."""

    ratio: float
    sun_speed: float
    planet_speed: float
    crank_speed_relative: float
    output_speed: float
    mesh_frequency: float


def speed_table(input_speed, geometry):
    """
    Speeds of sun, planet/crank and output for an input speed (Table 4).

    Parameters
    ----------
    input_speed : float
        Speed of the sun (input) gear [rad/s].
    geometry : Geometry
        Reducer geometry.

    Returns
    -------
    SpeedTable
        ``planet_speed`` is the first-stage value ``w_in·Zs/Zpl`` as the
        paper's Table 4 lists it; ``crank_speed_relative`` is the crank speed
        relative to the carrier, ``(w_in - w_out)·Zs/Zpl``.

    """
    i = total_ratio(geometry)
    out = input_speed / i
    return SpeedTable(
        ratio=i,
        sun_speed=input_speed,
        planet_speed=input_speed * geometry.z_sun / geometry.z_planet,
        crank_speed_relative=(input_speed - out) * geometry.z_sun / geometry.z_planet,
        output_speed=out,
        mesh_frequency=mesh_pass_rate(out, geometry),
    )
