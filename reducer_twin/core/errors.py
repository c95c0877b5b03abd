"""
Error types of the reducer twin.

Every error the project raises on bad input derives from
:class:`ReducerTwinError`, so callers (the CLI, the nodes, the bag reader) can
tell a rejected input from a programming error.
"""


class ReducerTwinError(Exception):
    """Base class of every error the project raises on purpose."""


class InvalidParameter(ReducerTwinError, ValueError):
    """A parameter value is outside its allowed range or of the wrong kind."""


class InvalidInput(ReducerTwinError, ValueError):
    """A measurement or message cannot be used (NaN, wrong length, bad stamp)."""


class BagError(ReducerTwinError):
    """A rosbag2 recording cannot be read or written as asked."""


class StateFileError(ReducerTwinError):
    """A persisted estimator state file is missing, corrupt or foreign."""


def out_of_range(name, value, unit, allowed):
    """
    Build the standard message for a value outside its range.

    Parameters
    ----------
    name : str
        Name of the quantity, as the user spells it.
    value : object
        The value that was given.
    unit : str
        Unit of the value ('' for dimensionless).
    allowed : str
        The allowed range, e.g. ``'> 0'`` or ``'0 .. 1'``.

    Returns
    -------
    str
        ``'<name> must be <allowed> <unit>, got <value>'``.

    """
    unit_txt = f' {unit}' if unit else ''
    return f'{name} must be {allowed}{unit_txt}, got {value!r}'
