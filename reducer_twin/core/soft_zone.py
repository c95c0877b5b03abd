"""
Whether a reducer's play is still being taken up at the lost-motion test torque.

A catalogue gives the lost motion as the width of the torsional curve at +-3 % of rated
torque. The window analysis reads it from the flanks of the TE's hysteresis, most of
whose torque bins lie well above the test torque, and extrapolates them down to it along
the model's curve (or a straight one): the play as taken up under load. A reducer whose
soft zone reaches beyond the test torque (a catalogue-style curve with its knee at 4-6 %
of rated) is narrower there than that: on the third generator
(``bench/third_generator.py``) such units read their full soft zone, 0.5-1.6 arcmin more
than their lost motion at the test torque, the bins at the test torque showing it.

:class:`SoftZoneCheck` compares the hysteresis width in a window's bin at the test torque
with the straight line through the bins of loads beyond :data:`FAR_LOADS` times it, pooled
over recent windows (bins at the test torque seen before the stream's first line wait
for it :data:`FAR_MEMORY` windows), and pools the shortfall over the stream's recent
comparisons (:data:`SHORTFALL_MEMORY`: a short recording's whole stream), from bins of
:data:`NEAR_FLANK_SAMPLES` a flank while the stream has had none of a flank's worth
there; its standard error counts the windows' scatter. Once it is said
(:attr:`SoftZoneCheck.reason`), every window carries the pooled shortfall
(``WindowFeatures.soft_zone_shortfall``, with the width at the test torque,
``soft_zone_width``): the estimator still follows the play its windows read, and the lost
motion it gives is that play less the shortfall but not below that width (windows whose
loads seldom pass the knee read less than the far flanks' play:
:func:`.pipeline.taken_off`), the remaining life the time to the play reaching the limit
plus what was taken off (:func:`.life_basis.play_limit`).

Measured per joint (one-off survey, 300-h recordings at 1 kHz): third-generator units
with knees at 4.0-6.0 % of rated fell 0.55-2.2 arcmin (26-73 %) short at the test torque;
knees at 2.2-3.4 % -0.3 to +0.19 arcmin (at most 10 %, the generator's friction loop
still opening there); the independent generator's units within 0.02 arcmin; the model's
simulator 0.03 arcmin on used units and 0.13 arcmin (21 %) on new ones, whose contact
curve bends most (below the 0.2-arcmin floor). ``bench/bench_lost_motion.py --generator
third`` prints how many joints it is said of, by where their knee lies.
"""

import math

import numpy as np

from .units import ARCMIN

NEAR_SHARE = 0.15
"""Bins whose mean load lies within this share of the test torque are read as at it."""

FAR_LOADS = 2.5
"""Bins of loads from this multiple of the test torque on give the straight flanks."""

FAR_BINS = 3
"""Bins beyond :data:`FAR_LOADS` a window needs to add to the straight line."""

FAR_MEMORY = 10.0
"""
Windows with those bins over which the pooled straight line fades.

A window with a bin at the test torque seldom has bins far beyond it as well (3-6 of 50
windows have the one, 3-22 the others, on 150-s recordings of the third generator at
400-500 Hz; 0-1 both): it is compared with the line of recent windows. The play grows by
a few hundredths of an arcminute over tens of windows.
"""

SHORTFALL_RAD = 0.2 * ARCMIN
"""Pooled shortfall (0.2 arcmin) from which the soft zone is said ..."""

SHORTFALL_SHARE = 0.2
"""... when it is also this share of the play read at the test torque ..."""

SHORTFALL_SIGMAS = 5.0
"""... and this many standard errors above zero ..."""

HINT_SIGMAS = 1.0
"""
Standard errors above zero from which a shortfall beyond :data:`SHORTFALL_RAD` that is not
said (too few windows or standard errors, or less than :data:`SHORTFALL_SHARE` of the play)
is told: the lost motion given may be the play (:attr:`SoftZoneCheck.unconfirmed`).
"""

MIN_WINDOWS = 2
"""... from at least this many windows."""

