"""
Validated parameters of an RV reducer, in SI units.

Every quantity is a field of a frozen dataclass with its unit, allowed range
and a one-line description attached as field metadata. That metadata is the
single source for validation here, for the ROS parameter descriptors of the
nodes and for the YAML file in ``config/``.

Defaults are the RV-80E of the paper (Table 1) and its catalogue ratings.
Catalogue figures that the paper does not give (rated life, torsional
rigidity, lost-motion test torque) are common RV-80E datasheet values, kept
configurable because they were not checked against a vendor sheet.
"""

from dataclasses import dataclass, field, fields, replace
import math

from .errors import InvalidParameter, out_of_range


def spec(default, unit, lo=None, hi=None, doc='', lo_open=False, hi_open=False, integer=False):
    """
    Declare a parameter field with its unit and allowed range.

    Parameters
    ----------
    default : float or int
        Default value, in SI units.
    unit : str
        SI unit of the value ('' for dimensionless).
    lo, hi : float, optional
        Bounds of the allowed range (None: unbounded).
    doc : str
        One-line description (shown in ROS parameter descriptors).
    lo_open, hi_open : bool
        Whether the bound itself is excluded.
    integer : bool
        Whether the value must be a whole number.

    Returns
    -------
    dataclasses.Field
        A field carrying the metadata.

    """
    meta = {'unit': unit, 'lo': lo, 'hi': hi, 'doc': doc, 'lo_open': lo_open,
            'hi_open': hi_open, 'integer': integer}
    return field(default=default, metadata=meta)


def describe_range(meta):
    """
    Render a field's allowed range as text, e.g. ``'> 0'`` or ``'0 .. 1'``.

    Parameters
    ----------
    meta : mapping
        Field metadata made by :func:`spec`.

    Returns
    -------
    str
        Human-readable range.

    """
    lo, hi = meta['lo'], meta['hi']
    if lo is not None and hi is not None:
        left = '(' if meta['lo_open'] else '['
        right = ')' if meta['hi_open'] else ']'
        return f'in {left}{lo:g}, {hi:g}{right}'
    if lo is not None:
        return f"{'>' if meta['lo_open'] else '>='} {lo:g}"
    if hi is not None:
        return f"{'<' if meta['hi_open'] else '<='} {hi:g}"
    return 'finite'


def check_value(name, value, meta):
    """
    Validate one value against its field metadata.

    Parameters
    ----------
    name : str
        Dotted name of the parameter (for the message).
    value : object
        Candidate value.
    meta : mapping
        Field metadata made by :func:`spec`.

    Returns
    -------
    float or int
        The value converted to float (or int for integer fields).

    Raises
    ------
    InvalidParameter
        If the value is not a finite number in range.

    """
    allowed = describe_range(meta)
    if isinstance(value, bool):
        raise InvalidParameter(out_of_range(name, value, meta['unit'], 'a number ' + allowed))
    try:
        as_float = float(value)
    except (TypeError, ValueError, OverflowError):
        raise InvalidParameter(out_of_range(name, value, meta['unit'], 'a number ' + allowed))
    if not isinstance(value, (int, float)):
        value = as_float
    if not math.isfinite(as_float):
        raise InvalidParameter(out_of_range(name, value, meta['unit'], allowed))
    if meta['integer']:
        if value != int(value):
            raise InvalidParameter(
                out_of_range(name, value, meta['unit'], 'a whole number ' + allowed))
        value = int(value)
    else:
        value = float(value)
    lo, hi = meta['lo'], meta['hi']
    bad_lo = lo is not None and (value <= lo if meta['lo_open'] else value < lo)
    bad_hi = hi is not None and (value >= hi if meta['hi_open'] else value > hi)
    if bad_lo or bad_hi:
        raise InvalidParameter(out_of_range(name, value, meta['unit'], allowed))
    return value


class _Validated:
    """Mixin: validate every :func:`spec` field after construction."""

    def __post_init__(self):
        prefix = getattr(self, '_prefix', type(self).__name__.lower())
        for f in fields(self):
            if 'unit' not in f.metadata:
                continue
            value = check_value(f'{prefix}.{f.name}', getattr(self, f.name), f.metadata)
            object.__setattr__(self, f.name, value)
        self._check()

    def _check(self):
        """Cross-field checks; subclasses override."""


