"""Parameters: the paper's defaults, overrides from mappings and rejected values."""

import dataclasses
import math

import pytest
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.params import ReducerParams

# Paper, Table 1 ("Main parameters of gear parts of the precise planetary
# cycloidal 80e reducer"), lengths in mm as printed.
PAPER_TABLE1 = {
    'z_pins': 40,               # Number of needle teeth
    'z_cycloid': 39,            # Number of cycloid teeth
    'pin_circle_radius': 114.5,  # Radius of the distribution circle of the needle teeth/mm
    'pin_radius': 5.0,          # Needle tooth radius/mm
    'eccentricity': 2.2,        # Cycloidal pinion eccentricity/mm
    'equidistant_modification': 0.05,  # Isometric offer factor/mm (sign: physics notes 1)
    'shift_modification': 0.05,  # Shifting distance offer factor/mm (sign: physics notes 1)
    'z_sun': 18,                # Number of teeth for involute sun wheels
    'z_planet': 36,             # Number of teeth of involute planetary wheels
    'module': 2.6,              # Involute gear modulus/mm
}
LENGTHS_MM = {'pin_circle_radius', 'pin_radius', 'eccentricity', 'equidistant_modification',
              'shift_modification', 'module'}


@pytest.mark.parametrize('name', sorted(PAPER_TABLE1))
def test_default_geometry_is_the_paper_table_1(name):
    expected = PAPER_TABLE1[name] * (1e-3 if name in LENGTHS_MM else 1)
    value = getattr(ReducerParams().geometry, name)
    if name in LENGTHS_MM:
        assert value == pytest.approx(expected, rel=1e-12)
    else:
        assert value == expected
        assert isinstance(value, int)


def test_default_ratings_are_the_papers_784_nm_and_15_rpm():
    rating = ReducerParams().rating
    # Paper Table 3: output load torque Step(..., -784000) N*mm; physics notes 1: 15 rpm.
    assert rating.rated_torque == pytest.approx(784.0, rel=1e-12)
    assert rating.rated_output_speed == pytest.approx(15.0 * 2.0 * math.pi / 60.0, rel=1e-12)


def test_short_amplitude_factor_is_a_zp_over_rp():
    # Paper, after eq 16: k1 = a*Zp/Rp; physics notes 1: K1 = 0.76856.
    assert ReducerParams().geometry.k1 == pytest.approx(2.2 * 40 / 114.5, rel=1e-12)
    assert ReducerParams().geometry.k1 == pytest.approx(0.76856, abs=5e-6)


@pytest.mark.parametrize('overrides', [
    {'geometry': {'pin_radius': 0.006, 'disc_width': 0.02}},
    {'geometry.pin_radius': 0.006, 'geometry.disc_width': 0.02},
    {'geometry': {'pin_radius': 0.006}, 'geometry.disc_width': 0.02},
], ids=['nested', 'dotted', 'mixed'])
def test_overrides_nested_and_dotted_replace_only_the_named_values(overrides):
    base = ReducerParams()
    params = base.with_overrides(overrides)
    assert params.geometry.pin_radius == 0.006
    assert params.geometry.disc_width == 0.02
    assert params.geometry.z_pins == 40
    assert params.materials == base.materials
    assert base.geometry.pin_radius == 0.005   # the original is untouched


def test_parameters_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        ReducerParams().geometry.pin_radius = 0.006


def test_integer_fields_accept_whole_floats_and_store_ints():
    params = ReducerParams().with_overrides({'geometry.n_discs': 1.0})
    assert params.geometry.n_discs == 1
    assert isinstance(params.geometry.n_discs, int)


# Each row: overrides, fragments the message must hold (quantity, value, unit, range).
BAD_OVERRIDES = [
    ('negative pin radius', {'geometry.pin_radius': -0.002},
     ['geometry.pin_radius', '-0.002', ' m', '(0, 0.1]']),
    ('NaN modulus', {'materials.pin_youngs_modulus': float('nan')},
     ['materials.pin_youngs_modulus', 'nan', 'Pa', '[1e+09, 1e+12]']),
    ('infinite torque', {'rating.rated_torque': float('inf')},
     ['rating.rated_torque', 'inf', 'N*m', '(0, 1e+06]']),
    ('string', {'geometry.eccentricity': 'two mm'},
     ['geometry.eccentricity', "'two mm'", ' m', 'a number']),
    ('negative Poisson ratio', {'materials.disc_poisson_ratio': -0.1},
     ['materials.disc_poisson_ratio', '-0.1', '[0, 0.5)']),
    ('Poisson ratio at the open bound', {'materials.pin_poisson_ratio': 0.5},
     ['materials.pin_poisson_ratio', '0.5', '[0, 0.5)']),
    ('non-integer tooth count', {'geometry.z_pins': 40.5},
     ['geometry.z_pins', '40.5', 'whole number', '[3, 200]']),
    ('Zc != Zp - 1', {'geometry.z_cycloid': 38},
     ['geometry.z_cycloid', 'z_pins - 1', '39', '38']),
    ('K1 >= 1', {'geometry.eccentricity': 0.003},
     ['K1', '1.048', '< 1']),
    ('overlapping pins', {'geometry.pin_radius': 0.0095},
     ['geometry.pin_radius', '0.0095', ' m', '< 0.00898', 'overlap']),
    ('unknown section', {'gearing.pin_radius': 0.005},
     ["'gearing'", 'geometry']),
    ('unknown name, dotted', {'geometry.pin_diameter': 0.01},
     ['geometry.pin_diameter', 'pin_radius']),
    ('unknown name, nested', {'geometry': {'pin_diameter': 0.01}},
     ['geometry.pin_diameter', 'pin_radius']),
    ('name without section', {'pin_radius': 0.005},
     ["'pin_radius'", 'section.name']),
]


@pytest.mark.parametrize('overrides, fragments', [row[1:] for row in BAD_OVERRIDES],
                         ids=[row[0] for row in BAD_OVERRIDES])
def test_bad_values_are_rejected_with_a_message_naming_them(overrides, fragments):
    with pytest.raises(InvalidParameter) as info:
        ReducerParams().with_overrides(overrides)
    message = str(info.value)
    for fragment in fragments:
        assert fragment in message, f'{fragment!r} missing from {message!r}'


def test_invalid_parameter_is_a_value_error():
    # style.md: errors subclass built-ins (python-control's InvalidParameter(ValueError)).
    with pytest.raises(ValueError):
        ReducerParams().with_overrides({'geometry.pin_radius': -1.0})


@pytest.mark.parametrize('name', ['wear.slide_coefficient', 'geometry.n_discs'])
def test_a_bool_is_rejected_even_where_one_is_in_range(name):
    with pytest.raises(InvalidParameter, match=name):
        ReducerParams().with_overrides({name: True})


def test_a_huge_integer_is_rejected_as_out_of_range():
    with pytest.raises(InvalidParameter, match='geometry.z_pins'):
        ReducerParams().with_overrides({'geometry.z_pins': 10 ** 400})