KEEP_SIGMAS = 3.0
"""
Standard errors above zero the pooled shortfall must stay, once said, for it to stand.

Saying takes strong evidence (the rules above); withdrawing it takes evidence that the
shortfall is gone, not a weaker case for it: the windows' scatter (the Birge ratio)
widens the standard error as comparisons come in, and the third generator's shoulder 1014
(``bench_accuracy.py --generators third``, seed 1) was said at 10-15 standard errors,
then, with 0.37-0.55 arcmin of shortfall steady over its next 9 comparisons at 3.1-4.3,
withdrawn for the rest of its life: its lost motion given 1.1-1.5 arcmin high there. A
shortfall that fades to nothing (a false one) still goes.
"""

SHORTFALL_MEMORY = 30.0
"""
Comparisons over which the pooled shortfall fades.

A soft zone may change as the reducer wears (on the third generator it grows with the
play): pooled over a whole life, the early shortfall under-corrected the late windows.
A steady one reads the same as pooled over the whole stream; one that grows is followed,
lagging by about this many comparisons (and the far line's :data:`FAR_MEMORY`).
"""

NEAR_FLANK_SAMPLES = 4
"""
Samples of its own each flank of a bin at the test torque needs to be compared.

Fewer than a lost motion needs (``min_bin_samples``, 20 at 500 Hz and above): the load
passes the test torque quickly at each reversal, so a 2-s window seldom holds 20 there
under both signs (1-3 of 60-70 windows of third-generator shoulders at 500 Hz whose bins
lie there; 13-25 with 4 each). On a swing whose load is known such bins read the width
at the test torque as well as full ones, and on the independent generator's units the
same as full ones; but on a third-generator forearm whose full bins gave a shortfall of
0.35 +- 0.12 arcmin (10 windows) its thin bins gave 0.16 +- 0.23 (20 windows), which
pooled with the full ones took it under the floor. So their comparisons decide only while
a stream has fewer than :data:`MIN_WINDOWS` windows compared on full bins.
"""


