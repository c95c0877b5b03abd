"""The features of a batch of windows, read by ``WindowFit`` from a buffered stream."""

import math

import numpy as np
import pytest
from reducer_twin.core.held_effort import HeldEffort
from reducer_twin.core.simulator import JointSimulator, SimConfig
from reducer_twin.core.te_extraction import compute_te, TIME_OFFSET_LINEAR_S
from reducer_twin.core.transmission_error import lost_motion
from reducer_twin.core.window_fit import STILL_SPAN_RAD, WindowFit
from te_streams import PARAMS, RATIO, simulated

WINDOW = 2000     # samples of a 2-s window at the simulator's 1 kHz


def fit():
    """Return a fit with the window analysis's defaults (orders 1, 2, Zc, Zp; 16 bins)."""
    g, rated = PARAMS.geometry, PARAMS.rating.rated_torque
    edges = np.geomspace(0.02, 1.5, 17) * rated
    return WindowFit(PARAMS, (1, 2, g.z_cycloid, g.z_pins), edges,
                     min_bins=2, memory=math.exp(-0.1), compliance_prior=0.3,
                     torque_smoothing_s=0.03, sign_sigmas=3.0, friction=True,
                     friction_memory_windows=30.0, aging_factor=1.0, held_effort=HeldEffort())


def buffer(batch, time_offset_s=0.0):
    """Return the buffer the window analysis keeps of a simulated batch (exact stamps, no gap)."""
    stream = compute_te(batch.t, batch.motor_angle, batch.t + time_offset_s, batch.link_angle,
                        RATIO)
    dt = np.diff(batch.t, prepend=batch.t[0])
    return {'t': batch.t, 'te': stream.te, 'theta': stream.output_angle, 'torque': batch.effort,
            'speed': batch.link_velocity, 'dt': dt, 'gap': np.zeros(batch.t.size)}


def windows(n):
    return [(k * WINDOW, (k + 1) * WINDOW, 'duration') for k in range(n)]


def read(f, buf, n, offset_removed=True):
    return f.analyze(buf, windows(n), 20, offset_removed, lambda t: t)


def test_a_batch_of_windows_reads_the_lost_motion_of_the_units_wear():
    _, b = simulated(wear=10e-6, samples=30000)
    feats = read(fit(), buffer(b), 15)
    assert [f.samples for f in feats] == [WINDOW] * 15
    lm = np.array([f.lost_motion for f in feats])
    assert np.isfinite(lm).sum() >= 8
    assert np.median(lm[np.isfinite(lm)]) == pytest.approx(lost_motion(10e-6, PARAMS), rel=0.02)


def test_the_flank_pool_carries_over_from_one_batch_to_the_next():
    # The same 15 windows read in one batch or in three give the same features: the pool,
    # the friction and the checks are the fit's state, not the batch's.
    _, b = simulated(wear=10e-6, samples=30000)
    buf = buffer(b)
    whole = read(fit(), buf, 15)
    f = fit()
    parts = []
    for k in range(3):
        part = {key: v[k * 5 * WINDOW:(k + 1) * 5 * WINDOW] for key, v in buf.items()}
        parts += read(f, part, 5)
    np.testing.assert_allclose([p.lost_motion for p in parts], [w.lost_motion for w in whole],
                               rtol=1e-9, equal_nan=True)


def test_windows_that_stand_still_read_no_lost_motion_and_are_counted():
    _, b = simulated(wear=10e-6, samples=30000)
    buf = buffer(b)
    still = slice(6 * WINDOW, 9 * WINDOW)     # windows 6-8: the output angle frozen
    buf['theta'] = buf['theta'].copy()
    buf['theta'][still] = buf['theta'][still.start]
    f = fit()
    feats = read(f, buf, 15)
    assert all(np.isnan(feats[k].lost_motion) for k in (6, 7, 8))
    assert f.windows_still == 3 and STILL_SPAN_RAD > 0.0


def test_an_offset_beyond_the_linear_term_is_withheld_until_the_calibration_removes_it():
    # 5 ms between the encoders: the TE carries omega*delta beyond a linear term's reach.
    sim = JointSimulator(PARAMS, SimConfig(initial_wear_m=10e-6, exact_mesh=True, seed=5))
    b = sim.step(30000)
    buf = buffer(b, time_offset_s=5 * TIME_OFFSET_LINEAR_S)
    before = fit()
    feats = read(before, buf, 15, offset_removed=False)
    beyond = [f for f in feats if abs(f.time_offset_s) > TIME_OFFSET_LINEAR_S]
    assert len(beyond) >= 8 and all(np.isnan(f.lost_motion) for f in beyond)
    assert before.windows_offset_unremoved >= 8
    assert before.largest_unremoved_offset_s == pytest.approx(5e-3, rel=0.02)
    after = fit()
    lm = np.array([f.lost_motion for f in read(after, buf, 15)])
    assert np.isfinite(lm).sum() >= 8 and after.windows_offset_unremoved == 0
    assert np.median(lm[np.isfinite(lm)]) == pytest.approx(lost_motion(10e-6, PARAMS), rel=0.03)
