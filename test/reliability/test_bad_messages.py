"""
Bad messages fed over real DDS to the running chain of one joint.

``encoder_ingest`` -> ``te_monitor`` -> ``wear_estimator`` -> ``life_publisher``, in
this process on one executor, real DDS between them (as ``twin_bringup`` runs them).
A probe publishes the JointState messages of a simulated joint (``bad_inputs.py``:
500 Hz, aging factor 3.6e5, so that the five windows of the stream each carry 200
operating hours of wear) with one bad input at 40 % of the stream, one row of the
table per bad input; each row gets a fresh chain.

For every row: the nodes keep running (every good sample after the bad one is paired,
analysed, estimated and turned into remaining life), the bad sample is dropped or
repaired as the README's ingestion table says (the count in
``EncoderIngest.counts()`` and on ``/diagnostics``), the wear estimate and remaining
life stay finite, and the estimate does not jump: it ends within a tolerance of the
estimate of the clean stream and never steps further than the clean run does.
"""

import itertools
import math
import time

import bad_inputs as bad
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.msg_adapters.layouts import REMAINING_LIFE, WEAR_ESTIMATE
from reducer_twin.msg_adapters.ros import from_multiarray, make_joint_state
from reducer_twin.nodes.encoder_ingest import EncoderIngest
from reducer_twin.nodes.life_publisher import LifePublisher
from reducer_twin.nodes.qos import encoder_qos
from reducer_twin.nodes.te_monitor import TEMonitor
from reducer_twin.nodes.wear_estimator import WearEstimatorNode
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray


pytestmark = pytest.mark.timeout(60, method='thread')

_ids = itertools.count()

RECEIVE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10_000,
                         reliability=ReliabilityPolicy.RELIABLE)
LATE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