class SoftZoneCheck:
    """
    Pool how much narrower the hysteresis is at the test torque than the loads above give.

    Parameters
    ----------
    takeup_torque : float
        The catalogue's lost-motion test torque [N·m].
    series_stiffness : float
        The model's series stiffness [N·m/rad]: the windup ``2·T/k`` taken off the
        straight line's width at the test torque gives the play read there.

    Attributes
    ----------
    windows : int
        Windows whose bin at the test torque was compared with the pooled straight line
        (those with full bins once :data:`MIN_WINDOWS` of them were, else those with
        :data:`NEAR_FLANK_SAMPLES`).

    """

    def __init__(self, takeup_torque, series_stiffness):
        self.takeup_torque = float(takeup_torque)
        self.series_stiffness = float(series_stiffness)
        self._line = np.zeros(5)   # pooled Σw, Σw·T, Σw·T², Σw·h, Σw·T·h of the far bins
        self._memory = math.exp(-1.0 / FAR_MEMORY)
        # Per kind of comparison (full bins, thin bins): windows, then faded by
        # SHORTFALL_MEMORY comparisons: windows, Σw, Σw·s, Σw·s², Σw·p of the windows'
        # shortfalls s and plays p read at the test torque [rad], w = 1/sd².
        self._sums = {'full': np.zeros(6), 'thin': np.zeros(6)}
        self._fade = np.array([1.0] + [math.exp(-1.0 / SHORTFALL_MEMORY)] * 5)
        self._seen = 0        # windows observed
        self._waiting = []    # (window, kind, torque, width, sd) of bins without a line yet
        self._standing = False  # said at the end of the last batch (KEEP_SIGMAS)
        self._carried = {'full': 0, 'thin': 0}  # windows compared before continue_from

    @property
    def _pool(self):
        """Return the comparisons in use: the full bins' once there are enough."""
        full = self._sums['full']
        return full if full[0] >= MIN_WINDOWS or not self._sums['thin'][0] else \
            self._sums['thin']

    @property
    def windows(self):
        """Return the windows compared (of the comparisons in use)."""
        return int(self._pool[0])

    def observe(self, torque_b, width_b, std_b, usable, near_ok=None):
        """
        Add the windows of one batch, in stream order.

        A window with :data:`FAR_BINS` bins beyond :data:`FAR_LOADS` times the test torque
        adds them to the straight line pooled over recent such windows (it fades by
        :data:`FAR_MEMORY` of them); a window with a bin at the test torque is compared
        with that line. Before the stream has a line, such bins wait for it (a window
        seldom has both, and a joint may reach loads far beyond the test torque only after
        its bins there): those of the last :data:`FAR_MEMORY` windows are compared with
        the first line.

        Parameters
        ----------
        torque_b, width_b, std_b : ndarray, shape (W, B)
            Mean load [N·m], hysteresis width [rad] and its standard error [rad] per bin.
        usable : ndarray of bool, shape (W, B)
            Bins that take part in the lost motion.
        near_ok : ndarray of bool, shape (W, B), optional
            Bins that may be compared at the test torque when none of the window is
            usable there (thin bins: in windows that may be read, those whose flanks hold
            :data:`NEAR_FLANK_SAMPLES` each; default none).

        """
        tt = self.takeup_torque
        at_test = np.abs(torque_b - tt) <= NEAR_SHARE * tt
        near = usable & at_test
        thin = (near_ok & at_test & ~near.any(axis=1)[:, None]) if near_ok is not None \
            else np.zeros_like(near)
        far = usable & (torque_b >= FAR_LOADS * tt)
        lined = far.sum(axis=1) >= FAR_BINS
        for k in range(torque_b.shape[0]):
            self._seen += 1
            if lined[k]:
                t, h = torque_b[k, far[k]], width_b[k, far[k]]
                w = 1.0 / std_b[k, far[k]] ** 2
                self._line = self._memory * self._line + np.array(
                    [w.sum(), w @ t, w @ t ** 2, w @ h, w @ (t * h)])
            for kind, bins in (('full', near[k]), ('thin', thin[k])):
                if bins.any():
                    self._waiting.append((self._seen, kind, torque_b[k, bins],
                                          width_b[k, bins], std_b[k, bins]))
            # Bins at the test torque wait for a line (a window seldom has both; the
            # first line may come after them): those of the last FAR_MEMORY windows.
            self._waiting = [w for w in self._waiting if self._seen - w[0] < FAR_MEMORY]
            if self._waiting and self._line_defined():
                for _, kind, t, h, sd in self._waiting:
                    self._compare(kind, t, h, sd)
                self._waiting = []
        self._standing = self.said is not None

    def _line_defined(self):
        """Return whether the pooled far bins define a straight line."""
        s0, s1, s2 = self._line[:3]
        return s0 * s2 - s1 * s1 > 0.0

    def _compare(self, kind, torque, width, std):
        """Add one window's bins at the test torque against the pooled straight line."""
        s0, s1, s2, sy, sty = self._line
        det = s0 * s2 - s1 * s1
        if not det > 0.0:
            return
        a, b = (s2 * sy - s1 * sty) / det, (s0 * sty - s1 * sy) / det
        wn = 1.0 / std ** 2
        t_near, h_near = float(wn @ torque / wn.sum()), float(wn @ width / wn.sum())
        # The line's variance at t_near, plus the near bins'.
        var = (s2 - 2.0 * t_near * s1 + t_near ** 2 * s0) / det + 1.0 / float(wn.sum())
        if not var > 0.0:
            return
        line = a + b * t_near
        short = line - h_near
        self._sums[kind] = self._fade * self._sums[kind] + np.array([
            1.0, 1.0, 1.0 / var, short / var, short ** 2 / var,
            (line - 2.0 * t_near / self.series_stiffness) / var])

    @property
    def shortfall(self):
        """
        Return the pooled shortfall, its standard error and the play read [rad], or None.

        The standard error is the windows' own (their bins' standard errors) scaled up by
        their scatter about the pooled value where it exceeds them (the Birge ratio,
        ``sqrt(chi^2 / (n - 1))``).
        """
        _, n, weight, sum_s, sum_ss, sum_p = self._pool
        if weight <= 0.0:
            return None
        mean = sum_s / weight
        chi2 = max(sum_ss - mean * sum_s, 0.0)
        ratio = chi2 / (n - 1) if n > 1 else 1.0
        return (float(mean), math.sqrt(max(ratio, 1.0) / weight), float(sum_p / weight))

    @property
    def said(self):
        """
        Return the pooled figures once the soft zone is said, else None.

        Said by the rules of :data:`SHORTFALL_RAD` to :data:`MIN_WINDOWS`; once said (at
        the end of a batch :meth:`observe` took), it stands while the pooled shortfall
        stays :data:`KEEP_SIGMAS` standard errors above zero.

        Returns
        -------
        dict or None
            ``shortfall`` and its standard error ``shortfall_sd``, the ``play`` the flanks
            of higher loads give at the test torque and the ``width`` there (the
            catalogue's lost motion, ``play - shortfall``), all means over the stream's recent
            comparisons (:data:`SHORTFALL_MEMORY`) [rad], the
            ``windows`` compared, and ``few_samples``: True when those are thin bins
            (:data:`NEAR_FLANK_SAMPLES` a flank; no window had a flank's worth there).

        """
        found = self.shortfall
        if found is None or self.windows < MIN_WINDOWS:
            return None
        short, sd, play = found
        if self._standing:      # said: it stands while clear of zero
            if not (short >= KEEP_SIGMAS * sd and short < play):
                return None
        elif not _strong(short, sd, play):
            return None
        return self._figures(found)

    def _figures(self, found):
        """Return :attr:`said`'s dict of the pooled ``(shortfall, sd, play)``."""
        short, sd, play = found
        return {'shortfall': short, 'shortfall_sd': sd, 'play': play, 'width': play - short,
                'windows': self.windows, 'few_samples': self._pool is self._sums['thin']}

    @property
    def unconfirmed(self):
        """
        Return the pooled figures of a shortfall past the floor that is not said, else None.

        The shortfall is as large as :data:`SHORTFALL_RAD` and :data:`HINT_SIGMAS` standard
        errors above zero, but the windows compared are too few (:data:`MIN_WINDOWS`), their
        evidence short of :data:`SHORTFALL_SIGMAS`, or the shortfall less than
        :data:`SHORTFALL_SHARE` of the play: nothing is taken off the play, and the width at
        the test torque may be as little as these figures give. The floor keeps units
        without a soft zone quiet: over 300-h recordings the independent generator's fall
        short by 0.02 arcmin at most and the model's own curve by 0.13, but one of 24
        independent-generator joints of short random recordings passed it (README).

        Returns
        -------
        dict or None
            As :attr:`said`'s, or None.

        """
        found = self.shortfall
        if found is None or self.said is not None:
            return None
        short, sd, play = found
        if not (short >= SHORTFALL_RAD and short >= HINT_SIGMAS * sd and short < play):
            return None
        return self._figures(found)

    @property
    def outcome(self):
        """
        Return what the comparisons at the test torque found, or None before any window.

        Returns
        -------
        str or None
            ``'soft zone'`` (:attr:`said`), ``'unconfirmed'`` (:attr:`unconfirmed`),
            ``'not compared'`` (no window compared) or ``'none found'``.

        """
        if not self._seen:
            return None
        if self.said is not None:
            return 'soft zone'
        if self.unconfirmed is not None:
            return 'unconfirmed'
        return 'none found' if self.windows else 'not compared'

    @property
    def caveat(self):
        """
        Say when the windows compared show a soft zone that is not said.

        Until a soft zone is said, the lost motion given is the play the flanks of higher
        loads give: a unit whose play is still being taken up at the test torque has less
        there. Where the windows compared show a shortfall beyond the floor that is not said
        (:attr:`unconfirmed`), the line gives the width they read and why it is not said.

        Returns
        -------
        str or None
            The line, or None.

        """
        unconfirmed = self.unconfirmed
        if unconfirmed is None:
            return None
        short, sd, play = (unconfirmed[k] / ARCMIN for k in ('shortfall', 'shortfall_sd', 'play'))
        n = unconfirmed['windows']
        if n < MIN_WINDOWS:
            where = ('in the one window that compared them (a soft zone is said from '
                     f'{MIN_WINDOWS})')
        elif short < SHORTFALL_SHARE * play:
            where = (f'pooled over the {n} windows that compared them, {100 * short / play:.0f} % '
                     f'of the play (a soft zone is said from {100 * SHORTFALL_SHARE:.0f} %)')
        else:
            where = (f'pooled over the {n} windows that compared them, {short / sd:.1f} '
                     f'standard errors (a soft zone is said at {SHORTFALL_SIGMAS:.0f})')
        return (f"the transmission error's hysteresis at the lost-motion test torque "
                f'({self.takeup_torque:.1f} N·m) read {short:.2f} +- {sd:.2f} arcmin narrower '
                f'than the flanks of higher loads give, {where}: the lost motion given is the '
                f'play those flanks give ({play:.2f} arcmin); the width at the test torque, the '
                f"catalogue's lost motion, may be as little as {play - short:.2f} arcmin. A "
                'longer recording decides')

    @property
    def not_compared(self):
        """
        Say why no window compared the width at the test torque, where none did, else None.

        The lost motion given is then the play of the loaded flanks, whether or not the
        unit has a soft zone beyond the test torque. Said by the analysis of a recording
        where its answer is a warning or worse (a short recording whose loads seldom dwell
        at the test torque is common, and on a unit without a soft zone the play is its
        lost motion).

        Returns
        -------
        str or None
            The line, or None.

        """
        if self.outcome != 'not compared':
            return None
        tt = self.takeup_torque
        if not self._line_defined():
            why = (f'no window held {FAR_BINS} bins of loads beyond {FAR_LOADS * tt:.0f} N·m, '
                   f'the straight flanks the width at the lost-motion test torque ({tt:.1f} '
                   'N·m) is compared with')
        else:
            why = (f'no window held the load at the lost-motion test torque ({tt:.1f} N·m) '
                   'long enough under both signs to compare the width there with the flanks '
                   'of higher loads')
        return (f'{why}: whether the play is still being taken up at the test torque (a soft '
                'zone whose knee lies above it, as on catalogue-style units) is not known, so '
                "the lost motion given is the play those flanks give, more than the catalogue's "
                'lost motion where there is such a zone. A longer recording, or one whose load '
                'dwells near the test torque, compares them')

    def state(self):
        """
        Return the check's pools as plain JSON-able data, to continue after a restart.

        The far bins' line, both kinds of comparison, the bins at the test torque still
        waiting for a line, and whether the soft zone stands (:data:`KEEP_SIGMAS`): a
        ``te_monitor`` restarted from it says what it said and gives the same shortfall,
        where a new check needs :data:`SHORTFALL_SIGMAS` over two windows again.

        Returns
        -------
        dict
            ``takeup_torque_nm``, ``series_stiffness_nm_per_rad`` (the reducer it was
            made for), ``line``, ``full``, ``thin``, ``seen``, ``waiting``, ``standing``.

        """
        return {'takeup_torque_nm': self.takeup_torque,
                'series_stiffness_nm_per_rad': self.series_stiffness,
                'line': self._line.tolist(), 'full': self._sums['full'].tolist(),
                'thin': self._sums['thin'].tolist(), 'seen': self._seen,
                'waiting': [[w, kind, t.tolist(), h.tolist(), sd.tolist()]
                            for w, kind, t, h, sd in self._waiting],
                'standing': self._standing}

    def other_reducer(self, state):
        """
        Say when :meth:`state` was made for another reducer than this check's, else None.

        Its test torque or series stiffness differ: the joint's reducer was changed in the
        configuration, and its pools do not apply.
        """
        mine = (self.takeup_torque, self.series_stiffness)
        theirs = (float(state['takeup_torque_nm']), float(state['series_stiffness_nm_per_rad']))
        if np.allclose(mine, theirs, rtol=1e-9, atol=0.0):
            return None
        return (f'made for another reducer (test torque {theirs[0]:.2f} N·m, series stiffness '
                f'{theirs[1]:.4g} N·m/rad; this one {mine[0]:.2f}, {mine[1]:.4g})')

    def continue_from(self, state):
        """
        Continue from :meth:`state` of a check of the same reducer (:meth:`other_reducer`).

        Raises
        ------
        ValueError
            If the state is not a check's (wrong sizes, values not finite); the check is
            then left as it was.
        KeyError, TypeError
            If a key is missing or a value is of the wrong type.

        """
        line = np.array(state['line'], dtype=float)
        sums = {kind: np.array(state[kind], dtype=float) for kind in ('full', 'thin')}
        waiting = [(int(w), str(kind), *(np.array(v, dtype=float) for v in arrays))
                   for w, kind, *arrays in state['waiting']]
        seen, standing = int(state['seen']), state['standing']
        sizes = line.shape == (5,) and all(s.shape == (6,) for s in sums.values())
        bins = all(kind in sums and w <= seen and t.ndim == 1 and t.shape == h.shape == sd.shape
                   for w, kind, t, h, sd in waiting)
        arrays = [line, *sums.values(), *(a for w in waiting for a in w[2:])]
        if not (sizes and bins and all(np.all(np.isfinite(a)) for a in arrays)
                and isinstance(standing, bool)):
            raise ValueError('line must be 5 finite sums, full and thin 6 each, waiting '
                             '[window, kind, torques, widths, sds] of windows seen, '
                             'standing true or false')
        self._line, self._sums, self._waiting, self._seen = line, sums, waiting, seen
        self._standing = standing
        self._carried = {kind: int(s[0]) for kind, s in sums.items()}

    @property
    def reason(self):
        """Say when the play is still being taken up at the test torque, else None."""
        said = self.said
        if said is None:
            return None
        short, play = said['shortfall'], said['play']
        few = (', from a few samples a bin: the load passes the test torque fast'
               if said['few_samples'] else '')
        carried = self._carried['thin' if said['few_samples'] else 'full']
        if carried:
            few += (f'; {carried} of them carried over from earlier streams of this reducer '
                    '(a restart, or its last recording)')
        return (f"the transmission error's hysteresis at the lost-motion test torque "
                f'({self.takeup_torque:.1f} N·m) is {short / ARCMIN:.2f} arcmin narrower than '
                f'the flanks of higher loads give ({self.windows} windows{few}): the play is '
                'still being taken up there (a soft zone whose knee lies above the test torque). '
                f'Those flanks give {play / ARCMIN:.2f} arcmin of play, the width at the test '
                f"torque (the catalogue's lost motion) is about {(play - short) / ARCMIN:.2f}; "
                'the lost motion and remaining life are given at the test torque from here on '
                '(the play the estimate follows, less this shortfall but not below that '
                'width); the wear is that of the play')


