"""The simulated robot's encoder stream, made block by block on the worker, as ready bytes."""

from types import SimpleNamespace

import numpy as np
from reducer_twin.core.simulator import joint_state_columns, joint_state_names
from reducer_twin.core.transmission_error import model_tables
from reducer_twin.msg_adapters.jointstate_cdr import encode_joint_states
from reducer_twin.nodes.runtime import WORKER

BLOCK_S = 0.1
"""Samples are generated this far ahead, vectorised."""


class SimulatedStream:
    """
    Serialised JointState messages of simulated joints, one block ahead on the worker.

    Parameters
    ----------
    sims : list of JointSimulator
        One per joint.
    rate_hz : float
        Sample rate [Hz].
    split : bool
        Link and motor sides on two topics (else ``<joint>`` and ``<joint>_motor`` in one).

    """

    def __init__(self, sims, rate_hz, split=False):
        self.sims = sims
        self.rate_hz = float(rate_hz)
        self.split = bool(split)
        self._names = list(joint_state_names([s.config.name for s in sims], self.split))
        self.block = None          # (stamps [ns], link rows, motor rows or None)
        self.block_start = 0
        self._truth = None
        self._pending = self._submit()

    def _submit(self):
        """Queue the next block of every joint on the worker, one task per joint."""
        n = max(1, int(round(BLOCK_S * self.rate_hz)))
        return [WORKER.submit(s.step, n) for s in self.sims]

    def message(self, sent, start_ns):
        """
        Return sample ``sent`` of the stream that started at ``start_ns``.

        Returns
        -------
        tuple
            ``(stamp [ns], link message bytes, motor message bytes or None)``.

        """
        if self.block is None or sent - self.block_start >= len(self.block[0]):
            self._next(sent, start_ns)
        stamps, link, motor = self.block
        i = sent - self.block_start
        return stamps[i], link[i].tobytes(), None if motor is None else motor[i].tobytes()

    def _next(self, sent, start_ns):
        # The block after this one is prepared on the worker while this one is published.
        batches = [f.result() for f in self._pending]
        self._truth = [(b.true_wear, b.exposure_s) for b in batches]
        self._pending = self._submit()
        self.block_start = sent
        # Serialised for the whole block at once (the messages differ only in stamp and
        # numbers): a tick publishes ready bytes instead of converting a JointState.
        pos, vel, eff, motor = joint_state_columns(batches, self.split)
        stamps = start_ns + np.round(batches[0].t * 1e9).astype(np.int64)
        link = _rows_of(*encode_joint_states(stamps, self._names, pos, vel, eff))
        if self.split:
            motor = _rows_of(*encode_joint_states(stamps, self._names, motor))
        self.block = (stamps, link, motor)

    def truth(self, sent):
        """
        Return the truth after ``sent`` published samples, per joint.

        Returns
        -------
        dict
            ``{joint: SimpleNamespace(wear, lost_motion, exposure_s,
            wear_rate_scale, limit_time_s, true_rul_s)}`` in SI units.

        """
        i = max(sent - 1 - self.block_start, 0)
        out = {}
        for k, sim in enumerate(self.sims):
            if self._truth is None:
                wear, exposure = sim.config.initial_wear_m, 0.0
            else:
                wear_arr, exposure_arr = self._truth[k]
                wear, exposure = float(wear_arr[i]), float(exposure_arr[i])
            limit = sim.limit_time_s
            out[sim.config.name] = SimpleNamespace(
                wear=wear, lost_motion=float(model_tables(sim.params).lost_motion(wear)),
                exposure_s=exposure, wear_rate_scale=sim.config.wear_rate_scale,
                limit_time_s=limit, true_rul_s=limit - exposure)
        return out


def _rows_of(buffer, offsets):
    """Return same-length serialised messages as one row each."""
    return buffer.reshape(offsets.size - 1, -1)