class Chain:
    """
    The four nodes of one joint and a probe that plays a controller and listens.

    Parameters
    ----------
    ros : RosHarness
        The harness spinning the nodes.
    state_dir : Path
        Directory of the estimator's state file.
    split : bool
        Link and motor on two topics.

    """

    def __init__(self, ros, state_dir, split=False):
        n = next(_ids)
        self.ros = ros
        self.joint = joint = f'arm{n}'
        self.rename = {bad.JOINT: joint, bad.MOTOR: joint + '_motor'}
        link_topic = f'/robot{n}/joint_states'
        motor_topic = f'/robot{n}/motor_states' if split else ''
        ctx = ros.context
        self.ingest = ros.add(EncoderIngest(
            f'encoder_ingest_{n}', context=ctx, parameter_overrides=[
                Parameter('joints', value=[joint]), Parameter('link_topic', value=link_topic),
                Parameter('motor_topic', value=motor_topic),
                Parameter('diagnostics_period_s', value=0.1)]))
        self.te = ros.add(TEMonitor(f'te_monitor_{n}', context=ctx, parameter_overrides=[
            Parameter('joint', value=joint), Parameter('aging_factor', value=bad.AGING),
            Parameter('analysis_period_s', value=0.05)]))
        self.estimator = ros.add(WearEstimatorNode(
            f'wear_estimator_{n}', context=ctx, parameter_overrides=[
                Parameter('joint', value=joint), Parameter('state_dir', value=str(state_dir))]))
        self.life = ros.add(LifePublisher(f'life_publisher_{n}', context=ctx,
                                          parameter_overrides=[Parameter('joint', value=joint)]))
        probe = self.probe = ros.probe()
        self.pubs = {'link': probe.publisher(link_topic, JointState, encoder_qos())}
        # The probe hears its own topics: once it has, the node's reader has the messages.
        self.echo = {'link': probe.listen(link_topic, JointState, RECEIVE_QOS)}
        if split:
            self.pubs['motor'] = probe.publisher(motor_topic, JointState, encoder_qos())
            self.echo['motor'] = probe.listen(motor_topic, JointState, RECEIVE_QOS)
        self.wear = probe.listen(joint_topic(joint, 'wear'), Float64MultiArray, LATE_QOS)
        self.remaining = probe.listen(joint_topic(joint, 'remaining_life'), Float64MultiArray,
                                      LATE_QOS)
        self.diagnostics = probe.listen('/diagnostics', DiagnosticArray, RECEIVE_QOS)
        ros.wait_matched(*self.pubs.values(), self.ingest.outputs[joint].publisher,
                         self.te.feat_pub, self.estimator.pub)

    def feed(self, messages, published):
        """
        Publish the messages in order; spin until the chain has dealt with all of them.

        The node's reader keeps 200 samples (KEEP_LAST): the probe waits to hear
        its own messages before sending more. Two topics go out in slices of 16 ms
        of stream, as a controller sends them: the node gives up link samples the
        motor stream has not covered within ``max_gap_s`` (50 ms) of link stamps,
        and one executor may take a burst of one topic before the other's.
        """
        slice_ = 12 if len(self.pubs) > 1 else 50
        sent = dict.fromkeys(self.pubs, 0)
        for start in range(0, len(messages), slice_):
            for m in messages[start:start + slice_]:
                self.pubs[m.topic].publish(make_joint_state(
                    m.stamp_ns, [self.rename.get(x, x) for x in m.names], m.position,
                    m.velocity or None, m.effort or None))
                sent[m.topic] += 1
            self.ros.spin_until(lambda: all(len(self.echo[t]) >= sent[t] for t in sent),
                                what='the echo of the probe')
        joint, te, est = self.joint, self.te, self.estimator
        self.ros.spin_until(lambda: self.ingest.counts()[joint]['published'] >= published,
                            what=f'{published} encoder pairs published ({self.ingest.counts()})')
        self.ros.spin_until(lambda: te.samples >= self.ingest.counts()[joint]['published'],
                            what='every pair at the TE monitor')
        te.analyze_now()    # what the timer would do next, and wait for the analysis

        def settled():
            # Every window stepped, the probe heard every estimate (one on start and one
            # per window: the estimator's count runs ahead of what DDS has delivered), and
            # the remaining life of the last one.
            stepped = sum(est.statuses.values())
            if stepped < te.windows or len(self.wear) < 1 + stepped:
                return False
            last = from_multiarray(self.wear[-1], WEAR_ESTIMATE)['stamp_s']
            return bool(self.remaining) and from_multiarray(
                self.remaining[-1], REMAINING_LIFE)['stamp_s'] == last

        self.ros.spin_until(settled, what='every window estimated and its remaining life')

    def status(self, predicate):
        """Spin until an ingest /diagnostics status of the joint satisfies ``predicate``."""
        name = f'reducer_twin: {self.joint} encoder ingest'
        found = []

        def latest():
            found[:] = [s for s in self.ros.statuses(self.diagnostics, name) if predicate(s)]
            return bool(found)

        self.ros.spin_until(latest, what=f'a diagnostics status {name!r}')
        return found[-1]

    def records(self):
        """Return the wear and remaining-life records heard (each window's), as arrays."""
        wear = [from_multiarray(m, WEAR_ESTIMATE) for m in self.wear]
        life = [from_multiarray(m, REMAINING_LIFE) for m in self.remaining]
        return ({f: np.array([r[f] for r in wear]) for f in WEAR_ESTIMATE.fields},
                {f: np.array([r[f] for r in life]) for f in REMAINING_LIFE.fields})


