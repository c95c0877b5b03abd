"""CDR of the derived topics without ROS: Float64MultiArray layouts and DiagnosticArray."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core.errors import InvalidInput
from reducer_twin.msg_adapters.diagnostic_cdr import encode_diagnostic_array, format_value, Status
from reducer_twin.msg_adapters.layouts import (
    GROUND_TRUTH, LAYOUTS, TE_BATCH, TE_FEATURES, WEAR_ESTIMATE)
from reducer_twin.msg_adapters.multiarray_cdr import decode_layout_batch, decode_multiarray
from reducer_twin.msg_adapters.multiarray_cdr import encode_multiarray, encode_multiarrays
from reducer_twin.msg_adapters.multiarray_cdr import multiarray_columns
from rosbags.typesys import get_typestore, Stores

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
MULTIARRAY = 'std_msgs/msg/Float64MultiArray'
DIAGNOSTICS = 'diagnostic_msgs/msg/DiagnosticArray'


def _reserialised(payload, msgtype):
    """Decode with rosbags and serialise again: rosbags' bytes for the same message."""
    return bytes(TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(payload, msgtype), msgtype))


@pytest.mark.parametrize('layout', list(LAYOUTS.values()), ids=list(LAYOUTS))
def test_every_layout_encodes_byte_identical_to_rosbags(layout):
    rng = np.random.default_rng(1)
    n = len(layout.fields)
    values = rng.normal(size=(7, n)) if layout.batch else rng.normal(size=n)
    payload = encode_multiarray(layout, values)
    assert _reserialised(payload, MULTIARRAY) == payload
    msg = TYPESTORE.deserialize_cdr(payload, MULTIARRAY)
    labels = [(d.label, d.size, d.stride) for d in msg.layout.dim]
    if layout.batch:
        assert labels == [('samples', 7, 7 * n), (layout.label, n, n)]
    else:
        assert labels == [(layout.label, n, n)]
    np.testing.assert_array_equal(np.asarray(msg.data), np.ravel(values))


def test_an_empty_batch_has_no_data_and_no_alignment_padding():
    payload = encode_multiarray(TE_BATCH, np.zeros((0, 4)))
    assert _reserialised(payload, MULTIARRAY) == payload
    decoded = decode_multiarray(payload)
    assert decoded.dims[0] == ('samples', 0, 0) and decoded.data.size == 0


def test_n_messages_at_once_equal_n_single_encodings():
    rng = np.random.default_rng(2)
    values = rng.normal(size=(5, 3, 4))
    buffer, offsets = encode_multiarrays(TE_BATCH, values)
    singles = [encode_multiarray(TE_BATCH, v) for v in values]
    assert [buffer[a:b].tobytes() for a, b in zip(offsets[:-1], offsets[1:])] == singles
    records = rng.normal(size=(3, len(WEAR_ESTIMATE.fields)))
    template, columns = multiarray_columns(WEAR_ESTIMATE, records)
    (offset, dtype, column), = columns
    rows = np.tile(template, (3, 1))
    rows[:, offset:offset + column.shape[1] * 8].view(dtype)[...] = column
    assert [r.tobytes() for r in rows] == [encode_multiarray(WEAR_ESTIMATE, r) for r in records]


def test_decoding_returns_the_values_by_layout_and_stacks_messages():
    rng = np.random.default_rng(3)
    records = rng.normal(size=(4, len(TE_FEATURES.fields)))
    got = decode_layout_batch(TE_FEATURES, [encode_multiarray(TE_FEATURES, r) for r in records])
    np.testing.assert_array_equal(got, records)
    batches = [rng.normal(size=(k, 4)) for k in (3, 0, 5)]
    got = decode_layout_batch(TE_BATCH, [encode_multiarray(TE_BATCH, b) for b in batches])
    np.testing.assert_array_equal(got, np.concatenate(batches))
    assert decode_layout_batch(TE_BATCH, []).shape == (0, 4)


def test_a_big_endian_message_decodes_too():
    msg = TYPESTORE.deserialize_cdr(encode_multiarray(GROUND_TRUTH, np.arange(8.0)), MULTIARRAY)
    big = bytes(TYPESTORE.serialize_cdr(msg, MULTIARRAY, little_endian=False))
    assert big[:2] == b'\x00\x00'
    np.testing.assert_array_equal(decode_multiarray(big).values(GROUND_TRUTH), np.arange(8.0))


