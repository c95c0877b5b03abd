"""
Soak benchmark: the 6-joint, 1 kHz bringup with the simulator, for ten minutes.

Runs what ``twin_bringup`` runs with ``twin.simulate`` (simulator, encoder_ingest and,
per joint, te_monitor, wear_estimator and life_publisher; one process, real DDS, the
set-up of ``bench_live_chain.py``) and prints, for issue 6 ("sustained load, with
nothing lost"):

* samples dropped (missing at ingest, unpaired) and messages rejected by any node,
  counted after the start-up (``--settle-s``), and samples published but not analysed;
* process CPU in cores, per 30 s interval and overall;
* resident memory every 30 s, and its growth after the first minute (also by kind:
  anonymous, pages of mapped files, shared memory)
  (``--warmup-s``), once the caches are warm: the first minute fills the model
  tables, the import caches and the executor's pools. The nodes' fixed-size
  latency rings (``te_monitor``: 131 k samples per joint; the simulator's publish
  log) are written through when the nodes are built, so that their filling is not
  taken for growth;
* objects in reference cycles reclaimed by the garbage collector during the run and
  left at the end (the nodes make none in steady operation; a library that does
  grows the young generation until a collection);
* estimator state files written (and whether each file on disk decodes), windows
  analysed, and whether every node survived: still making progress in the last
  interval, nothing raised out of a callback.

Floors: zero drops, memory growth <= 5 MB; over an hour (``--duration-s 3600``), growth
<= 5 MB after the first 5 minutes and a trend <= 0.02 MB/min over the last 30 minutes.

Usage: ``python bench/bench_soak.py [--joints 6] [--duration-s 600] [--warmup-s 60]``
"""

import argparse
from pathlib import Path
import resource
import time

from live_bringup import rss_kinds_mb, rss_mb, start_bringup


def cpu_s():
    """Return the CPU time of this process so far (user + system) [s]."""
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def _mallinfo2():
    """Return glibc's ``mallinfo2`` with its result type set, or None (loaded once)."""
    import ctypes

    class MallInfo2(ctypes.Structure):
        _fields_ = [(name, ctypes.c_size_t) for name in (
            'arena', 'ordblks', 'smblks', 'hblks', 'hblkhd', 'usmblks', 'fsmblks',
            'uordblks', 'fordblks', 'keepcost')]

    try:
        function = ctypes.CDLL('libc.so.6').mallinfo2
    except (OSError, AttributeError):
        return None
    function.restype = MallInfo2
    return function


_MALLINFO2 = []


def allocated_mb():
    """
    Return the memory glibc's malloc has handed out and not got back [MB], or NaN.

    Unlike the RSS, it leaves out the free memory the allocator keeps in its heaps
    (fragmentation, returned to the system only by ``malloc_trim``). Only the main
    arena and large mapped blocks are counted (what ``mallinfo2`` reports).
    """
    if not _MALLINFO2:
        _MALLINFO2.append(_mallinfo2())
    if _MALLINFO2[0] is None:
        return float('nan')
    info = _MALLINFO2[0]()
    return (info.uordblks + info.hblkhd) / 1e6


class CycleCount:
    """Objects in reference cycles that the garbage collector reclaims (none is expected)."""

    def __init__(self):
        import gc
        self.collected = 0
        self.collections = 0
        gc.callbacks.append(self._on_gc)

    def _on_gc(self, phase, info):
        if phase == 'stop':
            self.collected += info['collected']
            self.collections += 1

    def final(self):
        """Run a full collection now; return the objects it found unreachable."""
        import gc
        gc.callbacks.remove(self._on_gc)
        return gc.collect()


