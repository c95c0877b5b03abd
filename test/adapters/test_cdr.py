"""The CDR primitives the encoders share, checked against rosbags' serialiser."""

import pytest
from reducer_twin.core.errors import InvalidInput
from reducer_twin.msg_adapters.cdr import align, cdr_string, CdrWriter, ENCAPSULATION
from rosbags.typesys import get_typestore, Stores


@pytest.mark.parametrize('pos, size, expected', [
    (4, 4, 4), (5, 4, 8), (8, 4, 8), (9, 8, 12), (12, 8, 12), (13, 8, 20), (20, 8, 20),
])
def test_alignment_counts_from_the_end_of_the_encapsulation_header(pos, size, expected):
    assert align(pos, size) == expected


def test_a_string_is_its_length_with_the_nul_then_the_bytes_and_the_nul():
    assert cdr_string('µm', 'unit') == b'\x04\x00\x00\x00\xc2\xb5m\x00'
    assert cdr_string('', 'empty') == b'\x01\x00\x00\x00\x00'


@pytest.mark.parametrize('text, fragment', [
    ('a\x00b', 'NUL'), (None, 'must be a str'), (b'bytes', 'must be a str'),
    ('\udcff', 'must be a str'),
])
def test_a_string_that_cannot_be_serialised_raises_invalid_input_naming_it(text, fragment):
    with pytest.raises(InvalidInput, match=f'label.*{fragment}'):
        cdr_string(text, 'label')


def test_the_writer_builds_a_message_rosbags_serialises_identically():
    store = get_typestore(Stores.ROS2_JAZZY)
    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']
    String = store.types['std_msgs/msg/String']
    msg = CdrWriter()
    msg.raw(bytes(8))                 # stamp 0
    msg.string('base_link', 'frame_id')
    assert msg.getvalue() == bytes(store.serialize_cdr(Header(Time(0, 0), 'base_link'),
                                                       'std_msgs/msg/Header'))
    assert msg.getvalue()[:4] == ENCAPSULATION
    text = CdrWriter()
    text.string('x', 'data')
    assert text.getvalue() == bytes(store.serialize_cdr(String('x'), 'std_msgs/msg/String'))


def test_zeros_of_a_wide_type_are_aligned_only_when_there_are_any():
    msg = CdrWriter()
    msg.raw(b'\x01')
    msg.zeros(0, 8)
    assert len(msg) == 5
    msg.zeros(2, 8)
    assert len(msg) == 12 + 16
