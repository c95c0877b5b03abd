"""
What ``te_monitor`` learnt of its reducer: kept across restarts, forgotten on a replacement.

A controller restarts, and the node with it: without its state the next stream would learn
the encoders' time offset again (its first windows give no lost motion) and need five
standard errors over two windows to say a soft zone again, while the ``wear_estimator``
gave the play (the lost motion the soft zone's width higher) until then. The file
(:class:`~reducer_twin.io.front_state.FrontStateFile`) sits beside the estimator's,
``<state_dir>/<joint>.te_monitor.json``, written after every batch of windows.

A reducer replaced (the ``wear_estimator``'s ``reset`` service) takes what the windows
learnt of the old one with it: the estimator publishes the event on
``/reducer_twin/<joint>/maintenance`` (transient-local), and the monitor starts its window
analysis afresh (:meth:`~reducer_twin.core.joint_twin.TwinFront.new_reducer`) on any event
other than the last it followed, which its state keeps. Before, the new reducer's windows
carried the old one's soft zone, and the estimator took it off their lost motion.
"""

from reducer_twin.core.joint_twin import joint_topic
from reducer_twin.io.front_state import FrontStateFile
from reducer_twin.nodes.qos import latest_qos
from reducer_twin.nodes.runtime import state_path, WORKER
from std_msgs.msg import String

SUFFIX = '.te_monitor.json'
"""The ending of a ``te_monitor``'s state file in ``state_dir``."""

PARAMETERS = {
    'state_file': ('', "te_monitor state file (time offset, soft-zone checks); '' = "
                       f"<state_dir>/<joint>{SUFFIX}; 'none' = keep no state"),
    'state_dir': ('', "directory of state files; '' = $XDG_STATE_HOME/reducer_twin")}
"""The node's plain parameters of its state (``declare_plain``)."""


class FrontKeeper:
    """
    A ``te_monitor``'s state file and the maintenance events it follows.

    Parameters
    ----------
    node : rclpy.node.Node
        The monitor (its logger; the subscription to ``maintenance`` is made on it).
    joint : str
        The joint.
    twin : TwinFront
        The joint's front, continued from the file at once.
    state_file, state_dir : str
        The node's parameters (:data:`PARAMETERS`).

    Attributes
    ----------
    file : FrontStateFile or None
        The state file, written on a background thread; None to keep no state.
    heard : int
        Maintenance events heard (each is followed once; one heard again is not).

    Raises
    ------
    StateFileError
        If the file exists but neither it nor its backup can be used (the node stops:
        remove it, or set ``state_file:=none``, to start afresh).

    """

    def __init__(self, node, joint, twin, state_file, state_dir):
        self.log = node.get_logger()
        self.joint, self.twin = joint, twin
        self.heard = 0
        path = state_path(joint, state_file, state_dir, SUFFIX)
        self.file = None if path is None else FrontStateFile(path, background=True)
        restored = self.file.restore(twin) if self.file is not None else None
        if restored is not None:
            used, lines = restored
            for line in lines:
                self.log.info(f'{joint}: {line} (state {used})')
        node.create_subscription(String, joint_topic(joint, 'maintenance'),
                                 lambda msg: WORKER.post(node, self._follow, msg.data),
                                 latest_qos())

    def _follow(self, event):
        """Start the window analysis afresh for a replaced reducer, once per event (worker)."""
        self.heard += 1
        if event == self.twin.maintenance:
            return
        self.twin.new_reducer(event)
        self.log.info(f'{self.joint}: window analysis started afresh, the time offset kept '
                      f'({event})')
        self.save()

    def save(self):
        """Write the front's state (queued for the writer thread)."""
        if self.file is not None:
            self.file.save(self.twin.state())

    def close(self):
        """Wait until the states queued are written."""
        if self.file is not None:
            self.file.flush()

    def values(self, values):
        """
        Add the state file's figures to a status; return its write error, or None.

        Parameters
        ----------
        values : dict
            Key/values of the status, completed here.

        """
        values['state_file'] = str(self.file.path) if self.file is not None else 'none'
        if self.file is None:
            return None
        writer = self.file.writer
        values['state_writes_failed'] = writer.failures
        if writer.error is not None:
            values['state_write_error'] = str(writer.error)
        return writer.error
