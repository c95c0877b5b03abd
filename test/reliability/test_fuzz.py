"""
Fuzzing of everything that parses outside data: only the project's own errors come out.

Message decoders (JointState and Float64MultiArray CDR, layouts), the bag reader
(random bytes, mutated real rosbag2 files, mutated files of our own writer), the
``metadata.yaml`` of a bag directory (random YAML, Python tags that would run code)
and the estimator's state files. Whatever the input, the code under test returns or
raises a subclass of :class:`~reducer_twin.core.errors.ReducerTwinError`; any other
exception is a bug (a traceback for the user). Hypothesis runs derandomized
(deterministic examples) with bounded example counts, a few seconds per test.

The real bags (``../shared/data/rosbag2-jazzy``) are copied before they are mutated.
"""

import math
from pathlib import Path
import struct

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core.errors import ReducerTwinError, StateFileError
from reducer_twin.core.estimator import WearEstimator
from reducer_twin.core.params import ReducerParams
from reducer_twin.io.bag import open_bag, write_bag_dir
from reducer_twin.io.mcap_reader import McapBagReader
from reducer_twin.io.rosbag2_metadata import custom_data_strings
from reducer_twin.io.state_file import decode_state, encode_state
from reducer_twin.msg_adapters.jointstate_cdr import decode_joint_states, encode_joint_states
from reducer_twin.msg_adapters.layouts import LAYOUTS, parse_values, record_values, TE_FEATURES
from reducer_twin.msg_adapters.multiarray_cdr import decode_layout_batch, decode_multiarray
from reducer_twin.msg_adapters.multiarray_cdr import encode_multiarray
import yaml

pytestmark = pytest.mark.timeout(120, method='thread')

JOINT_STATE = 'sensor_msgs/msg/JointState'


def fuzz(examples):
    """Return Hypothesis settings: deterministic, ``examples`` examples, no deadline."""
    return settings(max_examples=examples, derandomize=True, deadline=None, database=None,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


def project_errors_only(call, *args, **kwargs):
    """Call; return its result, or None when it raised a project error."""
    return refused_with(ReducerTwinError, call, *args, **kwargs)


def refused_with(error, call, *args, **kwargs):
    """Call; return its result, or None when it raised ``error`` (anything else escapes)."""
    try:
        return call(*args, **kwargs)
    except error:
        return None


# --------------------------------------------------------------------------- messages


def _joint_states(n, joints=3, seed=0):
    rng = np.random.default_rng(seed)
    names = [f'j{k}' for k in range(joints)]
    buf, offsets = encode_joint_states(
        1_700_000_000_000_000_000 + np.arange(n) * 1_000_000, names,
        rng.normal(size=(n, joints)), rng.normal(size=(n, joints)), rng.normal(size=(n, joints)))
    return [bytes(buf[a:b]) for a, b in zip(offsets[:-1], offsets[1:])]


VALID_JOINT_STATES = _joint_states(64)

MUTATION = st.tuples(st.integers(0, 63), st.integers(0, 10_000), st.integers(0, 255))


@fuzz(200)
@given(st.lists(MUTATION, min_size=1, max_size=12), st.lists(st.integers(0, 63), max_size=4),
       st.integers(0, 40))
def test_joint_states_of_one_layout_with_corrupt_members_decode_or_raise_project_errors(
        mutations, cut_messages, cut):
    # Many messages of one length go through the template (column-wise) path: corrupt
    # some of them in place, cut others short; the rest must still decode.
    payloads = [bytearray(p) for p in VALID_JOINT_STATES]
    for msg, at, value in mutations:
        payloads[msg][at % len(payloads[msg])] = value
    for msg in cut_messages:
        payloads[msg] = payloads[msg][:max(0, len(payloads[msg]) - 1 - cut)]
    batch = project_errors_only(decode_joint_states, [bytes(p) for p in payloads],
                                errors='skip')
    assert batch is not None, "errors='skip' leaves out bad messages, it does not raise"
    assert len(batch) + len(batch.rejected) == len(payloads)
    untouched = set(range(64)) - {m for m, _, _ in mutations} - set(cut_messages)
    kept = set(range(64)) - {i for i, _ in batch.rejected}
    assert untouched <= kept


def _multiarray(layout, rows, seed=0):
    rng = np.random.default_rng(seed)
    shape = (rows, len(layout.fields)) if layout.batch else (len(layout.fields),)
    return bytes(encode_multiarray(layout, rng.normal(size=shape)))


VALID_ARRAYS = [_multiarray(layout, 3) for layout in LAYOUTS.values()]


@fuzz(300)
@given(st.one_of(st.binary(max_size=300),
                 st.tuples(st.sampled_from(VALID_ARRAYS), st.lists(
                     st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=6),
                     st.integers(0, 64)).map(lambda t: _mutate(*t))),
       st.sampled_from(sorted(LAYOUTS)))
def test_float64_multiarrays_decode_or_raise_project_errors(payload, layout_name):
    layout = LAYOUTS[layout_name]
    decoded = project_errors_only(decode_multiarray, payload)
    if decoded is not None:
        project_errors_only(decoded.values, layout)
    project_errors_only(decode_layout_batch, layout, [payload, payload])


def _mutate(data, edits, cut):
    out = bytearray(data)
    for at, value in edits:
        out[at % len(out)] = value
    return bytes(out[:len(out) - cut % len(out)])


LABEL = st.text(alphabet=st.characters(codec='utf-8'), max_size=40)


@fuzz(300)
@given(st.sampled_from(sorted(LAYOUTS)),
       st.lists(st.tuples(st.one_of(LABEL, st.sampled_from(
           [layout.label for layout in LAYOUTS.values()] + ['samples'])),
           st.integers(-2, 40)), max_size=3),
       st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=60))
