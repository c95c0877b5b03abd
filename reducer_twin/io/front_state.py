"""
``te_monitor``'s state file: what a joint's front learnt of its reducer, across restarts.

:meth:`~reducer_twin.core.joint_twin.TwinFront.state` (the encoders' time offset and the
soft-zone check's pools) in a file like the estimator's (:mod:`.state_file`): checksummed
canonical JSON of format ``reducer_twin.front_state.file``, written atomically with the
previous good copy kept as ``<path>.bak``, on a background thread for the live node.
Restoring falls back to the backup, and a file that neither it nor its backup can
continue from is an error naming both reasons, never a silent fresh start.
"""

from reducer_twin.core.errors import StateFileError
from reducer_twin.core.joint_twin import FRONT_STATE_KIND
from reducer_twin.io.state_file import backup_path, decode_state, KeptStateFile
from reducer_twin.io.state_file import read_with_fallback

WHAT = 'te_monitor state'
"""What the file holds, for messages."""


class FrontStateFile(KeptStateFile):
    """
    The state file of one joint's ``te_monitor``.

    Continued from on start (falling back to its ``.bak`` copy), written atomically after
    every batch of windows (see :class:`~reducer_twin.io.state_file.KeptStateFile` for the
    parameters and the writer).

    """

    kind = FRONT_STATE_KIND
    what = WHAT

    def restore(self, front):
        """
        Continue ``front`` from the file, or from its backup when the file cannot be used.

        Parameters
        ----------
        front : TwinFront
            The joint's front (:meth:`~reducer_twin.core.joint_twin.TwinFront.continue_from`).

        Returns
        -------
        tuple or None
            ``(path used, lines)``: the file continued from and what was continued; None
            when neither the file nor its backup exists (nothing learnt yet).

        Raises
        ------
        StateFileError
            If a file exists but neither it nor its backup can be continued from.

        """
        if not (self.path.exists() or backup_path(self.path).exists()):
            return None
        lines, used, _ = read_with_fallback(self.path, lambda p: _continue(p, front), WHAT)
        return used, lines


def _continue(path, front):
    """Continue ``front`` from one file; a StateFileError names the file."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise StateFileError(f'cannot read {WHAT} {path}: {err}') from err
    state = decode_state(data, path, FRONT_STATE_KIND)
    try:
        return front.continue_from(state)
    except StateFileError as err:
        raise StateFileError(f'{path}: {err}') from err
