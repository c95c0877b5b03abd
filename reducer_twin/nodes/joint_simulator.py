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

from dataclasses import fields
import threading
import time
from types import SimpleNamespace

from msg_adapters.jointstate_cdr import encode_joint_states
from msg_adapters.layouts import GROUND_TRUTH, record_values
from msg_adapters.ros import to_multiarray
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from reducer_twin.core.errors import InvalidParameter
from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.core.params import ReducerParams
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.core.units import ARCMIN
from reducer_twin.nodes.parameters import SpecParameters
from reducer_twin.nodes.qos import encoder_qos, latest_qos
from reducer_twin.nodes.runtime import run_nodes, WORKER
from reducer_twin.nodes.timers import create_spread_timer
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

BLOCK_S = 0.1
"""Samples are generated this far ahead, vectorised."""

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
        Reducer parameters of every joint.
    **kwargs
        Passed to :class:`rclpy.node.Node`.

    """

    def __init__(self, node_name='joint_simulator', params=None, **kwargs):
        super().__init__(node_name, **kwargs)
        plain = self._declare_plain()
        self.sim_params = SpecParameters(self, 'sim', SimConfig())
        base = self.sim_params.value
        self.params = params or ReducerParams()
        scales = list(plain['wear_rate_scales'])
        self.sims = []
        for k, name in enumerate(plain['joints']):
            overrides = {'name': name, 'seed': base.seed + k, 'profile': plain['profile'],
                         'load': plain['load'], 'exact_mesh': bool(plain['exact_mesh'])}
            if scales:
                if len(scales) != len(plain['joints']):
                    raise InvalidParameter(
                        f'wear_rate_scales must have one value per joint '
                        f'({len(plain["joints"])}), got {len(scales)}')
                overrides['wear_rate_scale'] = float(scales[k])
            cfg = SimConfig(**{**{f.name: getattr(base, f.name) for f in fields(base)},
                               **overrides})
            self.sims.append(JointSimulator(self.params, cfg))
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
        # Filled now (np.zeros would commit pages as the ring fills, a slow RSS growth).
        self.publish_log = np.empty((PUBLISH_LOG, 2), dtype=np.int64)
        self.publish_log.fill(0)
        self._block = None
        self._block_truth = None
        self._block_start = 0
        self._names = (self.names if self.split
                       else [x for n in self.names for x in (n, n + '_motor')])
        self._pending_block = self._submit_block()
        self.max_catch_up = int(plain['max_catch_up'])
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
        create_spread_timer(self, plain['truth_period_s'], self._publish_truth)
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
            'truth_period_s': (1.0, 'period of the ground-truth topics [s]'),
            'max_catch_up': (50, 'most samples published in one late timer tick'),
            'own_thread': (False, 'publish from a thread of its own instead of an executor '
                                  'timer (measured slower here: the GIL is shared)'),
        }
        out = {}
        for name, (default, doc) in specs.items():
            out[name] = self.declare_parameter(
                name, default, ParameterDescriptor(description=doc, read_only=True)).value
        if list(out['wear_rate_scales']) == [0.0]:
            out['wear_rate_scales'] = []
        if out['layout'] not in ('combined', 'split'):
            raise InvalidParameter(f"layout must be 'combined' or 'split', got {out['layout']!r}")
        if not out['joints'] or len(set(out['joints'])) != len(out['joints']):
            raise InvalidParameter(f"joints must be distinct names, got {out['joints']!r}")
        return out

    def _submit_block(self):
        """Queue the next block of every joint on the worker, one task per joint."""
        n = max(1, int(round(BLOCK_S * self.rate_hz)))
        return [WORKER.submit(s.step, n) for s in self.sims]

    def _assemble(self, batches):
        """Arrange per-joint blocks as the published arrays."""
        n = batches[0].t.size
        t = batches[0].t
        if self.split:
            link = np.stack([b.link_angle for b in batches], axis=1)
            motor = np.stack([b.motor_angle for b in batches], axis=1)
            vel = np.stack([b.link_velocity for b in batches], axis=1)
            eff = np.stack([b.effort for b in batches], axis=1)
            samples = (t, link, vel, eff, motor)
        else:
            pos = np.empty((n, 2 * len(batches)))
            vel = np.full((n, 2 * len(batches)), np.nan)
            eff = np.full((n, 2 * len(batches)), np.nan)
            for k, b in enumerate(batches):
                pos[:, 2 * k], pos[:, 2 * k + 1] = b.link_angle, b.motor_angle
                vel[:, 2 * k], eff[:, 2 * k] = b.link_velocity, b.effort
            samples = (t, pos, vel, eff, None)
        truth = [(b.true_wear, b.exposure_s) for b in batches]
        return samples, truth

    def _next_block(self):
        # The block after this one is prepared on the worker while this one is published.
        samples, self._block_truth = self._assemble([f.result() for f in self._pending_block])
        self._pending_block = self._submit_block()
        self._block_start = self.sent
        # Serialised for the whole block at once (the messages differ only in stamp and
        # numbers): a tick publishes ready bytes instead of converting a JointState.
        t, pos, vel, eff, motor = samples
        stamps = self.start_ns + np.round(t * 1e9).astype(np.int64)
        link = _rows_of(*encode_joint_states(stamps, self._names, pos, vel, eff))
        if self.split:
            motor = _rows_of(*encode_joint_states(stamps, self._names, motor))
        self._block = (stamps, link, motor)

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
        """Stop the publishing thread (before the node is destroyed)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def _tick(self):
        now = self.get_clock().now().nanoseconds
        if self.start_ns is None:
            self.start_ns = now
        due = int((now - self.start_ns) * 1e-9 * self.rate_hz) + 1
        budget = self.max_catch_up
        while self.sent < due and budget > 0:
            if self._block is None or self.sent - self._block_start >= len(self._block[0]):
                self._next_block()
            stamps, link, motor = self._block
            i = self.sent - self._block_start
            self.pub.publish(link[i].tobytes())
            if self.split:
                self.motor_pub.publish(motor[i].tobytes())
            k = self.sent % PUBLISH_LOG
            self.publish_log[k, 0], self.publish_log[k, 1] = stamps[i], time.time_ns()
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
        """
        Return the truth at the last published sample, per joint (demo, tests, topic).

        Returns
        -------
        dict
            ``{joint: SimpleNamespace(wear, lost_motion, exposure_s,
            wear_rate_scale, limit_time_s, true_rul_s)}`` in SI units.

        """
        tables = model_tables(self.params)
        i = max(self.sent - 1 - self._block_start, 0)
        out = {}
        for k, sim in enumerate(self.sims):
            if self._block_truth is None:
                wear, exposure = sim.config.initial_wear_m, 0.0
            else:
                wear_arr, exposure_arr = self._block_truth[k]
                wear, exposure = float(wear_arr[i]), float(exposure_arr[i])
            limit = sim.limit_time_s
            out[sim.config.name] = SimpleNamespace(
                wear=wear, lost_motion=float(tables.lost_motion(wear)), exposure_s=exposure,
                wear_rate_scale=sim.config.wear_rate_scale, limit_time_s=limit,
                true_rul_s=limit - exposure)
        return out

    def publish_times(self, stamps_ns):
        """
        Return when the samples with these stamps were published [ns] (0 if unknown).

        Parameters
        ----------
        stamps_ns : array_like of int
            Header stamps of published samples.

        Returns
        -------
        ndarray of int64
            Wall-clock publish times.

        """
        n = min(self.sent, PUBLISH_LOG)
        log = self.publish_log[:n]
        order = np.argsort(log[:, 0], kind='stable')
        keys, times = log[order, 0], log[order, 1]
        if n == 0:
            return np.zeros(np.shape(stamps_ns), dtype=np.int64)
        # Stamps that travelled as float seconds are off by a fraction of a microsecond.
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        hi = np.clip(np.searchsorted(keys, stamps), 0, n - 1)
        lo = np.clip(hi - 1, 0, n - 1)
        idx = np.where(np.abs(keys[lo] - stamps) < np.abs(keys[hi] - stamps), lo, hi)
        return np.where(np.abs(keys[idx] - stamps) < 1000, times[idx], 0)

    def describe(self):
        """Return a one-line summary of the simulated joints."""
        parts = [f'{n}: LM {tr.lost_motion / ARCMIN:.2f} arcmin'
                 for n, tr in self.truth().items()]
        return '; '.join(parts)


def _rows_of(buffer, offsets):
    """Return same-length serialised messages as one row each."""
    return buffer.reshape(offsets.size - 1, -1)


def main(args=None):
    """Run the joint_simulator node."""
    return run_nodes(JointSimulatorNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