def test_layout_parsing_returns_the_fields_or_raises_invalid_input(layout_name, labels, data):
    layout = LAYOUTS[layout_name]
    values = project_errors_only(parse_values, layout, labels, data)
    if values is not None:
        assert set(values) == set(layout.fields)


def test_a_valid_te_features_record_parses_back_to_its_values():
    rec = {f: float(k) for k, f in enumerate(TE_FEATURES.fields)}
    data = record_values(TE_FEATURES, rec)
    assert parse_values(TE_FEATURES, [(TE_FEATURES.label, len(data))], data) == rec


# --------------------------------------------------------------------------- bag files


def read_everything(path):
    """Open a bag and read every message of every topic (JointState decoded), as analyze does."""
    with open_bag(path) as bag:
        for _, raw in bag.iter_raw():
            for i in range(len(raw)):
                raw.payload(i)
        states = [n for n, t in bag.topics.items() if t.msgtype == JOINT_STATE]
        if states:
            bag.read_joint_states(states)
        return bag.warnings


def read_mcap(path):
    """Read a file with McapBagReader alone: topics, metadata, batches, messages."""
    with McapBagReader(path) as reader:
        reader.topics()
        reader.rosbag2_metadata()
        for batch in reader.iter_batches():
            len(batch)
        for _ in reader.iter_messages():
            pass


@pytest.fixture(scope='module')
def corpus(rosbag2_jazzy_dir, tmp_path_factory):
    """
    Return copies of the real bags' storage files and of one JointState bag of ours.

    Returns
    -------
    dict of str to bytes
        File name to content (the shared files are never written).

    """
    files = {}
    for path in sorted(rosbag2_jazzy_dir.rglob('*')):
        if path.suffix in ('.mcap', '.db3'):
            files[f'{path.parent.name}/{path.name}'] = path.read_bytes()
    ours = tmp_path_factory.mktemp('ours') / 'arm'
    stamps = 1_700_000_000_000_000_000 + np.arange(300) * 1_000_000
    rng = np.random.default_rng(1)
    from reducer_twin.msg_adapters.jointstate_cdr import JointStateBatch
    batch = JointStateBatch(stamps, ('j', 'j_motor'), rng.normal(size=(300, 2)),
                            rng.normal(size=(300, 2)), rng.normal(size=(300, 2)))
    write_bag_dir(ours, {'/joint_states': batch}, compression='zstd')
    files['ours/arm_0.mcap'] = (ours / 'arm_0.mcap').read_bytes()
    write_bag_dir(ours.parent / 'plain', {'/joint_states': batch}, compression='none')
    files['ours/plain_0.mcap'] = (ours.parent / 'plain' / 'plain_0.mcap').read_bytes()
    return files


@pytest.fixture(scope='module')
def scratch(tmp_path_factory):
    """Return a directory for the mutated files."""
    return tmp_path_factory.mktemp('fuzz')


