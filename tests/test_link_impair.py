"""The userspace impaired link's pure parts (``zentrack/cluster/engines/link_impair.py``): loss, rate, delay, jitter and
order, with an injected clock and random generator; and the CLI's checks of its flags (no root needed)."""
from __future__ import annotations

import random
import subprocess
import sys

import pytest

from zentrack.cluster.engines.link_impair import QUEUE_LIMIT_S, DelayLine, Impairment, LinkModel


def model(**kw) -> LinkModel:
    return LinkModel(Impairment(**kw).validate(), random.Random(7))


def test_a_clean_link_delivers_every_packet_at_once():
    link = model()
    assert [link.admit(t, 100) for t in (0.0, 0.5, 1.0)] == [0.0, 0.5, 1.0]


def test_delay_without_jitter_is_exact():
    link = model(delay_ms=30)
    assert link.admit(1.0, 100) == pytest.approx(1.03)


def test_loss_is_bernoulli_at_the_configured_rate():
    link = model(loss=0.05)
    fates = [link.admit(i * 1e-3, 100) for i in range(20_000)]
    lost = sum(f is None for f in fates)
    assert lost == link.lost
    assert 0.045 < lost / len(fates) < 0.055  # 5 % +- 3.5 standard deviations


def test_jitter_stays_within_its_bounds_spreads_and_never_reorders():
    link = model(delay_ms=30, jitter_ms=10)
    sent = [i * 1e-3 for i in range(5000)]  # a packet every ms: uniform jitter of +-10 ms would reorder them
    delays = [link.admit(t, 100) - t for t in sent]
    assert min(delays) >= 0.020 - 1e-9 and max(delays) <= 0.040 + 1e-9
    assert max(delays) - min(delays) > 0.015  # the jitter is there
    delivered = [t + d for t, d in zip(sent, delays)]
    assert delivered == sorted(delivered)  # order preserved


def test_jitter_on_sparse_packets_is_uniform_around_the_delay():
    link = model(delay_ms=30, jitter_ms=10)
    delays = [link.admit(i * 1.0, 100) - i * 1.0 for i in range(4000)]  # far apart: order costs nothing
    mean = sum(delays) / len(delays)
    assert mean == pytest.approx(0.030, abs=0.0005)
    assert sum(d < 0.025 for d in delays) / len(delays) == pytest.approx(0.25, abs=0.03)


def test_rate_serialises_packets_back_to_back():
    link = model(rate_kbit=80)  # 10 kB/s: a 1000-byte packet takes 0.1 s
    assert [link.admit(0.0, 1000) for _ in range(3)] == pytest.approx([0.1, 0.2, 0.3])
    assert link.admit(10.0, 1000) == pytest.approx(10.1)  # the queue drained meanwhile


def test_rate_tail_drops_beyond_the_queue_limit():
    link = model(rate_kbit=80)
    fates = [link.admit(0.0, 1000) for _ in range(20)]
    kept = [f for f in fates if f is not None]
    assert len(kept) == int(QUEUE_LIMIT_S / 0.1) + 1 and link.overflow == 20 - len(kept)


def test_delay_adds_after_the_rate():
    link = model(delay_ms=30, rate_kbit=80)
    assert link.admit(0.0, 1000) == pytest.approx(0.13)


def test_delay_line_releases_packets_when_due_in_order():
    line = DelayLine()
    line.push(1.0, b"a")
    line.push(1.5, b"b")
    assert line.next_time() == 1.0
    assert line.due(0.9) == [] and line.due(1.2) == [b"a"] and line.due(2.0) == [b"b"]
    assert line.next_time() is None


def test_the_forwarder_argument_round_trips():
    imp = Impairment(30.0, 10.0, 0.05, None)
    assert Impairment.from_arg(imp.to_arg()) == imp
    assert Impairment.from_arg(Impairment(1.0, 0.0, 0.0, 64.0).to_arg()).rate_kbit == 64.0


@pytest.mark.parametrize("kw, flag", [({"loss": 1.0}, "--loss"), ({"loss": -0.1}, "--loss"),
                                      ({"delay_ms": float("nan")}, "--delay-ms"), ({"delay_ms": -1}, "--delay-ms"),
                                      ({"delay_ms": 5, "jitter_ms": 6}, "--jitter-ms"), ({"rate_kbit": 0}, "--rate-kbit"),
                                      ({"rate_kbit": float("inf")}, "--rate-kbit")])
def test_bad_values_name_their_flag(kw, flag):
    with pytest.raises(ValueError, match=flag):
        Impairment(**kw).validate()


@pytest.mark.parametrize("args, flag", [(["--loss", "2"], "--loss"), (["--delay-ms", "nan"], "--delay-ms"),
                                        (["--impair-backend", "tc"], "--impair-backend")])
def test_the_cli_refuses_bad_flags_in_one_line_before_touching_anything(tmp_path, args, flag):
    done = subprocess.run([sys.executable, "-m", "zentrack", "netns", "impair", "router-0", "router-1",
                           "--dir", str(tmp_path / "none"), *args], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and flag in done.stderr, done.stderr
    assert not (tmp_path / "none").exists()


def test_the_cli_needs_two_services(tmp_path):
    done = subprocess.run([sys.executable, "-m", "zentrack", "netns", "clear", "router-0", "--dir", str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "two service names" in done.stderr, done.stderr


def test_netem_gets_the_same_impairment():
    assert Impairment(30.0, 10.0, 0.05, None).netem_args() == ["delay", "30.0ms", "10.0ms", "loss", "5.0%"]
    assert Impairment(5.0, 0.0, 0.0, 512.0).netem_args()[-2:] == ["rate", "512.0kbit"]


def test_impair_without_a_harness_says_so(tmp_path):
    done = subprocess.run([sys.executable, "-m", "zentrack", "netns", "impair", "router-0", "router-1", "--loss", "0.1",
                           "--dir", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "no harness runs" in done.stderr, done.stderr