@pytest.fixture(scope='module')
def stream():
    """Return the clean stream, stamped from two minutes ago (stale batches flush as live)."""
    return bad.simulate((time.time_ns() // 1_000_000 - 120_000) * 1_000_000)


def run_chain(ros, tmp_path, stream, case=None):
    """Feed the clean stream, or the case's spoilt one, to a new chain; return it."""
    chain = Chain(ros, tmp_path, split=case is not None and case.split)
    messages = stream.messages() if case is None else case.spoil(stream)
    chain.feed(messages, bad.SAMPLES if case is None else case.published(stream))
    return chain


@pytest.fixture(scope='module')
def clean(module_ros, stream, tmp_path_factory):
    """Return the wear and remaining-life records of the clean stream through a chain."""
    chain = run_chain(module_ros, tmp_path_factory.mktemp('clean'), stream)
    assert chain.te.windows >= 4, 'windows enough to compare estimates'
    records = chain.records()
    for node in list(module_ros.nodes):
        module_ros.remove(node)         # the clean chain has done its work
    return records


def finite(values):
    """Return whether every value is finite."""
    return bool(np.isfinite(values).all())


@pytest.mark.parametrize('case', bad.CASES, ids=[c.name for c in bad.CASES])
def test_a_bad_input_is_dropped_or_repaired_counted_and_the_estimate_holds(
        ros, tmp_path, stream, clean, case):
    chain = run_chain(ros, tmp_path, stream, case)
    joint = chain.joint

    # Dropped or repaired as the README's ingestion table says, and nothing else counted.
    expected = bad.expected_counts(case, stream)
    refused = expected.pop('rejected_messages', 0)
    counts = chain.ingest.counts()[joint]
    assert {k: counts[k] for k in expected} == expected
    assert chain.ingest.rejects.counts == ({'bad_joint_state': refused} if refused else {})
    assert counts['published'] == case.published(stream)

    # ... and on /diagnostics, with the final counts.
    status = chain.status(lambda s: ros.key_values(s).get('published') == str(
        counts['published']))
    values = ros.key_values(status)
    for key, value in {**expected, 'rejected_messages': refused}.items():
        assert values[key] == str(value), key
    spoilt = any(v for k, v in expected.items() if not k.endswith('_wrap'))
    assert status.level == (DiagnosticStatus.WARN if spoilt else DiagnosticStatus.OK)

    # The nodes kept running: every good sample after the bad one reached the TE monitor,
    # every window it completed was estimated and turned into remaining life.
    assert chain.te.samples == counts['published']
    assert chain.te.rejects.total == chain.estimator.rejects.total == 0
    assert chain.life.rejects.total == 0
    wear, life = chain.records()
    clean_wear, clean_life = clean
    assert chain.te.windows >= clean_wear['wear_m'].size - 1
    assert wear['stamp_s'][-1] == life['stamp_s'][-1]

    # Finite, ordered, and no jump. The tolerance is the estimate's own uncertainty: 3 sd
    # of the difference of two estimates (sd from each run's covariance). Where the
    # windows hold the clean run's samples but one, the estimates must agree far closer:
    # one sample among ~1000 per window moves the lost motion by < 0.1 %.
    assert finite(wear['wear_m']) and finite(wear['wear_std_m'])
    # Before the first lost motion no number stands for the reducer (NaN); after, every
    # remaining life is a number.
    updates = dict(zip(wear['stamp_s'], wear['updates']))
    seen = np.array([updates.get(t, 0.0) > 0 for t in life['stamp_s']])
    assert seen.any() and seen[-1]
    for key in ('p10_s', 'p50_s', 'p90_s'):
        assert finite(life[key][seen]) and np.isnan(life[key][~seen]).all(), key
    life = {key: values[seen] for key, values in life.items()}
    assert (life['p10_s'] <= life['p50_s']).all() and (life['p50_s'] <= life['p90_s']).all()
    w, w0 = wear['wear_m'][-1], clean_wear['wear_m'][-1]
    tol = 3.0 * math.hypot(wear['wear_std_m'][-1], clean_wear['wear_std_m'][-1])
    if case.same_windows:
        tol = 0.02e-6
    assert abs(w - w0) <= tol, f'wear {w * 1e6:.4f} um vs {w0 * 1e6:.4f} um clean'
    largest_clean_step = np.abs(np.diff(clean_wear['wear_m'])).max()
    steps = np.abs(np.diff(wear['wear_m']))
    assert steps.max() <= largest_clean_step + tol, (
        f'steps {steps * 1e6} um, clean at most {largest_clean_step * 1e6:.3f} um')
    # The exposure is that of the windows seen, never counted twice (the bag loop).
    assert wear['exposure_s'][-1] <= clean_wear['exposure_s'][-1] + 2.0 * bad.AGING
    # The clean run's median remaining life lies within this run's P10-P90.
    # Calibrated 80 % intervals from a few differing windows overlap (see test_bad_bags.py).
    assert life['p10_s'][-1] <= clean_life['p90_s'][-1]
    assert clean_life['p10_s'][-1] <= life['p90_s'][-1]
