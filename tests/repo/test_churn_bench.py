"""bench/churn/churn.py's arithmetic: the RSS slope after the warm-up and the CPU per 5-minute window
(the churn and soak figures of docs/PERFORMANCE.md are these)."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from bench.churn import churn  # noqa: E402  (nothing is started: the agent and ROS only in run())


def test_the_slope_is_megabytes_an_hour_by_least_squares():
    # 1 MB more every 10 minutes, with noise that cancels: 6 MB/h
    points = [(t, 50.0 + t / 600.0 + (0.05 if i % 2 else -0.05)) for i, t in
              enumerate(range(0, 3600, 10))]
    assert churn.slope_mb_per_hour(points) == pytest.approx(6.0, abs=0.05)
    assert churn.slope_mb_per_hour(points[:2]) is None


def test_the_summary_leaves_the_warm_up_out_of_the_slope_and_splits_cpu_by_window():
    # (seconds, RSS MB, agent CPU seconds, publishers): RSS jumps during the first 5 minutes,
    # then stays flat; the agent uses 10 % of a core, then 20 % after 5 minutes.
    samples = []
    cpu = 0.0
    for t in range(0, 901, 10):
        if t:
            cpu += (1.0 if t <= 300 else 2.0)
        samples.append((float(t), 40.0 + min(t, 300) / 30.0, cpu, 3 if t < 900 else 1))
    summary = churn.summarize(samples, warmup_s=300.0)
    assert summary["rss_start"] == 40.0 and summary["rss_warm"] == 50.0
    assert summary["slope_mb_h"] == pytest.approx(0.0, abs=1e-9)
    assert summary["cpu_windows"] == [10.0, 20.0, 20.0]
    assert summary["publishers_end"] == 1 and summary["publishers_max"] == 3
