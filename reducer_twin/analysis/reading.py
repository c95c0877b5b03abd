"""
A recording read in chunks of JointState messages, in log-time order.

:class:`BagChunks` reads and decodes a bag a chunk at a time (several publishers'
partial messages of one tick merged, :func:`merge_partial_messages`);
:class:`ForkedBagChunks` does it a few chunks ahead in a forked process. Warnings about
the bag go to its list (:func:`warn`).
"""

from dataclasses import replace

import numpy as np
from reducer_twin.analysis.forking import end_process, end_with_parent, parent_of_fork
from reducer_twin.core.stamp_clock import CLOCK_SCATTER, retimed_message, step_scatter
from reducer_twin.core.stamp_clock import unstamped_message
from reducer_twin.io.mcap_reader import ReadWarning
from reducer_twin.msg_adapters.jointstate_cdr import concat_batches, JointStateBatch


READ_END, READ_ERROR = '!end', '!error'
"""Control messages of the reading process's queue."""


def warn(bag, text):
    """Add a warning about the bag (printed as ``WARNING: <bag>: <text>``)."""
    bag.warnings.append(ReadWarning(str(bag.path), None, text))


class BagChunks:
    """JointState messages of the plan's topics, decoded in chunks of about N messages."""

    def __init__(self, bag, topics, size, prefix=''):
        self.bag = bag
        self.topics = list(topics)
        self.size = size
        self.prefix = prefix    # put before every entry name (a robot's namespace)
        self.messages = dict.fromkeys(self.topics, 0)
        self.malformed = dict.fromkeys(self.topics, 0)
        self.first_problem = {}
        self.repeated_names = dict.fromkeys(self.topics, 0)
        self.stamp_repeats = dict.fromkeys(self.topics, 0)
        self.stamp_clashes = dict.fromkeys(self.topics, 0)
        self.step_scatter = {}      # topic -> [(period, scatter)] of each chunk [ns]
        self.zero_stamps = dict.fromkeys(self.topics, 0)
        self.merged_topics = set()  # topics of which some messages named only some joints
        self.unstamped = {}         # topic -> its stamps are the log times (see _stamped)
        self._last_stamp = {}

    def __iter__(self):
        parts = {t: [] for t in self.topics}
        pending = 0
        for topic, decoded in self.bag.iter_joint_states(self.topics):
            if decoded.rejected:
                self.malformed[topic] += len(decoded.rejected)
                self.first_problem.setdefault(topic, decoded.rejected[0][1])
            self.repeated_names[topic] += decoded.repeated_names
            self.messages[topic] += len(decoded)
            parts[topic].append(decoded)
            pending += len(decoded)
            if pending >= self.size:
                yield {t: self._ready(t, p) for t, p in parts.items()}
                parts = {t: [] for t in self.topics}
                pending = 0
        if pending:
            yield {t: self._ready(t, p) for t, p in parts.items()}
        self._warn()

    def _ready(self, topic, parts):
        """Return a topic's messages of one chunk, several publishers' partial ones merged."""
        if not parts:
            return None
        batch = concat_batches(parts)
        batch = self._stamped(topic, batch)
        if self.prefix:
            batch = replace(batch, names=tuple(self.prefix + n for n in batch.names))
        absent = np.isnan(batch.position)
        merged = merge_partial_messages(batch) if absent.any() else batch
        if merged is not batch:     # several publishers: a joint is in the messages naming it
            self.merged_topics.add(topic)
        batch = merged
        self._note_stamps(topic, batch.stamps_ns, batch.position)
        return batch

    def _stamped(self, topic, batch):
        """
        Return a topic's batch with the recorder's receive times for stamps if it has none.

        A publisher that never fills ``header.stamp`` (every stamp of the topic's first
        chunk zero) leaves the log times, when the recorder received each message, as
        the only clock: they are taken for the whole topic, and said. They carry the
        delivery's delays, which the stamp clock re-times where they scatter about the
        period (:class:`.stamp_clock.StampClock`). A topic that has stamps keeps them:
        zero stamps among them are a clock that stands, and said so.
        """
        if topic not in self.unstamped and len(batch):
            logs = batch.log_time_ns
            self.unstamped[topic] = bool(
                logs is not None and not batch.stamps_ns.any() and (logs > 0).all())
            if self.unstamped[topic]:
                warn(self.bag, unstamped_message(
                    topic, 'the recorder received them (log times)'))
        if self.unstamped.get(topic) and batch.log_time_ns is not None:
            batch = replace(batch, stamps_ns=batch.log_time_ns.copy())
        return batch

    def _note_stamps(self, topic, stamps, position):
        """
        Count messages whose header stamp repeats the one before (a clock that stands).

        Those that repeat a stamp once, not in a run, with other positions than the
        message before are counted apart: two streams under one clock (a clock set back
        while recording), neither a message logged twice nor a clock that stands.
        """
        if not stamps.size:
            return
        last = self._last_stamp.get(topic)
        same = stamps[1:] == stamps[:-1]
        self.stamp_repeats[topic] += int(np.count_nonzero(same)) + int(
            last is not None and stamps[0] == last)
        if same.any():
            pair = same.copy()
            pair[1:] &= ~same[:-1]
            pair[:-1] &= ~same[1:]
            a, b = position[1:][pair], position[:-1][pair]
            self.stamp_clashes[topic] += int(np.count_nonzero(
                ((a != b) & ~(np.isnan(a) & np.isnan(b))).any(axis=1)))
        self.zero_stamps[topic] += int(np.count_nonzero(stamps == 0))
        self._last_stamp[topic] = stamps[-1]
        steps = np.diff(stamps)
        steps = steps[steps > 0]
        if steps.size >= 64:     # the period and the scatter of the steps about it
            self.step_scatter.setdefault(topic, []).append(step_scatter(steps))

    def _warn(self):
        """Say what the messages did wrong that the ingestion counts do not name."""
        for topic in self.topics:
            n, repeats = self.messages[topic], self.stamp_repeats[topic]
            if repeats >= 2 and repeats * 100 >= n:   # 1 % or more: a clock that stands
                zeros, clashes = self.zero_stamps[topic], self.stamp_clashes[topic]
                if not zeros and clashes * 2 >= repeats:
                    warn(self.bag, f'{repeats:,} of {n:,} JointState messages on {topic} repeat '
                         f'the header stamp of the message before, {clashes:,} with '
                         'other positions: two streams under one clock, as when the '
                         'clock is set back while recording; the first message of each '
                         'stamp is read, and the operating time the others cover is not '
                         'counted')
                else:
                    kind = 'all zero' if zeros == n else (
                        f'{zeros:,} of them zero' if zeros else
                        'a frozen clock, or each message logged twice')
                    warn(self.bag, f'{repeats:,} of {n:,} JointState messages on {topic} '
                         'carry the header stamp of the message before (stamps that do not '
                         f'advance: {kind}); their samples are dropped as duplicates')
            if self.repeated_names[topic]:
                warn(self.bag, f'{self.repeated_names[topic]:,} JointState entries on {topic} '
                     'named a joint their message had named before; those entries were dropped '
                     '(the first entry of a name counts)')


