"""
The joint simulator node: a controller's JointState stream and its hidden truth, over DDS.

It publishes ``/joint_states`` with ``<joint>`` and ``<joint>_motor`` entries at its rate,
and stops publishing when closed, whether it ticks on the executor's timer (the default)
or on a thread of its own: the demo closes it when the stream it was asked for is complete.
"""

import pytest
from rclpy.parameter import Parameter
from reducer_twin.nodes.joint_simulator import JointSimulatorNode
from reducer_twin.nodes.qos import encoder_qos
from sensor_msgs.msg import JointState

pytestmark = pytest.mark.timeout(60, method='thread')


@pytest.mark.parametrize('own_thread', [False, True], ids=['executor timer', 'own thread'])
def test_the_simulator_streams_both_encoders_and_stops_when_closed(ros, own_thread):
    sim = ros.add(JointSimulatorNode(context=ros.context, parameter_overrides=[
        Parameter('joints', value=['joint_1']), Parameter('own_thread', value=own_thread),
        Parameter('sim.rate_hz', value=200.0)]))
    probe = ros.probe()
    heard = probe.listen('/joint_states', JointState, encoder_qos())
    ros.spin_until(lambda: len(heard) >= 50, what='50 JointState messages')
    assert list(heard[-1].name) == ['joint_1', 'joint_1_motor']
    assert all(len(m.position) == 2 and len(m.effort) == 2 for m in heard)
    sim.close()
    sent = sim.sent
    count = -1
    while count != len(heard):    # what was on its way arrives
        count = len(heard)
        ros.spin_for(0.2)
    ros.spin_for(0.5)             # 100 more samples at 200 Hz if it went on
    assert sim.sent == sent and len(heard) == count <= sent
    # The truth stands at the last sample published (stamped (sent - 1) / rate).
    aging = sim.sims[0].config.aging_factor
    assert sim.truth()['joint_1'].exposure_s == pytest.approx((sent - 1) / 200.0 * aging)
