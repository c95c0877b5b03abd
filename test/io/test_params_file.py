"""Reducer parameter files: YAML in SI units, read safely, every problem naming the file."""

import pytest
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.params import ReducerParams
from reducer_twin.io.params_file import default_config_path, read_reducer_params


def test_config_file_loads_equal_to_the_defaults(repo_root):
    loaded = read_reducer_params(repo_root / 'config' / 'rv80e.yaml')
    assert loaded.to_dict() == ReducerParams().to_dict()
    assert loaded == ReducerParams()


def test_yaml_sections_may_sit_at_the_top_level(tmp_path):
    path = tmp_path / 'flat.yaml'
    path.write_text('geometry:\n  pin_radius: 0.0045\n', encoding='utf-8')
    assert read_reducer_params(path).geometry.pin_radius == 0.0045


def test_yaml_overrides_apply_after_the_file(tmp_path):
    path = tmp_path / 'p.yaml'
    path.write_text('reducer:\n  geometry:\n    pin_radius: 0.0045\n', encoding='utf-8')
    params = read_reducer_params(path, {'geometry.pin_radius': 0.004})
    assert params.geometry.pin_radius == 0.004


def test_an_empty_yaml_file_gives_the_defaults(tmp_path):
    path = tmp_path / 'empty.yaml'
    path.write_text('', encoding='utf-8')
    assert read_reducer_params(path) == ReducerParams()


# Each row: YAML text, fragments of the message.
BAD_YAML = [
    ('list at top level', '- 1\n- 2\n', ['expected a mapping', 'list']),
    ('scalar at top level', '42\n', ['expected a mapping', 'int']),
    ('syntax error', 'geometry: [1, 2\n', ['cannot read']),
    ('bad value', 'reducer:\n  geometry:\n    pin_radius: -0.005\n',
     ['geometry.pin_radius', '-0.005', ' m']),
    ('unknown name', 'reducer:\n  geometry:\n    pin_diameter: 0.01\n',
     ['geometry.pin_diameter']),
]


@pytest.mark.parametrize('text, fragments', [row[1:] for row in BAD_YAML],
                         ids=[row[0] for row in BAD_YAML])
def test_bad_yaml_files_are_rejected(tmp_path, text, fragments):
    path = tmp_path / 'bad.yaml'
    path.write_text(text, encoding='utf-8')
    with pytest.raises(InvalidParameter) as info:
        read_reducer_params(path)
    for fragment in fragments:
        assert fragment in str(info.value)


@pytest.mark.parametrize('text', ['reducer: [1, 2]\n', 'reducer:\n', 'reducer: 5\n'],
                         ids=['list', 'null', 'scalar'])
def test_a_reducer_key_that_is_not_a_mapping_is_rejected(tmp_path, text):
    path = tmp_path / 'bad.yaml'
    path.write_text(text, encoding='utf-8')
    with pytest.raises(InvalidParameter, match='reducer'):
        read_reducer_params(path)


def test_missing_file_is_rejected_naming_the_path(tmp_path):
    path = tmp_path / 'no_such.yaml'
    with pytest.raises(InvalidParameter, match='no_such.yaml'):
        read_reducer_params(path)


def test_unreadable_file_is_rejected(tmp_path):
    # A directory cannot be read as a file, whoever runs the test (even root).
    with pytest.raises(InvalidParameter, match='cannot read'):
        read_reducer_params(tmp_path)


def test_yaml_loading_is_safe_a_python_tag_is_rejected_not_executed(tmp_path):
    marker = tmp_path / 'pwned'
    path = tmp_path / 'evil.yaml'
    path.write_text(f'reducer: !!python/object/apply:os.mkdir ["{marker}"]\n', encoding='utf-8')
    with pytest.raises(InvalidParameter):
        read_reducer_params(path)
    assert not marker.exists(), 'the YAML loader executed a python tag'
    path.write_text('reducer: !!python/object:reducer_twin.core.params.Geometry {}\n',
                    encoding='utf-8')
    with pytest.raises(InvalidParameter):
        read_reducer_params(path)


def test_the_packaged_parameter_file_is_found_and_holds_the_defaults():
    assert read_reducer_params(default_config_path()) == ReducerParams()


@pytest.mark.parametrize('data', [None, {}, {'reducer': {}}])
def test_an_empty_mapping_gives_the_defaults(data):
    assert ReducerParams.from_mapping(data) == ReducerParams()
