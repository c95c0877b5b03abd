"""
joint_simulator: robot joints with RV-80E reducers, published like a robot controller.

Stands in for the robot: N joints simulated by the core
(:class:`reducer_twin.core.simulator.JointSimulator`), published at
``sim.rate_hz`` as ros2_control's joint_state_broadcaster would, either
one ``/joint_states`` carrying ``<joint>`` and ``<joint>_motor``
(``layout: combined``) or link and motor sides on ``/joint_states`` and
``/motor_states`` (``layout: split``). Stamps come from the simulated
sample times, not from timer ticks: a late tick publishes the samples it
owes, none is skipped. The hidden truth (wear, lost motion, true remaining
life) goes to ``/reducer_twin/<joint>/ground_truth``.
"""

from dataclasses import replace
import threading
import time

from rclpy.node import Node
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.units import ARCMIN
from reducer_twin.msg_adapters.layouts import GROUND_TRUTH, record_values
from reducer_twin.msg_adapters.ros import to_multiarray
from reducer_twin.nodes.buffers import PublishLog
from reducer_twin.nodes.parameters import check_choice, declare_plain, SpecParameters
from reducer_twin.nodes.qos import encoder_qos, latest_qos
from reducer_twin.nodes.runtime import run_nodes
from reducer_twin.nodes.settings import SimulatorSettings
from reducer_twin.nodes.sim_stream import SimulatedStream
from reducer_twin.nodes.timers import create_spread_timer
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

PUBLISH_LOG = 1 << 18
"""Samples whose (stamp, publish time) are kept, ns (a ring of 4 MB; for latency benchmarks)."""


