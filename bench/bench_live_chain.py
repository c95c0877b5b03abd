"""
Live-chain benchmark: simulator + every twin node, N joints at 1 kHz, one process.

Runs the bringup (``twin_bringup`` with the simulator, as configured by
default: ingest hands its pairs to the TE monitors in process) with the
controller stream over real DDS on this machine and prints, for the measured
period after a warm-up: samples published and dropped (missing at ingest,
unpaired), process CPU in cores, the sample-to-TE latency p50/p99/max (from
the moment the simulator published a sample to the moment its TE was
computed in ``te_monitor``; also from the sample's stamp, which adds the
simulator's own lateness), windows analysed, resident memory, and the CPU
time the hypervisor gave to other guests during the run (steal: it shows in
the latency tail). Issue floors: 6 joints x 1 kHz for 60 s, zero drops,
CPU <= 1 core, latency p99 <= 5 ms.

Usage: ``python bench/bench_live_chain.py [--joints 6] [--duration-s 60]``
"""

import argparse
import os
import resource
import time

from live_bringup import rss_mb, start_bringup, steal_s


def main():
    """Run the benchmark and print its figures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--joints', type=int, default=6)
    ap.add_argument('--duration-s', type=float, default=60.0)
    ap.add_argument('--warmup-s', type=float, default=5.0)
    args = ap.parse_args()
    import numpy as np
    import rclpy
    nodes, executor, _ = start_bringup(args.joints, 'bench-live-')
    joints = list(nodes['te'])
    sim = nodes['simulator']

    def spin_for(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)

    spin_for(args.warmup_s)
    for te in nodes['te'].values():
        te.latency.reset()
    counts0 = nodes['ingest'].counts()
    sent0 = sim.sent
    rss0 = rss_mb()
    ru0 = resource.getrusage(resource.RUSAGE_SELF)
    steal0 = steal_s()
    t0 = time.monotonic()
    steal_marks = [steal0]            # the hypervisor's steal at the end of each 10 s
    while time.monotonic() - t0 < args.duration_s - 1e-3:
        spin_for(min(10.0, args.duration_s - (time.monotonic() - t0)))
        steal_marks.append(steal_s())
    wall = time.monotonic() - t0
    ru1 = resource.getrusage(resource.RUSAGE_SELF)
    steal1 = steal_s()
    counts1 = nodes['ingest'].counts()
    cpu = (ru1.ru_utime - ru0.ru_utime + ru1.ru_stime - ru0.ru_stime) / wall
    sent = sim.sent - sent0
    dropped = 0
    for j in joints:
        for key, value in counts1[j].items():
            if key.endswith('_missing') or key == 'unpaired':
                dropped += value - counts0[j][key]
    for te in nodes['te'].values():
        te.flush_latency()
    records = [te.latency.records() for te in nodes['te'].values()]
    stamps = np.concatenate([r[0] for r in records])
    te_time = np.concatenate([r[1] for r in records])
    lat = (te_time - stamps) * 1e3
    published = sim.publish_times(np.round(stamps * 1e9).astype(np.int64)) * 1e-9
    known = published > 0
    twin = (te_time[known] - published[known]) * 1e3
    late = (published[known] - stamps[known]) * 1e3
    windows = sum(te.windows for te in nodes['te'].values())
    behind = (time.monotonic() - t0) * sim.rate_hz - sent
    print(f'live chain: {args.joints} joints x {sim.rate_hz:g} Hz for {wall:.1f} s '
          f'(after {args.warmup_s:g} s warm-up), one process, '
          f'{type(executor).__name__}')
    print(f'  ticks published      {sent} ({sent / wall:.0f}/s; simulator behind by '
          f'{behind:.0f} samples)')
    print(f'  samples dropped      {dropped}   (floor: 0)')
    print(f'  CPU                  {cpu:.2f} cores   (floor: <= 1)')
    print(f'  sample-to-TE latency (published -> TE computed) p50 {np.percentile(twin, 50):.2f} '
          f'ms, p99 {np.percentile(twin, 99):.2f} ms, max {twin.max():.1f} ms over '
          f'{twin.size} samples (floor: p99 <= 5 ms)')
    start = published[known].min()
    slot = ((published[known] - start) // 10.0).astype(int)
    per_slot = [np.percentile(twin[slot == k], 99) for k in range(slot.max() + 1)
                if np.count_nonzero(slot == k) > 100]
    print(f'  p99 of each 10 s     {" ".join(f"{v:.1f}" for v in per_slot)} ms '
          f'(a stall of the whole machine shows as one high interval)')
    if None not in steal_marks:
        stolen = np.diff(steal_marks) / 10.0 / (os.cpu_count() or 1)
        print(f'  steal of each 10 s   {" ".join(f"{v:.0%}" for v in stolen)}')
    print(f'  stamp -> TE, incl. the simulator publishing late: p50 {np.percentile(lat, 50):.2f} '
          f'ms, p99 {np.percentile(lat, 99):.2f} ms; simulator lateness p99 '
          f'{np.percentile(late, 99):.2f} ms')
    print(f'  windows analysed     {windows}; RSS {rss0:.0f} -> {rss_mb():.0f} MB')
    if steal0 is not None and steal1 is not None:
        print(f'  CPU stolen by the hypervisor during the run: '
              f'{(steal1 - steal0) / wall / (os.cpu_count() or 1):.1%} of the machine '
              f'(the latency tail grows with it)')
    rclpy.try_shutdown()


if __name__ == '__main__':
    main()
