"""
Where a joint's output torque is read: its link entry, its motor entry, or both.

A controller may report the torque on the link (joint) entry, on the motor entry (as the
motor's torque or already in joint units), or on either where the other has none.
:func:`choose_effort` takes it from where the configuration says
(:data:`EFFORT_SOURCES`), scaled as :func:`motor_effort_scale` derives from
:data:`MOTOR_EFFORT_UNITS`; :func:`motor_torque_seen` tells from the data a motor torque
reported beside motor angles in output form.
"""

import numpy as np

EFFORT_SOURCES = ('auto', 'link', 'motor')
"""Where the joint torque is read: the link entry, the motor entry, or the link where known."""

MOTOR_EFFORT_UNITS = ('auto', 'motor', 'joint')
"""What the motor entry's effort is: motor torque, output torque, or as its angles say."""


def motor_effort_scale(units, motor_angles, ratio):
    """
    Factor that turns the motor entry's effort into output torque.

    Parameters
    ----------
    units : str
        One of :data:`MOTOR_EFFORT_UNITS`; ``'auto'``: a motor torque unless the
        motor angles are reported divided by the ratio (then joint units).
    motor_angles : str
        ``'raw'``, ``'output'`` or ``'auto'`` (taken as raw).
    ratio : float
        Reduction ratio.

    Returns
    -------
    float
        ``ratio`` for a motor torque, 1 for joint units.

    """
    if units == 'auto':
        units = 'joint' if motor_angles == 'output' else 'motor'
    return ratio if units == 'motor' else 1.0


def motor_torque_seen(link_effort, motor_effort, ratio, lowest_bin, largest_torque):
    """
    Tell from the data a motor torque on the motor entry beside motor angles in output form.

    With ``motor_effort_units`` left to ``auto``, an effort on the motor entry beside
    motor angles divided by the ratio is read in joint units. A drive that reports the
    joint's angle but its motor's torque then gives efforts ``ratio`` times too small:
    the lowest torque bin the lost motion is read from is never reached, and the joint
    is not observed. Such an effort is taken for a motor torque when the link entry
    carries none (the motor entry's is the one read), the motor entry's stays below
    ``lowest_bin`` (read as output torque, it gives no lost motion either way), and
    ``ratio`` times it reaches ``lowest_bin`` without passing ``largest_torque``.

    Parameters
    ----------
    link_effort, motor_effort : ndarray
        The entries' efforts over the samples seen so far [as published] (NaN: none).
    ratio : float
        The reduction ratio.
    lowest_bin : float
        The lower edge of the lowest torque bin the lost motion is read from [N*m].
    largest_torque : float
        The largest output torque a reducer takes [N*m].

    Returns
    -------
    float or None
        The motor entry's largest effort (its 99.9th percentile of ``|effort|``) when it
        is a motor torque, else None (the configured rule stands).

    """
    if np.isfinite(link_effort).any():
        return None
    effort = np.abs(motor_effort[np.isfinite(motor_effort)])
    if effort.size < 100:
        return None
    peak = float(np.percentile(effort, 99.9))
    if peak < lowest_bin <= ratio * peak <= largest_torque:
        return peak
    return None


def choose_effort(link_effort, motor_effort, source='link', motor_effort_scale=1.0,
                  effort_scale=1.0):
    """
    Output torque from the link side, the motor side, or the link side where it is known.

    Parameters
    ----------
    link_effort, motor_effort : ndarray
        Effort of the link and motor entries at the same samples.
    source : str
        One of :data:`EFFORT_SOURCES`.
    motor_effort_scale : float
        Factor that turns the motor entry's effort into output torque (the ratio
        for a motor torque, 1 when the controller reports it in joint units).
    effort_scale : float
        Output torque per unit of the effort so chosen (-1 for an effort of the other
        sign; a torque constant for a current).

    Returns
    -------
    ndarray
        Output torque [N·m], NaN where unknown.

    """
    if effort_scale != 1.0:
        return effort_scale * choose_effort(link_effort, motor_effort, source,
                                            motor_effort_scale)
    if source == 'link':
        return link_effort
    if source != 'motor':
        known = np.isfinite(link_effort)
        if known.all():
            return link_effort
    motor = motor_effort * motor_effort_scale if motor_effort_scale != 1.0 else motor_effort
    if source == 'motor':
        return motor
    return np.where(known, link_effort, motor)
