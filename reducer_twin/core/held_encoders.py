"""
Whether a joint's encoder readings are held between updates slower than the stream.

A drive or fieldbus that refreshes one encoder slower than the controller publishes (a
secondary link encoder polled at 250 Hz on a 1 kHz bus) repeats each reading until the
next. The repeated reading is stale by the samples since its update, so the TE of those
samples carries the motion since, ``omega`` times the reading's age: a sawtooth of up to
``omega·(k - 1)·dt``, arcminutes at a robot's speeds, in step with the motion. The time
offset learnt from the first windows takes its mean, the rest reads as play. Measured
(the model's simulator, 1 kHz, the link reading held for 4 samples, a used unit at 2.27
arcmin): windows read 1.90 arcmin at first and 1.11 at the end, the estimator took the
fall for an as-built clearance of 3.3 µm, and the remaining life came out 9-10 times the
true one, with no word said.

:class:`HeldEncoders` judges each encoder once, from pairs of successive samples over
which the other encoder clearly moved (:data:`MOVING_STEP_RAD`): a fresh encoder then
changes every sample (a 17-bit one included), a held one repeats all but one sample per
update. Once one is found held, the samples that repeat its reading while the other
encoder moved are left out of the TE, so that each TE sample pairs an update with the
angle of the other encoder at its stamp; a reading that stays while neither moves (the
joint at rest) is kept, so a resting joint leaves no hole in the stream.

Both encoders held on the same samples give a right TE, as old as the update, beside an
effort that is not: new units of the model's simulator read 6-9 % high with both held for
4 samples. Neither moves while the other repeats, so they are judged from the link's own
runs: a run of samples repeating both readings that ends in a step of more than
:data:`MOVING_STEP_RAD` a sample of the run is a held update; such runs' repeats are left
out (the chunk's last run, whose end is not known yet, is kept).
"""

import numpy as np

HELD_SHARE = 0.25
"""
Share of the moving pairs whose reading repeats from which an encoder is held.

A fresh encoder repeats none of them; one updated every ``k`` samples repeats
``(k - 1)/k``, a half at every other sample.
"""

HELD_MIN_PAIRS = 200
"""Moving pairs of successive samples seen before the encoders are judged."""

MIN_UPDATES = 0.02
"""Share of the moving pairs that update a held reading: one in 50 samples or more."""

MOVING_STEP_RAD = 2e-4
"""
Motion of the other encoder over a pair [rad at the output] for the pair to be judged.

An encoder of 2^16 counts a turn or finer steps at least once over it (a step of 9.6e-5
rad); at 1 kHz it is 0.2 rad/s.
"""

STILL_RAD = 5e-6
"""
Motion of the other encoder [rad at the output] over a run of one held reading below which
the reading is kept: its TE errs by no more than that (1 arcsec).
"""


