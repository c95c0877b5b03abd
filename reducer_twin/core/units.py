"""
Unit conversions used at the edges (CLI, reports, YAML comments).

The core computes in SI (REP 103): metres, radians, seconds, newton-metres.
Names of converted values carry their unit (``wear_um``, ``te_arcmin``).
"""

import math

ARCMIN = math.pi / (180.0 * 60.0)
"""One arc minute in radians."""

ARCSEC = ARCMIN / 60.0
"""One arc second in radians."""

UM = 1e-6
"""One micrometre in metres."""

HOUR = 3600.0
"""One hour in seconds."""

RPM = 2.0 * math.pi / 60.0
"""One revolution per minute in rad/s."""

DEG = math.pi / 180.0
"""One degree in radians."""


def rad_to_arcmin(x):
    """Convert radians to arc minutes."""
    return x / ARCMIN


def rad_to_arcsec(x):
    """Convert radians to arc seconds."""
    return x / ARCSEC


def m_to_um(x):
    """Convert metres to micrometres."""
    return x / UM


def s_to_h(x):
    """Convert seconds to hours."""
    return x / HOUR