def stamp_scatter(bag, topic, scatter, clock):
    """Say that a topic's stamps scatter about their period, and whether they were re-timed."""
    if clock.active:
        warn(bag, retimed_message(topic, clock))
        return
    if not scatter:
        return
    period, spread = np.median(np.array(scatter), axis=0).tolist()
    if period > 0 and spread >= CLOCK_SCATTER * period:
        warn(bag, f'the header stamps on {topic} scatter by {spread * 1e-6:.3g} ms about '
                  f'their {period * 1e-6:.3g} ms period ({100 * spread / period:.0f} %): stamped '
                  'when a message arrived rather than when the encoders were read? Speeds, the '
                  "torque smoothing and the encoders' time offset rest on the stamps: each "
                  "window's lost motion is noisier, and the wear can read low")


def merge_partial_messages(batch):
    """
    Merge the messages of a tick that several publishers sent, each with some entries.

    Two ``joint_state_broadcaster`` (or a link and a motor publisher) on one topic each
    send their own entries of a controller tick, with the same stamp or stamps a fraction
    of a period apart, in either order. Taken one by one, the second message of a tick
    repeated or preceded the first's stamp and was dropped with all its entries (a joint
    reported as "stamps do not advance"). Within the chunk the messages are put in stamp
    order where they are at most a period out of it, and neighbours that name disjoint
    entries less than half a period apart become one message (at the first's stamp; the
    entries of one message keep theirs together). Full messages are left alone: a stamp
    that repeats on them is a clock that stands, and said so.

    Parameters
    ----------
    batch : JointStateBatch
        One topic's messages of a chunk, NaN where a message did not name an entry.

    Returns
    -------
    JointStateBatch
        The merged messages.

    """
    t = batch.stamps_ns
    if len(batch) < 2:
        return batch
    steps = np.diff(t)
    # The tick period, from the entry named most often (the stamps of all messages
    # alternate between the publishers' offsets).
    present = np.isfinite(batch.position)
    ticks = np.diff(np.sort(t[present[:, np.argmax(present.sum(axis=0))]]))
    ticks = ticks[ticks > 0]
    if not ticks.size:
        return batch
    period = float(np.median(ticks))
    if (steps < 0).any() and -steps.min() <= period:
        order = np.argsort(t, kind='stable')
        batch, present = batch.take(order), present[order]
        t = batch.stamps_ns
    # Only messages within half a tick of the one before can merge: a stream whose
    # partial messages are bad values of full ones (NaN) has none, and costs no loop.
    close = np.flatnonzero(np.diff(t) < 0.5 * period) + 1
    if not close.size:
        return batch
    pos, vel, eff = (a.copy() for a in (batch.position, batch.velocity, batch.effort))
    keep = np.ones(len(batch), dtype=bool)
    for k in close.tolist():
        j = k - 1
        while not keep[j]:
            j -= 1
        if t[k] - t[j] < 0.5 * period and not (present[k] & present[j]).any():
            take = present[k]
            pos[j, take], vel[j, take], eff[j, take] = pos[k, take], vel[k, take], eff[k, take]
            present[j] |= take
            keep[k] = False
    if keep.all():
        return batch
    log = None if batch.log_time_ns is None else batch.log_time_ns[keep]
    return JointStateBatch(t[keep], batch.names, pos[keep], vel[keep], eff[keep],
                           batch.frame_id, log, ())