class Progress:
    """Counters of every node, to tell that each one keeps working."""

    def __init__(self, nodes, joints):
        self.nodes = nodes
        self.joints = joints

    def snapshot(self):
        """Return the counters that grow while a node works."""
        n = self.nodes
        counts = n['ingest'].counts()
        snap = {'simulator': n['simulator'].sent}
        for j in self.joints:
            snap[f'encoder_ingest {j}'] = counts[j]['published']
            snap[f'te_monitor {j}'] = n['te'][j].samples
            snap[f'wear_estimator {j}'] = sum(n['estimator'][j].statuses.values())
            life = n['life'][j].last
            snap[f'life_publisher {j}'] = 0.0 if life is None else life[0]['stamp_s']
        return snap

    def dropped(self):
        """Return the samples lost (missing, unpaired) and the messages refused, by kind."""
        n = self.nodes
        counts = n['ingest'].counts()
        out = {'missing': 0, 'unpaired': 0, 'rejected messages': n['ingest'].rejects.total}
        for j in self.joints:
            out['missing'] += sum(v for k, v in counts[j].items() if k.endswith('_missing'))
            out['unpaired'] += counts[j]['unpaired']
            out['rejected messages'] += (n['te'][j].rejects.total
                                         + n['estimator'][j].rejects.total
                                         + n['life'][j].rejects.total)
        return out


