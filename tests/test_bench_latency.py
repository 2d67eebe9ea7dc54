"""The latency benchmark's schedule arithmetic: how late each posterior was published within its step."""
import numpy as np

from zentrack.bench.latency import publication_after_step_start


def test_publication_lateness_is_measured_from_the_truth_schedule():
    ts, t0 = 0.1, 1000.0
    k = np.arange(6)[:, None]
    t_meas = np.repeat(t0 + k * ts, 2, axis=1)
    t_meas[3, 1] += 0.017  # one late truth publication does not move the schedule (a median)
    t_pub = t_meas + np.array([0.002, 0.004])
    t_pub[4, 0] = np.nan  # a step without a posterior is left out
    t_pub[5, 1] = t0 + 5 * ts + 0.060  # published after a 50 ms deadline
    late = publication_after_step_start(t_meas, t_pub, ts)
    assert late.shape == (11,)
    np.testing.assert_allclose(np.sort(late)[-2:], [0.021, 0.060], atol=1e-9)
    assert np.isclose(late.min(), 0.002)