@settings(max_examples=40)
@given(rows=st.integers(0, 40), seed=st.integers(0, 2**32 - 1))
def test_any_batch_round_trips_through_cdr(rows, seed):
    values = np.random.default_rng(seed).normal(size=(rows, 4)) * 1e3
    payload = encode_multiarray(TE_BATCH, values)
    np.testing.assert_array_equal(decode_multiarray(payload).values(TE_BATCH), values)


WEAR_ZEROS = np.zeros(len(WEAR_ESTIMATE.fields))

BAD_VALUES = [
    ('batch without rows', TE_BATCH, np.zeros(4)),
    ('batch with a wrong field count', TE_BATCH, np.zeros((3, 5))),
    ('record with a wrong field count', WEAR_ESTIMATE, np.zeros(len(WEAR_ESTIMATE.fields) - 1)),
    ('record given as a batch', WEAR_ESTIMATE, np.zeros((2, len(WEAR_ESTIMATE.fields)))),
]


@pytest.mark.parametrize('layout, values', [row[1:] for row in BAD_VALUES],
                         ids=[row[0] for row in BAD_VALUES])
def test_values_of_the_wrong_shape_are_refused_naming_the_layout(layout, values):
    with pytest.raises(InvalidInput, match=layout.name):
        encode_multiarray(layout, values)


BAD_PAYLOADS = [
    ('empty', b'', 'encapsulation'),
    ('unknown encapsulation', b'\x00\x07\x00\x00\x01\x00\x00\x00', 'encapsulation'),
    ('cut inside the label', encode_multiarray(WEAR_ESTIMATE, WEAR_ZEROS)[:20], 'ends inside'),
    ('cut inside the data', encode_multiarray(WEAR_ESTIMATE, WEAR_ZEROS)[:-8], 'ends inside'),
]


@pytest.mark.parametrize('payload, fragment', [row[1:] for row in BAD_PAYLOADS],
                         ids=[row[0] for row in BAD_PAYLOADS])
def test_malformed_payloads_raise_invalid_input_saying_where(payload, fragment):
    with pytest.raises(InvalidInput, match=fragment):
        decode_multiarray(payload)


def test_a_message_of_another_layout_is_refused_by_label():
    decoded = decode_multiarray(encode_multiarray(WEAR_ESTIMATE, WEAR_ZEROS))
    with pytest.raises(InvalidInput, match='te_features'):
        decoded.values(TE_FEATURES)


def test_diagnostic_arrays_encode_byte_identical_to_rosbags():
    statuses = [Status('WARN', 'reducer_twin: joint_1 reducer', 'remaining life P10 900 h',
                       'joint_1', {'wear_um': 12.3456789, 'rul_p90_censored': False,
                                   'updates': 31, 'lost_motion_obs_arcmin': math.nan}),
                Status('OK', 'reducer_twin: joint_2 reducer', '', 'joint_2', {})]
    payload = encode_diagnostic_array(1_767_225_600_123_456_789, statuses, frame_id='base')
    assert _reserialised(payload, DIAGNOSTICS) == payload
    msg = TYPESTORE.deserialize_cdr(payload, DIAGNOSTICS)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_767_225_600, 123_456_789)
    assert [s.level for s in msg.status] == [1, 0]
    assert [(v.key, v.value) for v in msg.status[0].values] == [
        ('wear_um', '12.3457'), ('rul_p90_censored', 'False'), ('updates', '31'),
        ('lost_motion_obs_arcmin', 'nan')]


def test_values_are_formatted_as_the_live_nodes_format_them():
    assert format_value(0.000123456789) == '0.000123457'
    assert format_value(float('inf')) == 'inf'
    assert format_value(7) == '7' and format_value('text') == 'text'


BAD_DIAGNOSTICS = [
    ('unknown level', 0, [Status('FINE', 'n', 'm', 'h', {})], 'FINE'),
    ('NUL in a value', 0, [Status('OK', 'n', 'm', 'h', {'k': 'a\x00b'})], 'value of k'),
    ('negative stamp', -1, [], 'stamp_ns'),
]


@pytest.mark.parametrize('stamp, statuses, fragment', [row[1:] for row in BAD_DIAGNOSTICS],
                         ids=[row[0] for row in BAD_DIAGNOSTICS])
def test_bad_diagnostics_raise_invalid_input(stamp, statuses, fragment):
    with pytest.raises(InvalidInput, match=fragment):
        encode_diagnostic_array(stamp, statuses)