def test_the_corpus_is_read_without_warnings_before_it_is_mutated(corpus, scratch):
    for name, data in corpus.items():
        path = scratch / Path(name).name
        path.write_bytes(data)
        assert read_everything(path) == [], name


MAGICS = [b'', b'\x89MCAP0\r\n', b'SQLite format 3\x00']


@fuzz(100)
@given(st.binary(max_size=2000), st.sampled_from(MAGICS))
def test_random_bytes_as_a_bag_file_raise_bag_errors_only(scratch, data, head):
    for suffix in ('.mcap', '.db3'):
        path = scratch / f'random{suffix}'
        path.write_bytes(head + data)
        project_errors_only(read_everything, path)
        if suffix == '.mcap':
            project_errors_only(read_mcap, path)


MUTATIONS = st.lists(st.tuples(st.sampled_from(['set', 'flip', 'insert', 'delete']),
                               st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 255)),
                     min_size=1, max_size=8)


def mutate(data, edits, cut):
    """Apply byte edits at relative positions, then cut ``cut`` (a fraction) off the end."""
    out = bytearray(data)
    for kind, where, value in edits:
        at = int(where * len(out))
        if kind == 'set':
            out[at] = value
        elif kind == 'flip':
            out[at] ^= 1 << (value % 8)
        elif kind == 'insert':
            out[at:at] = bytes([value])
        elif len(out) > 1:
            del out[at]
    return bytes(out[:len(out) - int(cut * len(out))])


@fuzz(300)
@given(st.data(), MUTATIONS, st.one_of(st.just(0.0), st.floats(0.0, 1.0)))
def test_mutated_real_and_written_bag_files_raise_bag_errors_only(
        corpus, scratch, data, edits, cut):
    name = data.draw(st.sampled_from(sorted(corpus)))
    path = scratch / ('mutated' + Path(name).suffix)
    path.write_bytes(mutate(corpus[name], edits, cut))
    project_errors_only(read_everything, path)
    if path.suffix == '.mcap':
        project_errors_only(read_mcap, path)


def test_a_chunk_length_field_of_2_to_the_64_is_a_bag_error(corpus, scratch):
    # The largest lengths a record can claim: no MemoryError, no OverflowError.
    data = bytearray(corpus['ours/plain_0.mcap'])
    at = data.index(b'\x06', 8 + 9)          # the first chunk record after the header
    for value in (2**64 - 1, 2**63, 2**32):
        data[at + 1:at + 9] = struct.pack('<Q', value)
        path = scratch / 'huge.mcap'
        path.write_bytes(bytes(data))
        project_errors_only(read_everything, path)
        project_errors_only(read_mcap, path)


# --------------------------------------------------------------------------- metadata.yaml


@pytest.fixture(scope='module')
def bag_dir(corpus, tmp_path_factory):
    """Return a bag directory holding a real talker file, for metadata.yaml to describe."""
    root = tmp_path_factory.mktemp('meta') / 'talker'
    root.mkdir()
    (root / 'talker.mcap').write_bytes(corpus['talker/talker.mcap'])
    return root


YAML_SCALARS = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
                         st.floats(allow_nan=True), st.text(max_size=20),
                         st.sampled_from(['mcap', 'sqlite3', 'talker.mcap', '../talker.mcap',
                                          '/dev/null', '', 'zstd', 'file', 'message']))
YAML_VALUES = st.recursive(YAML_SCALARS, lambda kids: st.one_of(
    st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=12), kids, max_size=4)),
    max_leaves=12)
KEYS = ['version', 'storage_identifier', 'relative_file_paths', 'topics_with_message_count',
        'compression_mode', 'compression_format', 'custom_data', 'files', 'message_count',
        'duration', 'starting_time']
INFO = st.dictionaries(st.sampled_from(KEYS), YAML_VALUES, max_size=8)

PYTHON_TAGS = [
    '!!python/object/apply:builtins.open ["{canary}", "w"]',
    '!!python/object/apply:os.system ["touch {canary}"]',
    '!!python/object/new:pathlib.Path.touch [!!python/object/apply:pathlib.Path ["{canary}"]]',
    '!!python/name:os.system',
    '!!python/object:builtins.dict {{}}',
]


@fuzz(120)
@given(st.one_of(
    INFO.map(lambda info: yaml.safe_dump({'rosbag2_bagfile_information': info})),
    YAML_VALUES.map(yaml.safe_dump),
    st.text(max_size=300)),
    st.sampled_from([None] + PYTHON_TAGS), st.sampled_from(KEYS))