class JointSimulatorNode(Node):
    """
    Publish simulated joint states and the simulator's ground truth.

    Parameters
    ----------
    node_name : str
        ROS node name.
    params : ReducerParams, optional
        Reducer parameters of every joint without its own.
    joint_params : dict of str to ReducerParams, optional
        The reducers of joints that carry another one (per joint name).
    **kwargs
        Passed to :class:`rclpy.node.Node`.

    """

    def __init__(self, node_name='joint_simulator', params=None, joint_params=None, **kwargs):
        super().__init__(node_name, **kwargs)
        plain = self._declare_plain()
        self.sim_params = SpecParameters(self, 'sim', SimConfig())
        base = self.sim_params.value
        self.params = params or ReducerParams()
        scales = list(plain['wear_rate_scales'])
        if scales and len(scales) != len(plain['joints']):
            raise InvalidParameter(f'wear_rate_scales must have one value per joint '
                                   f'({len(plain["joints"])}), got {len(scales)}')
        self.sims = [JointSimulator((joint_params or {}).get(name, self.params), replace(
            base, name=name, seed=base.seed + k, profile=plain['profile'], load=plain['load'],
            exact_mesh=bool(plain['exact_mesh']),
            **({'wear_rate_scale': float(scales[k])} if scales else {})))
            for k, name in enumerate(plain['joints'])]
        self.rate_hz = base.rate_hz
        self.split = plain['layout'] == 'split'
        self.names = [s.config.name for s in self.sims]
        qos = encoder_qos()
        self.pub = self.create_publisher(JointState, plain['link_topic'], qos)
        self.motor_pub = (self.create_publisher(JointState, plain['motor_topic'], qos)
                          if self.split else None)
        self.truth_pubs = [self.create_publisher(Float64MultiArray,
                                                 joint_topic(n, 'ground_truth'), latest_qos())
                           for n in self.names]
        self.start_ns = None   # set at the first tick: the stream starts when spinning does
        self.sent = 0
        self.publish_log = PublishLog(PUBLISH_LOG)
        self.stream = SimulatedStream(self.sims, self.rate_hz, self.split)
        settings = SpecParameters(self, '', SimulatorSettings()).value
        self.max_catch_up = settings.max_catch_up
        self._stop = threading.Event()
        if plain['own_thread']:
            # A robot controller publishes on its own clock, not when the twin's executor
            # has time: a dedicated thread keeps the stream's timing independent of the load
            # the twin puts on the executor of the same process.
            self._thread = threading.Thread(target=self._run, name='joint-simulator',
                                            daemon=True)
            self._thread.start()
        else:
            self._thread = None
            self.create_timer(1.0 / self.rate_hz, self._tick)
        create_spread_timer(self, settings.truth_period_s, self._publish_truth)
        self.get_logger().info(
            f'simulating {len(self.sims)} joint(s) {self.names} at {self.rate_hz:g} Hz, '
            f'aging factor {base.aging_factor:g}, profile {plain["profile"]}')

    def _declare_plain(self):
        specs = {
            'joints': (['joint_1'], 'names of the simulated joints'),
            'profile': ('robot', "'robot' (moves, dwells, reversals) or 'paper' (90 deg/s)"),
            'load': ('gravity', "'gravity' (gravity + inertia) or 'constant'"),
            'wear_rate_scales': ([0.0], 'hidden Archard-rate multiplier per joint; [0.0] or '
                                        'empty: sim.wear_rate_scale for all'),
            'layout': ('combined', "'combined' (/joint_states with <joint>_motor) or 'split'"),
            'link_topic': ('/joint_states', 'topic of the (link-side) joint states'),
            'motor_topic': ('/motor_states', "topic of the motor side with layout 'split'"),
            'exact_mesh': (False, 'TE by the exact loaded mesh (slow, ground-truth studies) '
                                  'instead of the period-mean table (< 0.1 arcsec apart)'),
            'own_thread': (False, 'publish from a thread of its own instead of an executor '
                                  'timer (measured slower here: the GIL is shared)'),
        }
        out = declare_plain(self, specs)
        if list(out['wear_rate_scales']) == [0.0]:
            out['wear_rate_scales'] = []
        check_choice('layout', out['layout'], ('combined', 'split'))
        if not out['joints'] or len(set(out['joints'])) != len(out['joints']):
            raise InvalidParameter(f"joints must be distinct names, got {out['joints']!r}")
        return out

    def _run(self):
        """Publish every sample at its time, until the node closes (own thread)."""
        period = 1.0 / self.rate_hz
        while not self._stop.is_set():
            try:
                self._tick()
            except Exception as err:  # context shut down under us: stop quietly
                if not self._stop.is_set():
                    self.get_logger().error(f'simulator stopped: {err!r}')
                return
            if self.start_ns is None:
                continue
            next_s = (self.start_ns * 1e-9 + self.sent * period) - time.time()
            self._stop.wait(max(next_s, 0.0))

    def close(self):
        """Stop publishing (the thread or the timer; before the node is destroyed)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def _tick(self):
        if self._stop.is_set():
            return
        now = self.get_clock().now().nanoseconds
        if self.start_ns is None:
            self.start_ns = now
        due = int((now - self.start_ns) * 1e-9 * self.rate_hz) + 1
        budget = self.max_catch_up
        while self.sent < due and budget > 0:
            stamp, link, motor = self.stream.message(self.sent, self.start_ns)
            self.pub.publish(link)
            if motor is not None:
                self.motor_pub.publish(motor)
            self.publish_log.add(stamp, time.time_ns())
            self.sent += 1
            budget -= 1

    def _publish_truth(self):
        stamp_s = self.get_clock().now().nanoseconds * 1e-9
        for (name, tr), sim, pub in zip(self.truth().items(), self.sims, self.truth_pubs):
            rec = {'stamp_s': stamp_s, 'wear_m': tr.wear, 'lost_motion_rad': tr.lost_motion,
                   'exposure_s': tr.exposure_s, 'wear_rate_scale': tr.wear_rate_scale,
                   'aging_factor': sim.config.aging_factor, 'limit_time_s': tr.limit_time_s,
                   'true_rul_s': tr.true_rul_s}
            pub.publish(to_multiarray(GROUND_TRUTH, record_values(GROUND_TRUTH, rec)))

    def truth(self):
        """Return the truth at the last published sample, per joint (demo, tests, topic)."""
        return self.stream.truth(self.sent)

    def publish_times(self, stamps_ns):
        """Return when the samples with these stamps were published [ns] (0 if unknown)."""
        return self.publish_log.publish_times(stamps_ns)

    def describe(self):
        """Return a one-line summary of the simulated joints."""
        parts = [f'{n}: LM {tr.lost_motion / ARCMIN:.2f} arcmin'
                 for n, tr in self.truth().items()]
        return '; '.join(parts)


def main(args=None):
    """Run the joint_simulator node."""
    return run_nodes(JointSimulatorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
