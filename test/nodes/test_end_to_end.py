"""
The whole twin in one process: simulator, ingest, TE monitors, wear estimators, life publishers.

``twin_bringup.build_nodes`` builds the chain from the packaged
``config/twin.yaml`` (two joints) with the joint simulator switched on; an
aging factor of 5.4e5 compresses 3000 operating hours into 20 s of a 1 kHz
stream. The estimate must approach the simulator's hidden truth, no sample
may be lost between the simulator and the TE, and the remaining life and
the reducers' health must reach ``/diagnostics``. Real DDS between the nodes,
one executor, as ``twin_bringup`` runs them (the ingest hands its pairs to the
TE monitors in process, ``twin.intra_process``; the last test runs that hop
over DDS instead). The chain runs once per module;
each test checks one promise of that run.
"""

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.units import HOUR
from reducer_twin.io.state_file import decode_state
from reducer_twin.msg_adapters.layouts import REMAINING_LIFE
from reducer_twin.msg_adapters.ros import from_multiarray
from reducer_twin.nodes.runtime import WORKER
from reducer_twin.nodes.twin_bringup import build_nodes, default_config, load_config
from std_msgs.msg import Float64MultiArray

pytestmark = pytest.mark.timeout(120, method='thread')

HOURS = 3000.0
STREAM_S = 20.0
SCALES = [1.0, 0.8]
"""Hidden Archard-rate multipliers of the two joints (the estimator must learn them)."""


@pytest.fixture(scope='module')
def twin(default_ros, tmp_path_factory):
    """
    Run the chain for 20 s of stream.

    Returns
    -------
    dict
        ``nodes`` (of build_nodes), ``joints``, ``state_dir`` and what a
        probe heard: ``life`` (remaining_life per joint) and ``diagnostics``.

    """
    ros = default_ros
    state_dir = tmp_path_factory.mktemp('state') / 'reducer_twin'   # not made yet
    config = load_config(default_config())
    joints = config['twin']['joints']
    config['twin'].update({'simulate': True, 'aging_factor': HOURS * HOUR / STREAM_S,
                           'state_dir': str(state_dir)})
    config['simulator'].update({'wear_rate_scales': SCALES})
    probe = ros.probe()
    late = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)
    life = {j: probe.listen(joint_topic(j, 'remaining_life'), Float64MultiArray, late)
            for j in joints}
    diagnostics = probe.listen('/diagnostics', DiagnosticArray,
                               QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                                          reliability=ReliabilityPolicy.RELIABLE))
    nodes = build_nodes(config, sim_overrides=[Parameter('sim.seed', value=3)])
    ingest, sim = nodes['ingest'], nodes['simulator']
    for node in [sim, ingest, *nodes['te'].values(), *nodes['estimator'].values(),
                 *nodes['life'].values()]:
        ros.add(node)
    # In one process the ingest hands its pairs to the TE monitors directly (intra_process).
    assert all(out.sinks for out in ingest.outputs.values())
    ros.wait_matched(sim.pub)
    ros.spin_until(lambda: sim.sent >= STREAM_S * sim.rate_hz, timeout=STREAM_S + 25.0,
                   what=f'{STREAM_S:g} s of simulated stream')
    ros.remove(sim)                                     # the robot stops

    def delivered():
        counts = ingest.counts()
        return all(counts[j]['published'] == sim.sent == nodes['te'][j].samples
                   for j in joints)

    # The last batch goes out on the ingest's stale-batch timer; then the monitors analyse
    # what they hold and the last windows reach the estimators and life publishers.
    ros.spin_until(delivered, what='every simulated sample at the TE monitors')
    for te in nodes['te'].values():
        te.analyze_now()
    ros.spin_for(0.5)
    WORKER.wait_idle()              # the last windows' updates, published from the worker
    ros.spin_for(0.5)
    return {'nodes': nodes, 'joints': joints, 'state_dir': state_dir, 'life': life,
            'diagnostics': diagnostics, 'ros': ros}


def test_the_wear_estimate_approaches_the_simulators_truth(twin):
    nodes = twin['nodes']
    truth = nodes['simulator'].truth()
    for joint, scale in zip(twin['joints'], SCALES):
        est = nodes['estimator'][joint].stage.estimator
        assert est.updates >= 5, f'{joint}: {est.updates} windows used'
        assert truth[joint].wear_rate_scale == scale
        assert est.wear == pytest.approx(truth[joint].wear, rel=0.25), joint
        assert est.exposure_s == pytest.approx(truth[joint].exposure_s, rel=0.25)