class HeldEncoders:
    """
    Judge once whether a joint's link or motor reading is held; then find its stale samples.

    Parameters
    ----------
    ratio : float
        Reduction ratio ``i`` (motor angles are referred to the output by it).

    Attributes
    ----------
    decided : bool
        Both encoders have been judged (each is, from its own moving pairs).
    held : dict of str to bool
        ``'link'``, ``'motor'``: the encoder's reading is held between slower updates;
        ``'both'``: both are, updated on the same samples (judged from the link's own
        runs: a run of samples that repeat both readings and then a step of more than
        :data:`MOVING_STEP_RAD` a sample of the run).
        The chunk in which one is found held is left out of the TE where stale from its
        first sample; the samples of earlier chunks, fewer than a window, are dropped by
        the window analysis (:meth:`.window_analysis.WindowAnalyzer.discard_buffer`).
    stale : int
        Samples left out of the TE as stale so far.

    """

    def __init__(self, ratio):
        self.ratio = float(ratio)
        self.decided = False
        self.held = {'link': False, 'motor': False, 'both': False}
        self.stale = 0
        self._moving = {'link': 0, 'motor': 0, 'both': 0}
        self._repeats = {'link': 0, 'motor': 0, 'both': 0}
        self.interpolated = False  # the motor read between its own stamps (a topic of its own)
        self._last = None        # (link, motor at the output) of the latest sample
        self._run_start = {}     # per encoder, the other one at the start of its latest run

    @property
    def watching(self):
        """Whether samples still need to be seen: not yet judged, or an encoder held."""
        return not self.decided or any(self.held.values())

    def update_share(self, encoder):
        """Return the share of moving samples that update ``encoder``'s reading (NaN: unjudged)."""
        moving = self._moving[encoder]
        return 1.0 - self._repeats[encoder] / moving if moving else float('nan')

    def reason(self, rate_hz):
        """
        Say which encoder is held and what is done about it, else None.

        Parameters
        ----------
        rate_hz : float
            The stream's sample rate [Hz], for the line.

        """
        if self.held['both']:
            return ('the link and motor encoders repeat their readings together on '
                    'successive samples while the joint moves: updated at about '
                    f"{self.update_share('both') * rate_hz:.0f} Hz on a {rate_hz:.0f} Hz "
                    'stream (held between slower updates); a repeated reading is as old as '
                    'its update, and the effort beside it is not, so only the updates are '
                    f'read (the lost motion rests on fewer samples; {self.stale:,} left out '
                    'so far)')
        said = [name for name in ('link', 'motor') if self.held[name]]
        if not said:
            return None
        rates = ' and '.join(f'{self.update_share(name) * rate_hz:.0f}' for name in said)
        read = ("the motor is read between its own samples at the link's stamps, held ones "
                'included: the lost motion may read a few % high' if said == ['motor']
                and self.interpolated else 'only the updates are read (the lost motion '
                f'rests on fewer samples; {self.stale:,} left out so far)')
        return (f'the {" and ".join(said)} encoder{"s" if len(said) > 1 else ""} '
                f'repeat{" their readings" if len(said) > 1 else "s its reading"} on '
                f'successive samples while the joint moves: updated at about {rates} Hz on '
                f'a {rate_hz:.0f} Hz stream (held between slower updates); a repeated reading '
                f'is as old as its update, so {read}')

    def stale_mask(self, link, motor, shared=True):
        """
        Return the samples whose TE a held reading makes stale (None: none).

        Parameters
        ----------
        link, motor : ndarray, shape (N,)
            Link and motor angles of the same stamps, in stamp order [rad].
        shared : bool
            The motor was read on these stamps. False: it is interpolated at them from
            its own, so a held motor's repeats are not the TE's samples (measured: leaving
            them out read 15 % high, against 3 % as they are) and only the link's and both
            readings' stale samples are returned.

        Returns
        -------
        ndarray of bool or None
            True where a held encoder repeats its reading while the other moved.

        """
        if self.decided and not any(self.held.values()):
            return None
        link = np.asarray(link, dtype=float)
        out = np.asarray(motor, dtype=float) / self.ratio
        if link.size == 0 or link.shape != out.shape:
            return None
        prev = self._last
        self._last = (float(link[-1]), float(out[-1]))
        if prev is None:
            prev = (np.nan, np.nan)
        link_p = np.concatenate([[prev[0]], link])
        out_p = np.concatenate([[prev[1]], out])
        same = {'link': link_p[1:] == link_p[:-1], 'motor': out_p[1:] == out_p[:-1]}
        both = same['link'] & same['motor']
        step = None
        if not self.decided:
            step, runs = _runs(link_p, both)
            self._count('link', np.abs(np.diff(out_p)) > MOVING_STEP_RAD, same['link'])
            self._count('motor', np.abs(np.diff(link_p)) > MOVING_STEP_RAD, same['motor'])
            self._count('both', step / runs > MOVING_STEP_RAD, both)
            self.decided = min(self._moving.values()) >= HELD_MIN_PAIRS
        if not any(self.held.values()):
            return None
        self.interpolated = not shared
        stale = np.zeros(link.size, dtype=bool)
        for name, other in (('link', out_p), ('motor', link_p)):
            if self.held[name]:
                moved = same[name] & self._moved_over_run(same[name], other, name)
                if shared or name == 'link':
                    stale |= moved
        if self.held['both']:
            step = _runs(link_p, both)[0] if step is None else step
            stale |= both & (step > STILL_RAD)
        self.stale += int(np.count_nonzero(stale))
        return stale if stale.any() else None

    def _count(self, name, moving, repeats):
        """
        Count a judgement's moving samples and those that repeat; judge once enough are seen.

        Held: at least :data:`HELD_SHARE` of the moving samples repeat, and at least
        :data:`MIN_UPDATES` update (a reading that never updates is a frozen encoder, not a
        held one: :mod:`.observability` says so, the encoders do not measure one motion).
        """
        if self._moving[name] >= HELD_MIN_PAIRS:
            return
        self._moving[name] += int(np.count_nonzero(moving))
        self._repeats[name] += int(np.count_nonzero(moving & repeats))
        if self._moving[name] >= HELD_MIN_PAIRS:
            seen, repeated = self._moving[name], self._repeats[name]
            self.held[name] = HELD_SHARE * seen <= repeated <= (1.0 - MIN_UPDATES) * seen

    def _moved_over_run(self, same, other, name):
        """
        Whether the other encoder moved beyond :data:`STILL_RAD` since the reading's update.

        ``same`` (N,) marks the samples that repeat the one before; ``other`` (N + 1,) is
        the other encoder with the previous chunk's last sample first. A run that began
        in an earlier chunk is measured from where the other encoder stood at its start.
        """
        starts = np.flatnonzero(~same)
        run = np.cumsum(~same) - 1                      # -1: the run carried over
        start_other = np.where(run >= 0, other[1:][starts[np.maximum(run, 0)]]
                               if starts.size else np.nan, np.nan)
        carried = run < 0
        if carried.any():
            start_other[carried] = self._run_start.get(name, other[0])
        # The other encoder at the start of the latest run, for the next chunk.
        self._run_start[name] = float(other[1:][starts[-1]] if starts.size else
                                      self._run_start.get(name, other[0]))
        with np.errstate(invalid='ignore'):
            return np.abs(other[1:] - start_other) > STILL_RAD


def _runs(link_p, both):
    """
    Per sample: the link's step at the end of its run of repeated readings, and the run's length.

    ``link_p`` (N + 1,) is the link with the previous chunk's last sample first; ``both``
    (N,) marks the samples that repeat both readings. A run starts at each sample that does
    not; its step is the link's change from its first sample to the next run's first. The
    chunk's last run, whose end is not known yet, gets a step of 0 (judged and left as it
    is); a run carried from the chunk before counts its samples in this one.
    """
    n = both.size
    starts = np.flatnonzero(~both)
    run = np.cumsum(~both) - 1                 # -1: the run carried over
    ends = np.concatenate([starts, [n]])
    value_first = np.concatenate([[link_p[0]], link_p[1:][starts]])
    value_next = np.concatenate([link_p[1:][starts], [np.nan]])
    with np.errstate(invalid='ignore'):
        jump = np.nan_to_num(np.abs(value_next - value_first), nan=0.0)
    length = np.maximum(ends - np.concatenate([[-1], starts]), 1)
    # Entry 0 is the run carried from the chunk before; none when the first sample starts one.
    carried = not (starts.size and starts[0] == 0)
    if not carried:
        jump, length = jump[1:], length[1:]
    idx = run + (1 if carried else 0)
    return jump[idx], length[idx].astype(float)