@dataclass(frozen=True)
class Geometry(_Validated):
    """
    Gear geometry of the RV reducer (paper Table 1).

    The cycloid stage has ``z_pins`` pins on a circle of radius
    ``pin_circle_radius``; the first (involute) stage has a sun pinion and
    planet gears that drive the crankshafts.
    """

    _prefix = 'geometry'
    z_pins: int = spec(40, '', 3, 200, 'number of pins (needle teeth), Zp', integer=True)
    z_cycloid: int = spec(39, '', 2, 199, 'number of cycloid teeth, Zc = Zp - 1', integer=True)
    pin_circle_radius: float = spec(0.1145, 'm', 0.0, 2.0, 'radius of the pin-centre circle, Rp',
                                    lo_open=True)
    pin_radius: float = spec(0.005, 'm', 0.0, 0.1, 'pin radius, rrp', lo_open=True)
    eccentricity: float = spec(0.0022, 'm', 0.0, 0.1, 'crank eccentricity, a', lo_open=True)
    equidistant_modification: float = spec(
        0.05e-3, 'm', -1e-3, 1e-3, 'equidistant modification, delta rrp (+ adds clearance)')
    shift_modification: float = spec(0.05e-3, 'm', -1e-3, 1e-3,
                                     'shift (move-distance) modification, delta Rp')
    z_sun: int = spec(18, '', 6, 200, 'teeth of the involute sun (input) gear', integer=True)
    z_planet: int = spec(36, '', 6, 400, 'teeth of each involute planet gear', integer=True)
    module: float = spec(2.6e-3, 'm', 0.0, 0.05, 'module of the involute stage', lo_open=True)
    disc_width: float = spec(0.015, 'm', 0.0, 0.2, 'effective width of one cycloid disc, b',
                             lo_open=True)
    n_discs: int = spec(2, '', 1, 4, 'number of cycloid discs (phased evenly)', integer=True)

    def _check(self):
        if self.z_cycloid != self.z_pins - 1:
            raise InvalidParameter(
                f'geometry.z_cycloid must be z_pins - 1 = {self.z_pins - 1}, got {self.z_cycloid}')
        k1 = self.eccentricity * self.z_pins / self.pin_circle_radius
        if not k1 < 1.0:
            raise InvalidParameter(out_of_range(
                'geometry.eccentricity * z_pins / pin_circle_radius (K1)', k1, '', '< 1'))
        if self.pin_radius >= self.pin_circle_radius * math.sin(math.pi / self.z_pins):
            raise InvalidParameter(out_of_range(
                'geometry.pin_radius', self.pin_radius, 'm',
                f'< {self.pin_circle_radius * math.sin(math.pi / self.z_pins):g} '
                '(pins would overlap)'))

    @property
    def k1(self):
        """Short-amplitude factor K1 = a·Zp/Rp (paper, after eq 16)."""
        return self.eccentricity * self.z_pins / self.pin_circle_radius


@dataclass(frozen=True)
class Materials(_Validated):
    """Elastic properties: GCr15 pins against a 20CrMo cycloid disc."""

    _prefix = 'materials'
    pin_youngs_modulus: float = spec(206e9, 'Pa', 1e9, 1e12, 'Young modulus of the pins (GCr15)')
    pin_poisson_ratio: float = spec(0.3, '', 0.0, 0.5, 'Poisson ratio of the pins', hi_open=True)
    disc_youngs_modulus: float = spec(206e9, 'Pa', 1e9, 1e12,
                                      'Young modulus of the cycloid disc (20CrMo)')
    disc_poisson_ratio: float = spec(0.3, '', 0.0, 0.5, 'Poisson ratio of the disc', hi_open=True)

    @property
    def effective_modulus(self):
        """Equivalent modulus E*, 1/E* = (1-mu1^2)/E1 + (1-mu2^2)/E2 (eq 5) [Pa]."""
        inv = ((1.0 - self.pin_poisson_ratio ** 2) / self.pin_youngs_modulus
               + (1.0 - self.disc_poisson_ratio ** 2) / self.disc_youngs_modulus)
        return 1.0 / inv