def _read_worker(chunks, queue, parent):
    """Read and decode the chunks in a forked process; end with the counts and warnings."""
    end_with_parent(parent)
    try:
        for chunk in chunks:
            queue.put(chunk)
        queue.put((READ_END, {'messages': chunks.messages, 'malformed': chunks.malformed,
                              'merged_topics': chunks.merged_topics,
                              'first_problem': chunks.first_problem,
                              'step_scatter': chunks.step_scatter,
                              'warnings': list(chunks.bag.warnings)}))
    except BaseException as err:  # noqa: B902 - reported to the parent, which raises
        import traceback
        queue.put((READ_ERROR, f'{type(err).__name__}: {err}\n{traceback.format_exc()}'))


class ForkedBagChunks:
    """
    The chunks of :class:`BagChunks`, read and decoded by a forked process.

    The reading process runs a few chunks ahead (a bounded queue); the chunks, their
    order and the counts are the same as when read here. Its read warnings are added to
    this process's bag at the end.
    """

    def __init__(self, chunks):
        import multiprocessing
        ctx = multiprocessing.get_context('fork')
        self.bag = chunks.bag
        self.messages = chunks.messages
        self.malformed = chunks.malformed
        self.merged_topics = chunks.merged_topics
        self.first_problem = chunks.first_problem
        self.step_scatter = chunks.step_scatter
        self._queue = ctx.Queue(maxsize=3)
        self._proc = ctx.Process(target=_read_worker, name='reducer-twin-reader',
                                 args=(chunks, self._queue, parent_of_fork()), daemon=True)
        self._proc.start()

    def __iter__(self):
        while True:
            item = self._queue.get()
            if isinstance(item, dict):
                yield item
                continue
            kind, payload = item
            if kind == READ_ERROR:
                raise RuntimeError(f'the bag reading process failed: {payload}')
            self.messages = payload['messages']
            self.malformed = payload['malformed']
            self.merged_topics = payload['merged_topics']
            self.first_problem = payload['first_problem']
            self.step_scatter = payload['step_scatter']
            for warning in payload['warnings']:
                if warning not in self.bag.warnings:
                    self.bag.warnings.append(warning)
            break
        self._proc.join(timeout=10)

    def terminate(self):
        """Stop the reading process (after an error)."""
        end_process(self._proc)


def joint_columns(batch, names, fields=3):
    """
    Position, velocity and effort columns of the given names (NaN where absent).

    Each in Fortran order: a column is contiguous, and every later pass (cleaning,
    pairing, each joint's front) reads one joint's columns, not every entry of every
    message (as a message's entries are decoded side by side).
    """
    names = list(names)
    fields = (batch.position, batch.velocity, batch.effort)[:fields]
    if names == list(batch.names):
        return [np.asfortranarray(values) for values in fields]
    index = {n: k for k, n in enumerate(batch.names)}
    have = [j for j, name in enumerate(names) if name in index]
    take = [index[names[j]] for j in have]
    out = []
    for values in fields:
        if len(have) == len(names):
            out.append(values.T[take].T)
            continue
        cols = np.full((len(names), len(batch)), np.nan)
        cols[have] = values.T[take]
        out.append(cols.T)
    return out
