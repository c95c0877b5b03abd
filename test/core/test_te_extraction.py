"""TE from encoder pairs, checked against the joint simulator."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from reducer_twin.core.errors import InvalidInput, InvalidParameter
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.te_extraction import compute_te, TEExtractor
from reducer_twin.core.units import ARCSEC, DEG
from te_streams import analyse, PARAMS, RATIO, rms_without_offset, simulated


# -- compute_te and TEExtractor -------------------------------------------------------------

TWO_PI = 2.0 * math.pi


@pytest.mark.parametrize('profile', ['robot', 'paper'])
def test_te_matches_the_simulators_true_te_within_1_arcsec_rms(profile):
    # Issue floor 1 arcsec; expected about 0.2 arcsec from quantisation (0.15 arcsec link
    # counts) and the 1e-6 rad link noise.
    sim, b = simulated(profile=profile)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO,
                        link_time_offset_s=sim.config.time_offset_s)
    assert stream.dropped <= 1                # the last stamp + offset is past the motor stream
    assert rms_without_offset(stream.te - b.true_te) < 0.3 * ARCSEC


def test_fitted_time_offset_is_the_simulated_one_and_removing_it_leaves_the_true_te():
    sim, b = simulated()
    feats = analyse(b)
    delta = np.median([f.time_offset_s for f in feats])
    # 50 us offset seen through 16 arcsec at 90 deg/s and noise of 0.2 arcsec: within 1 us.
    assert delta == pytest.approx(sim.config.time_offset_s, abs=1e-6)
    stream = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO)
    assert rms_without_offset(stream.te - b.true_te) > 3.0 * ARCSEC   # the offset matters
    assert rms_without_offset(stream.te - delta * b.link_velocity - b.true_te) < 0.3 * ARCSEC


def wrapped(angle, how):
    """Wrap an angle stream as some encoders report it."""
    if how == 'signed':
        return np.mod(angle + math.pi, TWO_PI) - math.pi
    if how == 'positive':
        return np.mod(angle, TWO_PI)
    return angle


@settings(max_examples=25)
@given(motor_wrap=st.sampled_from(['none', 'signed', 'positive']),
       link_wrap=st.sampled_from(['none', 'signed', 'positive']),
       holes=st.lists(st.tuples(st.integers(0, 5999), st.integers(1, 400)), max_size=4))
def test_te_is_invariant_to_wrapping_the_input_angles_even_across_gaps(
        motor_wrap, link_wrap, holes):
    _, b = simulated(samples=6000, exact=False)
    keep = np.ones(b.t.size, dtype=bool)
    for start, length in holes:
        keep[start:start + length] = False
    t, motor, link = b.t[keep], b.motor_angle[keep], b.link_angle[keep]
    reference = compute_te(t, motor, t, link, RATIO)
    other = compute_te(t, wrapped(motor, motor_wrap), t, wrapped(link, link_wrap), RATIO)
    np.testing.assert_array_equal(other.valid, reference.valid)
    # Wrapping costs rounding of angles of up to 1e3 rad: 1e-12 rad is far below a count.
    np.testing.assert_allclose(other.te, reference.te, rtol=0, atol=1e-9)
    turns = (other.output_angle - reference.output_angle) / TWO_PI
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-9)


@pytest.mark.parametrize('motor_wrap', ['none', 'signed', 'positive'])
def test_a_fast_motor_across_a_few_lost_samples_is_not_unwrapped_by_a_turn(motor_wrap):
    # At 65 rad/s (0.8 rad/s at the output) a motor turns 3.2 rad over 49 ms of lost
    # messages, less than max_gap_s: that step was read as a wrap, the TE jumped by
    # 2*pi/ratio (267 arcmin) and the windows around read lost motions of 9-42 arcmin.
    t = np.arange(0.0, 1.0, 1e-3)
    speed = 0.8                                           # rad/s at the output
    te_true = 1e-4 * np.sin(5.0 * t)
    link = speed * t + te_true
    motor = RATIO * speed * t
    keep = (t < 0.300) | (t > 0.348)                      # 48 samples lost
    t, link, motor, te_true = t[keep], link[keep], motor[keep], te_true[keep]
    assert (RATIO * speed * 0.049) > math.pi
    stream = compute_te(t, wrapped(motor, motor_wrap), t, link, RATIO, max_gap_s=0.05)
    assert stream.valid.all()
    np.testing.assert_allclose(stream.te - stream.te[0], te_true - te_true[0], atol=1e-9)


def test_motor_angle_is_interpolated_at_link_stamps_that_differ_from_its_own():
    # Linear motion: linear interpolation is exact, so TE is the link's own error.
    t_motor = np.arange(0.0, 1.0, 1e-3)
    t_link = np.arange(0.0004, 0.99, 1e-3)
    speed = 90.0 * DEG
    te_true = 1e-4 * np.sin(3.0 * t_link)
    stream = compute_te(t_motor, RATIO * speed * t_motor, t_link, speed * t_link + te_true, RATIO)
    assert stream.valid.all()
    np.testing.assert_allclose(stream.te, te_true - te_true[0] + stream.te[0], atol=1e-12)
    np.testing.assert_allclose(stream.output_angle, speed * t_link + te_true, atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(steps=st.lists(st.floats(0.5e-3, 1.5e-3), min_size=3, max_size=40),
       offset=st.sampled_from([0.0, 5e-5, -5e-5, 4e-4, -4e-4, 1e-3, -1e-3, 2e-3]))
def test_a_link_stream_read_at_its_stamps_plus_an_offset_interpolates_as_a_binary_search(
        steps, offset):
    # Shared stamps read at the time offset take a shortcut past the binary search for the
    # motor step of each query: the TE must be the one computed with separate stamps.
    t = 10.0 + np.cumsum(steps)
    motor = RATIO * np.sin(3.0 * t)
    link = np.sin(3.0 * t) + 1e-4 * np.cos(7.0 * t)
    shared = compute_te(t, motor, t, link, RATIO, max_gap_s=0.01, link_time_offset_s=offset)
    # The same query stamps with a copy of the motor stamps shifted by nothing take the
    # general path (the arrays differ in length by one sample that is never queried).
    t_m = np.append(t, t[-1] + 1.0)
    general = compute_te(t_m, np.append(motor, motor[-1]), t, link, RATIO, max_gap_s=0.01,
                         link_time_offset_s=offset)
    in_span = t + offset <= t[-1]
    np.testing.assert_array_equal(shared.valid[in_span], general.valid[in_span])
    np.testing.assert_allclose(shared.te[in_span], general.te[in_span], rtol=0, atol=1e-15)


def test_link_samples_inside_a_motor_gap_are_dropped_not_interpolated():
    t = np.arange(0.0, 0.1, 1e-3)
    motor_keep = (t < 0.030) | (t > 0.050)            # a 21 ms hole in the motor stream
    t_link = t + 0.0005
    stream = compute_te(t[motor_keep], 81.0 * t[motor_keep], t_link, t_link, RATIO,
                        max_gap_s=0.005)
    inside = (t_link > 0.029) & (t_link < 0.051)
    assert not stream.valid[inside].any()
    assert stream.valid[~inside & (t_link < t[-1])].all()
    assert stream.link_uncovered == np.count_nonzero(~stream.valid)
    assert np.isnan(stream.te[inside]).all()


def test_nan_angles_and_non_increasing_stamps_are_dropped_and_counted():
    t = np.arange(10) * 1e-3
    motor = np.arange(10) * 0.1
    link = motor / RATIO
    t_link = t.copy()
    t_link[4] = t_link[3]            # duplicate stamp
    t_link[7] = 0.0                  # stamp going back
    link = link.copy()
    link[2] = np.nan
    motor = motor.copy()
    motor[5] = np.inf
    stream = compute_te(t, motor, t_link, link, RATIO)
    assert (stream.link_nonfinite, stream.link_unordered) == (1, 2)
    assert (stream.motor_nonfinite, stream.motor_unordered) == (1, 0)
    assert not stream.valid[[2, 4, 7]].any()
    assert stream.valid[[0, 1, 3, 5, 6, 8, 9]].all()   # sample 5 interpolated over 2 ms
    np.testing.assert_allclose(stream.te[stream.valid], 0.0, atol=1e-15)
    assert stream.dropped == 3 and len(stream) == 10


def test_an_empty_stream_gives_an_empty_te():
    stream = compute_te([], [], [], [], RATIO)
    assert len(stream) == 0 and stream.dropped == 0


BAD_ARRAYS = [
    ('motor stamps and angles must have the same length', ([0.0, 1.0], [0.0], [0.0], [0.0])),
    ('link stamps and angles must have the same length', ([0.0], [0.0], [0.0, 1.0], [0.0])),
    ('must be 1-D', (np.zeros((2, 2)), np.zeros((2, 2)), [0.0], [0.0])),
    ('must be numeric', (['a'], [0.0], [0.0], [0.0])),
]


@pytest.mark.parametrize('match, arrays', BAD_ARRAYS)
def test_malformed_arrays_raise_invalid_input(match, arrays):
    with pytest.raises(InvalidInput, match=match):
        compute_te(*arrays, RATIO)


@pytest.mark.parametrize('kw, match', [
    ({'ratio': 0.0}, 'ratio must be finite and non-zero'),
    ({'ratio': float('nan')}, 'ratio'),
    ({'max_gap_s': 0.0}, r'max_gap_s must be > 0 s, got 0.0'),
    ({'max_gap_s': -1.0}, 'max_gap_s'),
    ({'link_time_offset_s': float('inf')}, 'link_time_offset_s must be finite s'),
])
def test_out_of_range_settings_raise_invalid_parameter(kw, match):
    args = {'ratio': RATIO, **kw}
    with pytest.raises(InvalidParameter, match=match):
        compute_te([0.0, 1e-3], [0.0, 0.1], [0.0, 1e-3], [0.0, 0.001],
                   args.pop('ratio'), **args)


def test_chunks_through_the_extractor_agree_even_with_the_te_near_half_a_motor_turn():
    # A link zero offset that puts the TE constant at pi/i: compute_te alone may pick
    # either side per chunk; TEExtractor keeps the chunks continuous.
    cfg = SimConfig(exact_mesh=False, link_zero_offset_rad=math.pi / RATIO, seed=2)
    b = JointSimulator(PARAMS, cfg).step(5000)
    whole = compute_te(b.t, b.motor_angle, b.t, b.link_angle, RATIO).te
    extractor = TEExtractor(RATIO)
    parts = [extractor.update(b.t[sl], b.motor_angle[sl], b.t[sl], b.link_angle[sl]).te
             for sl in (slice(k, k + 700) for k in range(0, 5000, 700))]
    np.testing.assert_allclose(np.concatenate(parts), whole, rtol=0, atol=1e-12)


def test_a_chunked_extractor_with_a_time_offset_loses_no_sample():
    # The last link sample of a chunk needs the motor angle delta after the chunk's last
    # motor sample; it is extrapolated over delta instead of being dropped.
    params = ReducerParams()
    sim = JointSimulator(params, SimConfig(exact_mesh=False, aging_factor=1e5, seed=4))
    extractor = TEExtractor(81.0, link_time_offset_s=50e-6)
    errors = []
    for _ in range(100):
        batch = sim.step(5)
        stream = extractor.update(batch.t, batch.motor_angle, batch.t, batch.link_angle)
        assert stream.valid.all()
        errors.append(stream.te - batch.true_te)
    error = np.concatenate(errors)
    # Encoder resolution and noise leave ~0.22 arcsec RMS (bench); 0.5 arcsec bounds it.
    assert np.std(error) < 0.5 * ARCSEC


# -- pairing link and motor samples of one controller tick ----------------------------------

def controller_streams(stamps_are_true, seed=3, rate_hz=1000.0, duration_s=3.0, jitter_s=30e-6):
    """
    Link and motor encoders of one joint swinging at up to 1.5 rad/s, on stamps of their own.

    ``stamps_are_true=False``: both encoders are read on the controller tick ``k/rate`` and
    each topic's stamp adds its own jitter (ros2_control publishing). True: each encoder is
    read at its own jittered instant and the stamp is that instant, exactly. Encoder noise:
    0.1 µrad on the link, 2 µrad on the motor (0.025 µrad at the output). Returns
    ``(t_motor, motor, t_link, link, te_true)`` with the true TE at the link samples [rad].
    """
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz)
    tick = np.arange(n) / rate_hz
    jit_l, jit_m = (rng.normal(0.0, jitter_s, n) for _ in range(2))

    def q(t):
        return 0.5 * np.sin(3.0 * t) + 0.2 * np.sin(7.0 * t)

    def te(t):
        return 2e-4 * np.sin(q(t)) + 5e-5 * np.tanh(50.0 * np.cos(3.0 * t))

    t_l, t_m = (tick + jit_l, tick + jit_m) if stamps_are_true else (tick, tick)
    link = q(t_l) + te(t_l) + rng.normal(0.0, 1e-7, n)
    motor = RATIO * q(t_m) + rng.normal(0.0, 2e-6, n)
    stamp_l, stamp_m = tick + jit_l, tick + jit_m
    return stamp_m, motor, stamp_l, link, te(t_l)


def te_in_chunks(extractor, streams, chunk=250):
    """TE of ``controller_streams`` fed to an extractor in chunks of ``chunk`` samples."""
    t_m, motor, t_l, link, _ = streams
    parts = [extractor.update(t_m[a:a + chunk], motor[a:a + chunk], t_l[a:a + chunk],
                              link[a:a + chunk]) for a in range(0, t_l.size, chunk)]
    return np.concatenate([p.te for p in parts])


def interpolated_te(streams):
    """TE of ``controller_streams`` with the motor angle always interpolated (no tick rule)."""
    extractor = TEExtractor(RATIO)
    extractor.ticks = None
    return te_in_chunks(extractor, streams)


def through_the_tick_rule(stamps_are_true):
    """Streams of ``controller_streams``, the extractor they went through and its TE."""
    streams = controller_streams(stamps_are_true=stamps_are_true)
    extractor = TEExtractor(RATIO)
    return streams, extractor, te_in_chunks(extractor, streams)


def test_jittered_stamps_of_one_tick_are_paired_by_tick_and_leave_encoder_level_te_noise():
    streams, extractor, te = through_the_tick_rule(stamps_are_true=False)
    assert extractor.ticks.pairing == 'tick'
    assert 'jitter' in extractor.ticks.reason()
    err = (te - streams[4])[250:]          # from the second chunk on (the first decides)
    # At the level of the encoders (0.1 µrad link, 0.025 µrad motor at the output): interpolating
    # 30 µs of jitter per stamp at up to 1.5 rad/s left 30 µrad (0.1 arcmin) of TE noise.
    assert rms_without_offset(err) < 0.5e-6
    assert rms_without_offset(interpolated_te(streams)[250:] - streams[4][250:]) > 10e-6


def test_true_stamps_of_jittered_sampling_instants_keep_the_interpolation():
    streams, extractor, te = through_the_tick_rule(stamps_are_true=True)
    assert extractor.ticks.decided == 'interpolate'
    assert 'sample times' in extractor.ticks.reason()
    assert extractor.ticks.tick_paired == 0
    np.testing.assert_array_equal(te, interpolated_te(streams))
    assert rms_without_offset(te - streams[4]) < 0.5e-6


def test_streams_at_different_rates_are_interpolated_and_say_why():
    t_m, motor, t_l, link, te_true = controller_streams(stamps_are_true=False)
    extractor = TEExtractor(RATIO)
    stream = extractor.update(t_m[::2], motor[::2], t_l, link)
    assert extractor.ticks.pairing == 'interpolate' and extractor.ticks.decided is None
    assert 'different rates' in extractor.ticks.reason()
    assert stream.valid[1:-2].all()     # the motor stream covers all but the ends


def test_a_standing_joint_gives_no_evidence_and_stays_interpolated():
    t_m, motor, t_l, link, _ = controller_streams(stamps_are_true=False)
    extractor = TEExtractor(RATIO)
    still = np.full(t_l.size, 0.3)
    te_in_chunks(extractor, (t_m, RATIO * still, t_l, still + 1e-5, None))
    assert extractor.ticks.decided is None
    assert 'not enough evidence' in extractor.ticks.reason()


def test_a_learnt_time_offset_reads_the_tick_pair_along_the_motor_motion():
    # Link encoder read 50 µs after the motor one on the same tick (the simulator's offset),
    # stamps jittered: with the offset given, the TE is the true one again.
    t_m, motor, t_l, link, _ = controller_streams(stamps_are_true=False)
    delta = 50e-6
    tick = np.arange(t_l.size) / 1000.0

    def q(t):
        return 0.5 * np.sin(3.0 * t) + 0.2 * np.sin(7.0 * t)

    link_late = link - q(tick) + q(tick + delta)
    extractor = TEExtractor(RATIO)
    te_in_chunks(extractor, (t_m, motor, t_l, link_late, None))
    assert extractor.ticks.pairing == 'tick'
    extractor.link_time_offset_s = delta
    te = te_in_chunks(extractor, (t_m, motor, t_l, link_late, None))
    tick_te = link_late - motor / RATIO
    naive = rms_without_offset(tick_te - (link - motor / RATIO))
    assert naive > 20e-6      # the offset is visible: omega * delta, up to 75 µrad
    # Read along the motor's motion between tick pairs on jittered stamps (a speed 3 % off
    # per step at 30 µs in 1 ms): what is left is a few percent of omega * delta.
    assert rms_without_offset(te - (link - motor / RATIO)) < 0.15 * naive