@dataclass(frozen=True)
class Wear(_Validated):
    """
    Archard wear with the Janakiraman coefficient (eqs 1-11) and its calibration.

    ``rate_multiplier`` is the one number fitted to the paper's Table 2
    (:func:`.wear.calibrate_to_paper`): the coefficient of eq 7 is too
    sensitive to be a prediction (physics notes section 2), so the level is a
    fit, not a validation. ``composite_roughness`` is a nominal value, not
    fitted. ``run_in_fraction`` and ``run_in_depth`` describe a hypothesis:
    the roughness polishing down as wear accumulates, fitted to the two rate
    re-evaluations visible in Table 2 and checked by nothing else (0 drops
    it).
    """

    _prefix = 'wear'
    pressure_viscosity: float = spec(2.0e-8, '1/Pa', 0.0, 1e-7,
                                     'lubricant pressure-viscosity coefficient, alpha0',
                                     lo_open=True)
    composite_roughness: float = spec(0.5e-6, 'm', 0.0, 1e-5,
                                      'composite RMS roughness of ground flanks and pins, Rrms '
                                      '(nominal, not fitted)', lo_open=True)
    rate_multiplier: float = spec(0.3420, '', 0.0, 1e6,
                                  'multiplier on the Archard rate of the loaded mesh (the one '
                                  'number fitted to paper Table 2)', lo_open=True)
    run_in_fraction: float = spec(0.0731, '', 0.0, 1.0,
                                  'fraction of the roughness removed by running-in (hypothesis '
                                  'fitted to paper Table 2)', hi_open=True)
    run_in_depth: float = spec(18.76e-6, 'm', 0.0, 1e-3,
                               'wear depth over which running-in acts, e-folding (hypothesis '
                               'fitted to paper Table 2)', lo_open=True)
    janakiraman_constant: float = spec(3.981e29, '', 0.0, 1e40,
                                       'prefactor of the Janakiraman coefficient (eq 7)',
                                       lo_open=True)
    load_exponent: float = spec(1.219, '', 0.0, 5.0, 'exponent of the load parameter L (eq 7)')
    viscosity_exponent: float = spec(-7.377, '', -20.0, 0.0,
                                     'exponent of the viscosity parameter G (eq 7)')
    roughness_exponent: float = spec(1.589, '', 0.0, 5.0,
                                     'exponent of the roughness parameter S (eq 7)')
    slide_coefficient: float = spec(1.0, '', 0.0, 10.0, 'slide coefficient, lambda (eq 8)',
                                    lo_open=True)
    overlap_ratio: float = spec(1.0, '', 0.0, 10.0, 'overlap ratio, epsilon_alpha (eq 9)',
                                lo_open=True)
    paper_stage_hours: float = spec(2000.0, 'h', 0.0, 1e6,
                                    'interval at which the paper re-evaluates the wear rate',
                                    lo_open=True)


@dataclass(frozen=True)
class Rating(_Validated):
    """Catalogue ratings and the stiffness that ties the mesh to the whole reducer."""

    _prefix = 'rating'
    rated_torque: float = spec(784.0, 'N*m', 0.0, 1e6, 'rated output torque, T0', lo_open=True)
    rated_output_speed: float = spec(15.0 * 2.0 * math.pi / 60.0, 'rad/s', 0.0, 100.0,
                                     'rated output speed, N0 (15 rpm)', lo_open=True)
    rated_life: float = spec(6000.0 * 3600.0, 's', 0.0, 1e10, 'rated life K at T0, N0 (6000 h)',
                             lo_open=True)
    life_exponent: float = spec(10.0 / 3.0, '', 0.0, 20.0, 'torque exponent of the life formula',
                                lo_open=True)
    torsional_rigidity: float = spec(196.0 * 60.0 * 180.0 / math.pi, 'N*m/rad', 0.0, 1e9,
                                     'catalogue torsional rigidity (196 N*m/arcmin)',
                                     lo_open=True)
    lost_motion_torque_fraction: float = spec(0.03, '', 0.0, 1.0,
                                              'test torque of lost motion, fraction of T0',
                                              lo_open=True)
    contact_stiffness: float = spec(4.0e8, 'N/m', 0.0, 1e12,
                                    'Hertz secant stiffness of one pin contact, k_n',
                                    lo_open=True)


@dataclass(frozen=True)
class ManufacturingErrors(_Validated):
    """
    Manufacturing-error harmonics of the transmission error.

    The amplitude measured on real RV-80E prototypes (about ±30 arcsec) comes
    from these errors, not from the cycloid mesh (physics notes section 4).
    Orders are per output revolution: 1 (run-out of the output) and Zp = 40
    (once per crank revolution: crank eccentricity error).
    """

    _prefix = 'manufacturing'
    order1_amplitude: float = spec(0.14 / 60.0 * math.pi / 180.0, 'rad', 0.0, 0.01,
                                   'TE amplitude at 1x output frequency (0.14 arcmin)')
    order1_phase: float = spec(0.3, 'rad', -7.0, 7.0, 'phase of the 1x harmonic')
    order2_amplitude: float = spec(0.03 / 60.0 * math.pi / 180.0, 'rad', 0.0, 0.01,
                                   'TE amplitude at 2x output frequency (0.03 arcmin)')
    order2_phase: float = spec(1.1, 'rad', -7.0, 7.0, 'phase of the 2x harmonic')
    crank_amplitude: float = spec(0.04 / 60.0 * math.pi / 180.0, 'rad', 0.0, 0.01,
                                  'TE amplitude at the crank order Zp (0.04 arcmin)')
    crank_phase: float = spec(-0.7, 'rad', -7.0, 7.0, 'phase of the crank-order harmonic')


