"""
ROS parameters derived from the core's validated dataclasses, kept in sync at runtime.

Each field of a spec dataclass becomes a ROS parameter ``<section>.<name>``
(or ``<name>`` with an empty section) with a descriptor carrying its
description, unit and range; a set-parameters callback rejects an invalid
value with the core's own message while the old value stays.
"""

from dataclasses import fields, replace

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import ParameterType, SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from reducer_twin.core.errors import InvalidParameter, out_of_range
from reducer_twin.core.params import check_value, describe_range


class SpecParameters:
    """
    Declare a validated dataclass as ROS parameters and keep it in sync.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    prefix : str
        Parameter name prefix (e.g. ``'reducer.geometry'``, ``'sim'``); ``''``
        declares the fields by their own names.
    instance : dataclass
        Default values (a frozen, validated dataclass of the core).
    on_change : callable, optional
        Called with the new instance after an accepted change. Without it
        the node cannot apply a change while running, and the parameters are
        declared read-only (set them at start).

    """

    def __init__(self, node, prefix, instance, on_change=None):
        self.node = node
        self.prefix = prefix
        self.value = instance
        self.on_change = on_change
        self._names = {}
        values = {}
        for f in fields(instance):
            meta = f.metadata
            if 'unit' not in meta:
                continue
            name = f'{prefix}.{f.name}' if prefix else f.name
            self._names[name] = (f.name, meta)
            default = getattr(instance, f.name)
            desc = ParameterDescriptor(
                name=name,
                description=f"{meta['doc']} [{meta['unit'] or '-'}]",
                additional_constraints=f"{describe_range(meta)} {meta['unit']}".strip(),
                read_only=on_change is None)
            if meta['integer']:
                desc.type = ParameterType.PARAMETER_INTEGER
                if meta['lo'] is not None and meta['hi'] is not None:
                    desc.integer_range = [IntegerRange(from_value=int(meta['lo']),
                                                       to_value=int(meta['hi']), step=1)]
            else:
                desc.type = ParameterType.PARAMETER_DOUBLE
                if meta['lo'] is not None and meta['hi'] is not None:
                    # ROS ranges are closed: an open bound is declared closed (tools show the
                    # range), additional_constraints says it is open and the core enforces it.
                    desc.floating_point_range = [FloatingPointRange(
                        from_value=float(meta['lo']), to_value=float(meta['hi']), step=0.0)]
            try:
                param = node.declare_parameter(name, default, desc)
            except (InvalidParameterTypeException, InvalidParameterValueException) as err:
                raise InvalidParameter(
                    f'{node.get_name()}: {_refused_override(node, name, meta, err)}') from err
            try:        # named as the node's parameter (an open bound is declared closed)
                values[f.name] = check_value(name, param.value, meta)
            except InvalidParameter as err:
                raise InvalidParameter(f'{node.get_name()}: {err}') from err
        try:
            self.value = replace(instance, **values)
        except InvalidParameter as err:
            raise InvalidParameter(f'{node.get_name()}: {err}') from err
        node.add_on_set_parameters_callback(self._on_set)

    def _on_set(self, params):
        changes = {}
        for p in params:
            if p.name not in self._names:
                continue
            field_name, meta = self._names[p.name]
            try:
                changes[field_name] = check_value(p.name, p.value, meta)
            except InvalidParameter as err:
                return SetParametersResult(successful=False, reason=str(err))
        if not changes:
            return SetParametersResult(successful=True)
        try:
            candidate = replace(self.value, **changes)
        except InvalidParameter as err:
            return SetParametersResult(successful=False, reason=str(err))
        self.value = candidate
        if self.on_change is not None:
            self.on_change(candidate)
        return SetParametersResult(successful=True)


def _refused_override(node, name, meta, err):
    """
    Say in the core's words why rclpy refused the start value of a parameter.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    name : str
        Parameter name.
    meta : mapping
        Field metadata made by :func:`reducer_twin.core.params.spec`.
    err : rclpy.exceptions.ParameterException
        What rclpy raised (wrong type, or outside the descriptor's range).

    Returns
    -------
    str
        ``'<name> must be <allowed> <unit>, got <value>'``.

    """
    # The refused start value is not declared: declared again without a type or range, the
    # parameter takes it from the overrides (command line, parameter file, constructor).
    if node.has_parameter(name):
        return str(err)
    given = node.declare_parameter(
        name, None, ParameterDescriptor(dynamic_typing=True, read_only=True)).value
    if given is None:
        return str(err)
    try:
        check_value(name, given, meta)
    except InvalidParameter as bad:
        return str(bad)
    kind = 'a whole number' if meta['integer'] else 'a floating-point number (e.g. 5.0, not 5)'
    return out_of_range(name, given, meta['unit'], f'{kind} {describe_range(meta)}')


def declare_plain(node, specs):
    """
    Declare read-only parameters that are no core quantity (names, topics, choices).

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    specs : mapping
        Parameter name to ``(default, description)``.

    Returns
    -------
    dict
        Parameter name to the value the node starts with.

    """
    out = {}
    for name, (default, doc) in specs.items():
        if isinstance(default, float):   # a whole number given for a number is taken
            desc = ParameterDescriptor(description=doc, read_only=True, dynamic_typing=True)
            value = node.declare_parameter(name, default, desc).value
            if isinstance(value, int) and not isinstance(value, bool):
                value = float(value)
        else:
            value = node.declare_parameter(
                name, default, ParameterDescriptor(description=doc, read_only=True)).value
        out[name] = value
    return out


def check_choice(name, value, allowed):
    """
    Check that a string parameter is one of ``allowed``.

    Raises
    ------
    InvalidParameter
        Naming the parameter, the allowed values and the value found.

    """
    if value not in allowed:
        raise InvalidParameter(f'{name} must be one of '
                               f'{", ".join(repr(a) for a in allowed)}, got {value!r}')
    return value
