"""Encoder streams built by hand at 1 kHz, shared by the tests of the ingestion stage."""

import numpy as np
from reducer_twin.core.ingest import CleanStream, IngestConfig, StreamCleaner

MS = 1_000_000
"""One millisecond in nanoseconds (the 1 kHz period)."""

T0 = 1_763_000_000 * 1_000_000_000
"""First stamp [ns]: a wall-clock time, as ros2_control stamps samples."""

RATIO = 81.0
"""Total ratio of the RV-80E (paper Table 4)."""

CFG = IngestConfig()


def ramp(n, speed=1.0, start=0.3):
    """Return a 1 kHz stream moving at ``speed`` [rad/s]: ``(t_ns, position)``."""
    t = T0 + np.arange(n, dtype=np.int64) * MS
    return t, start + speed * (t - T0) * 1e-9


def motor_at(t_ns, speed=RATIO, start=0.3 * RATIO):
    """Motor angle of a joint turning at 1 rad/s output: linear in time [rad]."""
    return start + speed * (t_ns - T0) * 1e-9


def concat(streams):
    """Join the CleanStreams of successive chunks."""
    streams = [s for s in streams if len(s)]
    if not streams:
        return CleanStream.empty()
    return CleanStream(*(np.concatenate([getattr(s, f) for s in streams])
                         for f in ('t_ns', 'position', 'velocity', 'effort', 'segment')))


def in_chunks(cleaner, t, pos, sizes, vel=None, eff=None):
    """Clean a stream chunk by chunk (``sizes`` cycled) and join the results."""
    out, k, i = [], 0, 0
    while k < t.size:
        size = sizes[i % len(sizes)]
        sl = slice(k, k + size)
        out.append(cleaner.process(t[sl], pos[sl], None if vel is None else vel[sl],
                                   None if eff is None else eff[sl]))
        k += size
        i += 1
    return concat(out)


def clean(t, pos, cleaner=None):
    """Clean a 1-D stream with a fresh cleaner (or the one given)."""
    return (cleaner or StreamCleaner()).process(t, pos, np.full(t.size, 1.0),
                                                np.linspace(0.0, 5.0, t.size))