SECTIONS = {
    'geometry': Geometry,
    'materials': Materials,
    'wear': Wear,
    'rating': Rating,
    'manufacturing': ManufacturingErrors,
}


@dataclass(frozen=True)
class ReducerParams:
    """All parameters of one reducer; defaults are the paper's RV-80E."""

    geometry: Geometry = field(default_factory=Geometry)
    materials: Materials = field(default_factory=Materials)
    wear: Wear = field(default_factory=Wear)
    rating: Rating = field(default_factory=Rating)
    manufacturing: ManufacturingErrors = field(default_factory=ManufacturingErrors)

    def with_overrides(self, overrides):
        """
        Return a copy with some values replaced.

        Parameters
        ----------
        overrides : mapping
            Either nested ``{'geometry': {'pin_radius': 0.006}}`` or flat
            dotted ``{'geometry.pin_radius': 0.006}`` keys, SI units.

        Returns
        -------
        ReducerParams
            Validated copy.

        Raises
        ------
        InvalidParameter
            On an unknown name or a value out of range.

        """
        nested = {}
        for key, value in dict(overrides).items():
            if isinstance(value, dict):
                nested.setdefault(key, {}).update(value)
            else:
                section, _, name = str(key).partition('.')
                if not name:
                    raise InvalidParameter(
                        f"parameter name must be 'section.name', got {key!r}; "
                        f'sections: {", ".join(SECTIONS)}')
                nested.setdefault(section, {})[name] = value
        updated = {}
        for section, values in nested.items():
            if section not in SECTIONS:
                raise InvalidParameter(
                    f'unknown parameter section {section!r}; allowed: {", ".join(SECTIONS)}')
            current = getattr(self, section)
            known = {f.name for f in fields(current) if 'unit' in f.metadata}
            for name in values:
                if name not in known:
                    raise InvalidParameter(
                        f'unknown parameter {section}.{name}; allowed: {", ".join(sorted(known))}')
            updated[section] = replace(current, **values)
        return replace(self, **updated)

    def to_dict(self):
        """
        Return the parameters as a nested plain dict (SI units).

        Returns
        -------
        dict
            ``{section: {name: value}}``.

        """
        return {name: {f.name: getattr(getattr(self, name), f.name)
                       for f in fields(getattr(self, name)) if 'unit' in f.metadata}
                for name in SECTIONS}

    @classmethod
    def from_mapping(cls, data, overrides=None, source='reducer parameters'):
        """
        Build parameters from a mapping (as a YAML file holds them, SI), then apply overrides.

        Parameters
        ----------
        data : mapping or None
            ``{'reducer': {section: {name: value}}}`` or the sections directly;
            None or empty gives the defaults.
        overrides : mapping, optional
            Extra overrides, as for :meth:`with_overrides`.
        source : str
            Where the mapping came from (a file name), for messages.

        Returns
        -------
        ReducerParams
            Validated parameters.

        Raises
        ------
        InvalidParameter
            If the data is not a mapping of sections or holds bad values.

        """
        data = {} if data is None else data
        if not isinstance(data, dict):
            raise InvalidParameter(
                f'{source}: expected a mapping of sections, got {type(data).__name__}')
        data = data.get('reducer', data)
        if not isinstance(data, dict):
            raise InvalidParameter(
                f"{source}: 'reducer' must be a mapping of sections, got {type(data).__name__}")
        params = cls().with_overrides(data)
        return params.with_overrides(overrides) if overrides else params


def iter_specs(params=None):
    """
    Yield every parameter with its metadata.

    Parameters
    ----------
    params : ReducerParams, optional
        Source of the current values (defaults if omitted).

    Yields
    ------
    tuple
        ``(dotted_name, value, metadata)``.

    """
    params = params or ReducerParams()
    for section in SECTIONS:
        obj = getattr(params, section)
        for f in fields(obj):
            if 'unit' in f.metadata:
                yield f'{section}.{f.name}', getattr(obj, f.name), f.metadata
