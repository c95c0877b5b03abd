"""Spec: the words of a joint (:mod:`reducer_twin.analysis.joint_words`) from plain values."""

import numpy as np
from reducer_twin.analysis import joint_words
from reducer_twin.core.params import ReducerParams
from reducer_twin.msg_adapters.layouts import WEAR_ESTIMATE


def test_a_swap_names_both_entries_and_the_motor_topic_when_split():
    line = joint_words.swap_reason('joint_1', 'joint_1', '/motor_states', 80.4, 81.0)
    assert line.startswith('its link entry joint_1 moves 80.4 times its motor entry '
                           '/motor_states joint_1, where a motor moves about 81 times')
    assert 'entry joint_1_motor' in joint_words.swap_reason('joint_1', 'joint_1_motor', None,
                                                            80.4, 81.0)


def test_a_stream_that_cannot_be_read_is_said_in_order_of_its_causes():
    span = [0, 10_000_000_000]
    frozen = {'stream_duplicate': 900, 'spike': 0}
    assert joint_words.stream_reason(['stream'], frozen, 100, span, 0.05, '/js', None) \
        .startswith('stamps do not advance on /js: 900 samples')
    slow = joint_words.stream_reason(['stream'], {}, 101, span, 0.05, '/js', None)
    assert slow.startswith('its samples on /js are 0.100 s apart on average (10 Hz)')
    spikes = joint_words.stream_reason(['stream'], {'spike': 5000}, 4000, span, 0.05, '/js',
                                       None)
    assert spikes.startswith('5000 of 9000 motor/link sample pairs were dropped as spikes')
    assert joint_words.stream_reason(['link', 'motor'], {'unpaired': 7}, 0, None, 0.05,
                                     '/js', '/ms') == \
        'no motor/link sample pairs on /js and /ms (7 unpaired)'
    assert joint_words.stream_reason(['stream'], {}, 10_000, span, 0.05, '/js', None) is None


def test_malformed_effort_arrays_are_named_only_before_a_missing_effort():
    faults = {'/js': (3, 'effort[] has 2 entries for 4 names')}
    said = joint_words.effort_faults_reason('no effort on /js', faults, {'/js': 1000})
    assert said == ('3 of 1,000 JointState messages on /js are malformed: effort[] has 2 '
                    'entries for 4 names; their efforts are not read: no effort on /js')
    assert joint_words.effort_faults_reason('stamps do not advance', faults, {'/js': 1}) == \
        'stamps do not advance'
    assert joint_words.effort_faults_reason(None, faults, {'/js': 1}) is None


def test_holes_are_said_from_a_share_of_the_stream():
    span = [0, 100_000_000_000]     # 100 s
    assert joint_words.gaps_line(4.0, 2, span, 0.05) is None
    assert joint_words.gaps_line(6.0, 0, span, 0.05) is None
    line = joint_words.gaps_line(6.0, 1, span, 0.05)
    assert line.startswith('6.0 s of its 100.0 s stream (6 %) fall in 1 hole longer than')


def test_an_estimate_is_partial_when_its_joint_stops_early_or_lacks_effort():
    spans = [[0, 50_000_000_000], [0, 100_000_000_000]]
    early = joint_words.partial_reason('joint_1', spans[0], spans, 1.0, None, 40.0, 0, 10,
                                       '/js')
    assert early.startswith('its samples stop 50.0 s before the recording ends')
    stale = joint_words.partial_reason('joint_2', spans[1], spans, 1.0, (30.0, 'why', True),
                                       70.0, 0, 10, '/js')
    assert stale.startswith('no lost motion in the last 30 % of the stream (after 70.0 s '
                            'of 100.0 s): why;')
    assert 'in 3 of 10 samples' in joint_words.partial_reason(
        'joint_2', spans[1], spans, 1.0, None, 99.0, 3, 10, '/js')
    assert joint_words.partial_reason('joint_2', spans[1], spans, 1.0, None, 99.0, 1, 10,
                                      '/js') is None
    assert joint_words.stale_after_s(spans[1], 1.0) == 0.2 * 100.0