def main():
    """Run the soak and print its figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--joints', type=int, default=6)
    ap.add_argument('--duration-s', type=float, default=600.0,
                    help='whole run, warm-up included [s] (default 600)')
    ap.add_argument('--warmup-s', type=float, default=60.0,
                    help='memory growth is measured after this [s] (default 60)')
    ap.add_argument('--settle-s', type=float, default=5.0,
                    help='drops are counted after this start-up [s] (default 5)')
    ap.add_argument('--sample-s', type=float, default=30.0,
                    help='interval of the RSS and CPU samples [s] (default 30)')
    args = ap.parse_args()
    import numpy as np
    import rclpy
    from reducer_twin.core.errors import StateFileError
    from reducer_twin.io.state_file import decode_state

    nodes, executor, state_dir = start_bringup(args.joints, 'bench-soak-')
    reclaimed = CycleCount()
    state_dir = Path(state_dir)
    joints = list(nodes['te'])
    sim = nodes['simulator']
    progress = Progress(nodes, joints)
    failure = None

    start = time.monotonic()
    marks = sorted({args.settle_s, args.warmup_s,
                    *np.arange(args.sample_s, args.duration_s, args.sample_s).tolist(),
                    args.duration_s})
    samples = []   # (t, rss, cpu, sent, windows, dropped, snapshot, allocated, rss by kind)
    for mark in marks:
        try:
            while time.monotonic() - start < mark:
                executor.spin_once(timeout_sec=0.05)
        except Exception as err:   # noqa: B902 - a node that raised did not survive
            failure = f'{type(err).__name__}: {err}'
            break
        samples.append((time.monotonic() - start, rss_mb(), cpu_s(), sim.sent,
                        sum(te.windows for te in nodes['te'].values()),
                        progress.dropped(), progress.snapshot(), allocated_mb(),
                        rss_kinds_mb()))

    end = samples[-1]
    settled = next(s for s in samples if s[0] >= args.settle_s)
    warm = next(s for s in samples if s[0] >= args.warmup_s)
    wall = end[0] - settled[0]
    cpu = (end[2] - settled[2]) / wall
    dropped = {k: end[5][k] - settled[5][k] for k in end[5]}
    sent = end[3] - settled[3]
    growth = end[1] - warm[1]
    after = [s for s in samples if s[0] >= args.warmup_s]
    slope = (np.polyfit([s[0] / 60.0 for s in after], [s[1] for s in after], 1)[0]
             if len(after) >= 3 else float('nan'))
    # The robot stops; what is in flight drains; then every sample the simulator published
    # must have been paired by ingest and analysed by its TE monitor.
    previous = samples[-2][6] if len(samples) > 1 else {}
    stalled = [name for name, value in end[6].items() if value <= previous.get(name, -1)]
    executor.remove_node(sim)
    drain = time.monotonic() + 2.0
    while time.monotonic() < drain:
        executor.spin_once(timeout_sec=0.05)
    lost = sum(sim.sent - nodes['te'][j].samples for j in joints)
    writers = [nodes['estimator'][j].stage.store.writer for j in joints]
    for j in joints:
        nodes['estimator'][j].close()        # queued updates done, last state written
    written = sum(w.written for w in writers if w is not None)
    write_failures = sum(w.failures for w in writers if w is not None)
    readable = 0
    for j in joints:
        path = state_dir / f'{j}.json'
        try:
            decode_state(path.read_bytes(), path)
            readable += 1
        except (OSError, StateFileError):
            pass

    print(f'soak: {args.joints} joints x {sim.rate_hz:g} Hz for {end[0]:.0f} s, one process, '
          f'{type(executor).__name__}; drops counted after {args.settle_s:g} s, memory '
          f'growth after {args.warmup_s:g} s')
    print('     t [s]   RSS [MB]   CPU [cores]   ticks/s   windows   dropped')
    for prev, cur in zip(samples, samples[1:]):
        dt = cur[0] - prev[0]
        print(f'  {cur[0]:8.0f}   {cur[1]:8.1f}   {(cur[2] - prev[2]) / dt:11.2f}   '
              f'{(cur[3] - prev[3]) / dt:7.0f}   {cur[4]:7d}   {sum(cur[5].values()):7d}')
    print(f'  ticks published      {sent} in {wall:.0f} s ({sent / wall:.0f}/s; '
          f'{args.joints * sent / wall:.0f} samples/s)')
    print(f'  samples dropped      {dropped["missing"] + dropped["unpaired"]} (missing '
          f'{dropped["missing"]}, unpaired {dropped["unpaired"]}); rejected messages '
          f'{dropped["rejected messages"]}; of the {sim.sent * args.joints} samples '
          f'simulated, not analysed after the robot stopped: {lost}   (floor: 0)')
    print(f'  CPU                  {cpu:.2f} cores')
    print(f'  RSS                  {settled[1]:.1f} MB at {settled[0]:.0f} s, {warm[1]:.1f} MB '
          f'at {warm[0]:.0f} s, {end[1]:.1f} MB at {end[0]:.0f} s: growth after '
          f'{warm[0]:.0f} s {growth:+.1f} MB, trend {slope:+.2f} MB/min   (floor: <= 5 MB)')
    # Months, not minutes: is the tail flat? Growth after 5 min, trend of the last 30 min
    # (or of the last half of a shorter run).
    five = next((s for s in samples if s[0] >= 300.0), None)
    tail_from = end[0] - min(1800.0, end[0] / 2.0)
    tail = [s for s in samples if s[0] >= tail_from]
    tail_slope = (np.polyfit([s[0] / 60.0 for s in tail], [s[1] for s in tail], 1)[0]
                  if len(tail) >= 3 else float('nan'))
    if five is not None and five is not end:
        print(f'  RSS after 5 min      {end[1] - five[1]:+.1f} MB from {five[0]:.0f} s to '
              f'{end[0]:.0f} s (floor: <= 5 MB); trend of the last '
              f'{(end[0] - tail_from) / 60:.0f} '
              f'min {tail_slope:+.3f} MB/min (floor: <= 0.02 MB/min over the last 30 min)')
    kinds = ', '.join(f'{kind} {end[8][kind] - warm[8][kind]:+.1f} MB' for kind in end[8])
    print(f'  RSS growth by kind   {kinds or "not reported by this kernel"}')
    print(f'  reference cycles     {reclaimed.collected} objects reclaimed by the collector '
          f'during the run ({reclaimed.collections} young collections); '
          f'{reclaimed.final()} left for a full collection at the end')
    print(f'  malloc in use        {warm[7]:.1f} MB at {warm[0]:.0f} s, {end[7]:.1f} MB at '
          f'{end[0]:.0f} s ({end[7] - warm[7]:+.1f} MB; the RSS also counts the free memory '
          f'the allocator keeps)')
    print(f'  windows analysed     {end[4]}; estimator state files written {written} '
          f'({write_failures} failed), {readable}/{args.joints} files on disk decode')
    survived = failure is None and not stalled
    print(f'  every node survived  {"yes" if survived else "NO"}'
          + (f' (raised: {failure})' if failure else '')
          + (f' (no progress in the last interval: {stalled})' if stalled else ''))
    rclpy.try_shutdown()


if __name__ == '__main__':
    main()