def test_any_metadata_yaml_gives_a_bag_or_a_bag_error_and_runs_nothing(
        bag_dir, text, tag, key):
    canary = bag_dir.parent / 'canary'
    if tag is not None:
        text = (f'rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n'
                f'  {key}: {tag.format(canary=canary)}\n')
    (bag_dir / 'metadata.yaml').write_text(text, encoding='utf-8')
    project_errors_only(read_everything, bag_dir)
    custom_data_strings(text)
    assert not canary.exists(), 'a YAML tag ran code'


@pytest.mark.parametrize('tag', PYTHON_TAGS)
def test_a_python_tag_in_metadata_yaml_is_refused_and_creates_no_file(bag_dir, tag):
    canary = bag_dir.parent / 'created_by_yaml'
    (bag_dir / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n'
        f'  relative_file_paths: [talker.mcap]\n  custom_data: {tag.format(canary=canary)}\n')
    with pytest.raises(ReducerTwinError, match='cannot be read as YAML'):
        open_bag(bag_dir)
    # custom_data is read with YAML's BaseLoader: tags are not constructed, only strings.
    custom = custom_data_strings((bag_dir / 'metadata.yaml').read_text())
    assert custom is None or all(isinstance(v, str) for v in custom.values())
    assert not canary.exists()


def test_a_python_tag_in_the_mcap_files_own_metadata_record_runs_nothing(tmp_path):
    # A bare .mcap carries rosbag2's metadata as YAML in a Metadata record.
    from mcap.writer import Writer
    canary = tmp_path / 'created_by_record'
    path = tmp_path / 'evil.mcap'
    with open(path, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='ros2', library='test')
        writer.add_metadata('rosbag2', {'serialized_metadata': (
            'rosbag2_bagfile_information:\n  custom_data: '
            + PYTHON_TAGS[0].format(canary=canary) + '\n')})
        writer.finish()
    warnings = read_everything(path)
    assert any('not YAML' in w.message for w in warnings)
    assert not canary.exists()


# --------------------------------------------------------------------------- state files


@pytest.fixture(scope='module')
def state_bytes():
    """Return a valid estimator state file's bytes."""
    return encode_state(WearEstimator(ReducerParams()).state_dict())


@fuzz(300)
@given(st.one_of(st.binary(max_size=400), st.text(max_size=300).map(str.encode)))
def test_random_bytes_as_a_state_file_raise_state_file_errors_only(data):
    refused_with(StateFileError, decode_state, data)


@fuzz(300)
@given(st.data(), MUTATIONS, st.floats(0.0, 0.5))
def test_a_mutated_state_file_is_refused_or_decodes_to_a_state_that_restores(
        state_bytes, data, edits, cut):
    mutated = mutate(state_bytes, edits, data.draw(st.sampled_from([0.0, cut])))
    state = refused_with(StateFileError, decode_state, mutated)
    if state is not None:
        # The checksum held (e.g. an edit in the indentation): the state is intact.
        est = WearEstimator.from_state(ReducerParams(), state)
        assert math.isfinite(est.wear)


def test_the_shared_bags_are_left_untouched(rosbag2_jazzy_dir, corpus):
    for name, data in corpus.items():
        if not name.startswith('ours/'):
            assert (rosbag2_jazzy_dir / name).read_bytes() == data


JSON_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
              st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=10)),
    lambda kids: st.one_of(st.lists(kids, max_size=3),
                           st.dictionaries(st.text(max_size=8), kids, max_size=3)),
    max_leaves=8)


@fuzz(300)
@given(st.dictionaries(st.sampled_from(sorted(WearEstimator(ReducerParams()).state_dict())),
                       JSON_VALUES, min_size=1, max_size=4))
def test_a_checksummed_state_with_garbled_fields_restores_or_raises_state_file_error(
        state_bytes, changes):
    # A writer bug or another program could produce a well-formed file with a valid
    # checksum around nonsense: restoring must refuse it in words, not crash.
    state = {**decode_state(state_bytes), **changes}
    data = encode_state(state)
    est = refused_with(StateFileError, WearEstimator.from_state, ReducerParams(),
                       decode_state(data))
    if est is not None:
        assert np.isfinite(est.x).all() and np.isfinite(est.P).all()
