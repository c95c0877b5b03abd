"""
The pairing of a joint's motor and link samples (Pairer, pair_columns, pair_same_stamps).

Link and motor streams are built by hand at 1 kHz (and 500 Hz on the motor side), cleaned
by the stage's cleaner, then paired: interpolated at the link stamps, held while the motor
stream may still cover them, given up when it stalls, never across a gap.
"""

from encoder_streams import CFG, clean, motor_at, MS, ramp, RATIO, T0
import numpy as np
import pytest
from reducer_twin.core.ingest import StreamCleaner
from reducer_twin.core.pairing import pair_columns, pair_same_stamps, Pairer


def test_a_500hz_motor_stream_is_interpolated_at_the_1khz_link_stamps():
    t_link, link = ramp(400)
    t_motor = T0 + np.arange(0, 200, dtype=np.int64) * 2 * MS + 300_000   # 0.3 ms late
    pairer = Pairer()
    pairer.add_link(clean(t_link, link))
    pairer.add_motor(clean(t_motor, motor_at(t_motor)))
    pairs = pairer.pop(final=True)
    inside = (t_link >= t_motor[0]) & (t_link <= t_motor[-1])
    np.testing.assert_array_equal(pairs.t_ns, t_link[inside])
    np.testing.assert_allclose(pairs.motor_angle, motor_at(t_link[inside]), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(pairs.link_angle, link[inside])
    assert pairer.unpaired == int(np.count_nonzero(~inside)) == 2


def test_shared_stamps_pair_exactly_and_motor_angles_are_scaled():
    t, link = ramp(100)
    motor_out = link.copy()             # a vendor that reports motor angles / ratio
    pairer = Pairer(motor_scale=RATIO)
    pairer.add_link(clean(t, link))
    pairer.add_motor(clean(t, motor_out))
    pairs = pairer.pop()
    np.testing.assert_array_equal(pairs.t_ns, t)
    np.testing.assert_allclose(pairs.motor_angle, RATIO * link, rtol=1e-15)
    rows = pairs.as_rows(T0)
    assert rows.shape == (100, 5)
    np.testing.assert_allclose(rows[:, 0], (t - T0) * 1e-9)


def test_link_samples_ahead_of_the_motor_stream_wait_for_it():
    t_link, link = ramp(40)
    t_motor = t_link[::2]
    pairer = Pairer()
    pairer.add_link(clean(t_link, link))
    pairer.add_motor(clean(t_motor[:10], motor_at(t_motor[:10])))
    first = pairer.pop()
    assert len(first) == 19 and pairer.unpaired == 0, 'samples after the motor horizon wait'
    pairer.add_motor(clean(t_motor[10:], motor_at(t_motor[10:])))
    second = pairer.pop()
    np.testing.assert_array_equal(np.concatenate([first.t_ns, second.t_ns]), t_link[:39])
    assert pairer.unpaired == 0
    pairer.pop(final=True)
    assert pairer.unpaired == 1, 'the last link sample is past the last motor sample'


def test_link_samples_are_given_up_when_the_motor_stream_stalls_for_max_gap():
    # The motor topic dies after 10 ms: link samples that no motor sample covered while the
    # link stream ran on for max_gap_s are unpaired, not held (and buffered) for ever.
    t_link, link = ramp(200)
    gap = int(CFG.max_gap_s * 1e9)
    pairer = Pairer()
    pairer.add_motor(clean(t_link[:10], motor_at(t_link[:10])))
    pairer.add_link(clean(t_link, link))
    pairs = pairer.pop()
    np.testing.assert_array_equal(pairs.t_ns, t_link[:10])
    given_up = (t_link > t_link[9]) & (t_link < t_link[-1] - gap)
    assert pairer.unpaired == int(np.count_nonzero(given_up)) == 139
    assert len(pairer._link) == 200 - 10 - 139


def test_link_samples_are_given_up_when_no_motor_sample_ever_arrives():
    t_link, link = ramp(200)
    pairer = Pairer()
    pairer.add_link(clean(t_link, link))
    assert len(pairer.pop()) == 0
    assert pairer.unpaired == 149 and len(pairer._link) == 51


def test_no_interpolation_across_a_gap_of_the_motor_stream():
    t_link, link = ramp(400)
    t_motor = t_link[::2]
    hole = (t_motor > T0 + 150 * MS) & (t_motor < T0 + 230 * MS)   # 80 ms: a new segment
    cleaner = StreamCleaner()
    # A slow joint: the motor turns 1.6 rad during the gap (a fast one: the next test).
    motor = clean(t_motor[~hole], motor_at(t_motor[~hole], speed=20.0), cleaner)
    assert cleaner.counts['gap'] == 1
    pairer = Pairer()
    pairer.add_link(clean(t_link, link))
    pairer.add_motor(motor)
    pairs = pairer.pop(final=True)
    lo, hi = t_motor[~hole][t_motor[~hole] <= T0 + 150 * MS][-1], t_motor[hole][-1] + 2 * MS
    across = (t_link > lo) & (t_link < hi)
    np.testing.assert_array_equal(pairs.t_ns, t_link[~across][:-1])
    assert pairer.unpaired == int(np.count_nonzero(across)) + 1
    np.testing.assert_allclose(pairs.motor_angle, motor_at(pairs.t_ns, speed=20.0),
                               rtol=0, atol=1e-9)


@pytest.mark.parametrize('link_chunk, motor_chunk', [(2, 1), (1, 1), (7, 3), (50, 40)])
def test_pairing_chunk_by_chunk_equals_pairing_at_once(link_chunk, motor_chunk):
    t_link, link = ramp(300)
    t_motor = T0 + np.arange(150, dtype=np.int64) * 2 * MS + 300_000
    once = Pairer()
    once.add_link(clean(t_link, link))
    once.add_motor(clean(t_motor, motor_at(t_motor)))
    expected = once.pop(final=True)
    live = Pairer()
    link_cleaner, motor_cleaner = StreamCleaner(), StreamCleaner()
    got, k, j = [], 0, 0
    while k < t_link.size or j < t_motor.size:
        live.add_link(clean(t_link[k:k + link_chunk], link[k:k + link_chunk], link_cleaner))
        live.add_motor(clean(t_motor[j:j + motor_chunk], motor_at(t_motor[j:j + motor_chunk]),
                             motor_cleaner))
        k, j = k + link_chunk, j + motor_chunk
        got.append(live.pop())
    got.append(live.pop(final=True))
    np.testing.assert_array_equal(np.concatenate([p.t_ns for p in got]), expected.t_ns)
    np.testing.assert_allclose(np.concatenate([p.motor_angle for p in got]),
                               expected.motor_angle, rtol=0, atol=1e-12)
    assert live.unpaired == once.unpaired


def test_pop_without_motor_samples_holds_recent_link_samples_until_the_end():
    t, link = ramp(10)
    pairer = Pairer()
    pairer.add_link(clean(t, link))
    assert len(pairer.pop()) == 0 and pairer.unpaired == 0
    assert len(pairer.pop(final=True)) == 0 and pairer.unpaired == 10


def test_pair_columns_pairs_rows_where_both_sides_are_valid():
    t, link = ramp(30)
    pos = np.column_stack([link, RATIO * link, 2 * link, 2 * RATIO * link])
    pos[4, 1] = np.nan                  # joint 1: motor missing
    pos[9, 0] = np.nan                  # joint 1: link missing
    pos[12, 2:] = np.nan                # joint 2: both missing (not unpaired: nothing arrived)
    stream = StreamCleaner().process(t, pos)
    cols, unpaired = pair_columns(stream, 0, 1)
    np.testing.assert_array_equal(cols[0], np.delete(t, [4, 9]))
    np.testing.assert_array_equal(cols[1], np.delete(RATIO * link, [4, 9]))
    assert unpaired == 2
    cols, unpaired = pair_columns(stream, 2, 3, motor_scale=0.5)
    np.testing.assert_array_equal(cols[0], np.delete(t, 12))
    np.testing.assert_allclose(cols[1], np.delete(RATIO * link, 12))
    assert unpaired == 0


def test_pair_same_stamps_pairs_the_common_stamps_only():
    t, link = ramp(30)
    a = clean(t, link)
    b = clean(np.delete(t, [3, 4]), np.delete(RATIO * link, [3, 4]))
    pairs, unpaired = pair_same_stamps(a, b)
    np.testing.assert_array_equal(pairs.t_ns, np.delete(t, [3, 4]))
    assert unpaired == 2
    pairs, unpaired = pair_same_stamps(a, clean(t, RATIO * link), motor_scale=2.0)
    np.testing.assert_allclose(pairs.motor_angle, 2.0 * RATIO * link)
    assert unpaired == 0


def test_a_held_link_sample_is_paired_when_its_motor_partner_comes_seconds_later():
    # Offline, a bag can log the motor topic seconds after the link topic: with a hold of
    # 60 s nothing is given up at a chunk boundary; live (default hold) a stalled motor
    # topic must not hold the link for longer than max_gap_s.
    t, link = ramp(3000)
    offline, live = Pairer(hold_s=60.0), Pairer()
    for pairer in (offline, live):
        pairer.add_link(clean(t, link))
        assert len(pairer.pop()) == 0
        pairer.add_motor(clean(t, motor_at(t)))
    assert len(offline.pop(final=True)) == 3000 and offline.unpaired == 0
    assert live.unpaired > 2900


def test_a_split_pairer_reads_the_motor_effort_at_the_link_stamps():
    t, link = ramp(100)
    motor = StreamCleaner().process(t, motor_at(t)[:, None], None, np.full((100, 1), 2.0))
    pairer = Pairer(effort='motor', motor_effort_scale=RATIO)
    pairer.add_link(clean(t, link))
    pairer.add_motor(motor.column(0))
    pairs = pairer.pop(final=True)
    np.testing.assert_allclose(pairs.effort, 2.0 * RATIO)