def test_the_last_service_judgement_is_kept_and_each_refusal_said():
    outputs = [{}, {'service': (False, 1.0, 'not taken: hours?', 5.0)},
               {'service': (True, 0.8, 'taken', 5.0)}]
    assert joint_words.service_taken(outputs) == (
        {'hours': 5.0, 'taken': True, 'rate_scale': 0.8}, ['not taken: hours?'])
    assert joint_words.service_taken([{}]) == (None, [])


def test_a_front_state_of_another_version_is_said_and_only_its_offset_carried():
    params = ReducerParams()
    assert joint_words.carried_front(None, params) == ({'time_offset_s': None}, None)
    carried, line = joint_words.carried_front(
        {'time_offset_s': 0.005, 'front': {'kind': 'other', 'version': 0}}, params)
    assert carried == {'time_offset_s': 0.005}
    assert line.startswith('what its last bag learnt of the encoders and the soft zone is '
                           'not usable (') and line.endswith('): learnt afresh from this bag')


def test_stream_warnings_say_a_loss_of_one_percent_or_more():
    assert joint_words.out_of_order_line(9, 1000, '/js') is None
    assert joint_words.out_of_order_line(10, 1000, '/js').startswith(
        '10 of 1,000 JointState messages on /js were logged after a later stamp')
    assert joint_words.ingest_status(0) == ('OK', 'streams clean')
    assert joint_words.ingest_status(3) == ('WARN', '3 samples dropped or repaired')


def test_an_alarm_on_the_loaded_flanks_play_says_the_test_torque_was_not_compared():
    line = 'no window held the load at the lost-motion test torque ...'
    wear = np.zeros((3, len(WEAR_ESTIMATE.fields)))
    said = joint_words.not_compared_line
    assert said(True, ['OK', 'ERROR'], wear, line) == line
    assert said(True, ['ERROR', 'WARN'], wear, line) == line
    # A clean answer, a joint not observed, nothing to say: no line.
    assert said(True, ['WARN', 'OK'], wear, line) is None
    assert said(False, ['ERROR'], wear, line) is None
    assert said(True, ['ERROR'], wear, None) is None
    # A soft zone carried over from the reducer's last recording gives the lost motion at
    # the test torque already.
    wear[-1, WEAR_ESTIMATE.fields.index('soft_zone_shortfall_rad')] = 1e-4
    assert said(True, ['ERROR'], wear, line) is None


def _wear_with_shortfall(shortfall):
    wear = np.zeros((1, len(WEAR_ESTIMATE.fields)))
    wear[0, WEAR_ESTIMATE.fields.index('soft_zone_shortfall_rad')] = shortfall
    return wear


def test_what_an_earlier_bag_found_at_the_test_torque_is_said_until_this_one_shows_it():
    # A soft zone (a positive shortfall) or loads within one (negative) carried over from
    # the reducer's last bag: said while this bag's own check has not shown the same.
    soft = joint_words.soft_zone_carried_line(None, _wear_with_shortfall(4e-4))
    assert 'the soft zone an earlier recording of this reducer found' in soft
    within = joint_words.soft_zone_carried_line(None, _wear_with_shortfall(-2e-4))
    assert "its loads within a soft zone (the flanks' reading plus 0.69 arcmin)" in within
    assert joint_words.soft_zone_carried_line({'width': 1.0}, _wear_with_shortfall(4e-4)) \
        is None
    assert joint_words.soft_zone_carried_line(None, _wear_with_shortfall(-2e-4),
                                              'the lost motion read ...') is None
    # The other finding does not stand for it.
    assert joint_words.soft_zone_carried_line(None, _wear_with_shortfall(4e-4),
                                              'the lost motion read ...') == soft
    assert joint_words.soft_zone_carried_line(None, _wear_with_shortfall(0.0)) is None