def test_no_sample_is_lost_between_the_simulator_and_the_te(twin):
    nodes = twin['nodes']
    sent = nodes['simulator'].sent
    for joint in twin['joints']:
        counts = nodes['ingest'].counts()[joint]
        assert {k: v for k, v in counts.items() if k.endswith('_missing')} == {
            'stream_missing': 0}
        assert counts['unpaired'] == 0
        assert counts['stream_non_finite'] == counts['spike'] == 0
        assert counts['published'] == sent
        assert nodes['te'][joint].samples == sent
        assert nodes['te'][joint].rejects.total == 0
    assert nodes['ingest'].rejects.total == 0


def test_remaining_life_is_finite_and_ordered(twin):
    for joint in twin['joints']:
        assert twin['life'][joint], f'no remaining_life of {joint}'
        rec = from_multiarray(twin['life'][joint][-1], REMAINING_LIFE)
        assert 0.0 < rec['p10_s'] <= rec['p50_s'] <= rec['p90_s'] < math.inf
        assert rec['p10_censored'] == 0.0
        assert math.isfinite(rec['catalogue_life_s'])
        summary = twin['nodes']['life'][joint].summary()
        assert summary['rul_p10_h'] == pytest.approx(rec['p10_s'] / HOUR)


def test_diagnostics_carry_the_reducer_status_of_every_joint(twin):
    ros = twin['ros']
    for joint in twin['joints']:
        reducer = ros.statuses(twin['diagnostics'], f'reducer_twin: {joint} reducer')
        assert reducer, f'no reducer status of {joint}'
        status = reducer[-1]
        assert status.hardware_id == joint
        assert status.level == DiagnosticStatus.OK, status.message
        values = ros.key_values(status)
        assert float(values['wear_um']) > 0.0
        assert float(values['rul_p10_h']) > 0.0
        assert float(values['exposure_h']) > 0.5 * HOURS
        for name in (f'reducer_twin: {joint} encoder ingest',
                     f'reducer_twin: {joint} transmission error',
                     f'reducer_twin: {joint} wear estimator'):
            found = ros.statuses(twin['diagnostics'], name)
            assert found and found[-1].level == DiagnosticStatus.OK, name


def test_each_estimator_and_te_monitor_saved_its_state_in_the_state_dir(twin):
    for joint in twin['joints']:
        path = twin['state_dir'] / f'{joint}.json'
        state = decode_state(path.read_bytes(), path)
        assert state['counters']['updates'] == (
            twin['nodes']['estimator'][joint].stage.estimator.updates)
        monitor = twin['nodes']['te'][joint]
        monitor.close()     # its last batch's state written
        path = twin['state_dir'] / f'{joint}.te_monitor.json'
        state = decode_state(path.read_bytes(), path, 'reducer_twin.front_state')
        assert state['windows'] == monitor.windows > 0
        assert state['time_offset_s'] == monitor.twin.calibration.to_carry


def test_without_intra_process_the_pairs_cross_dds_and_none_is_lost(default_ros, tmp_path):
    ros = default_ros
    config = load_config(default_config())
    joint = config['twin']['joints'][0]
    config['twin'].update({'simulate': True, 'intra_process': False, 'joints': [joint],
                           'aging_factor': 3600.0, 'state_dir': str(tmp_path)})
    nodes = build_nodes(config, sim_overrides=[Parameter('sim.seed', value=5)])
    ingest, sim, te = nodes['ingest'], nodes['simulator'], nodes['te'][joint]
    assert not ingest.outputs[joint].sinks
    for node in [ingest, te, nodes['estimator'][joint], nodes['life'][joint]]:
        ros.add(node)
    ros.wait_matched(sim.pub, ingest.outputs[joint].publisher)
    ros.add(sim)                                  # the stream starts when it is spun
    ros.spin_until(lambda: sim.sent >= 2000, what='2 s of simulated stream')
    ros.remove(sim)
    ros.spin_until(lambda: ingest.counts()[joint]['published'] == sim.sent == te.samples,
                   what='every simulated sample at the TE monitor over DDS')
    assert te.rejects.total == 0 and ingest.rejects.total == 0