def _strong(short, sd, play):
    """Return whether a pooled shortfall is strong enough to be said (``SoftZoneCheck.said``)."""
    # short < play: no width left at the test torque means the bins there are misread
    # (the load's sign mistaken), not a soft zone; a hysteresis is never narrower than none.
    return (short >= SHORTFALL_RAD and short >= SHORTFALL_SHARE * play
            and short >= SHORTFALL_SIGMAS * sd and short < play)


def carried_line(shortfall):
    """
    Say that the lost motion is given with a soft zone an earlier recording found.

    Parameters
    ----------
    shortfall : float
        The shortfall carried over from the reducer's last recording [rad] (negative: the
        lost motion read below its bins' width at the test torque, :mod:`.within_zone`).

    Returns
    -------
    str
        The line (the bag analysis's ``WARNING`` and input line, the live log).

    """
    if shortfall < 0.0:
        return ('the lost motion and remaining life are given at the width an earlier '
                'recording of this reducer showed at the lost-motion test torque, its loads '
                "within a soft zone (the flanks' reading plus "
                f'{-shortfall / ARCMIN:.2f} arcmin); this recording has not shown it yet')
    return ('the lost motion and remaining life are given at the lost-motion test torque with '
            'the soft zone an earlier recording of this reducer found (the play '
            f'{shortfall / ARCMIN:.2f} arcmin wider than the width there); this recording has '
            'not shown it yet')
