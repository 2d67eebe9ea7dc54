"""A soak refuses what it cannot judge (issue 50): a fault schedule that places no fault is refused before
anything starts, saying the least duration that places one; a criterion that a short soak cannot measure
(``rss_growth``) is reported NOT JUDGED with its reason, never FAILED, and the verdict names only criteria
that were judged."""
from __future__ import annotations

import argparse

import pytest

from zentrack.cli import main
from zentrack.cluster.soak.criteria import RSS_LEAST_S, RSS_SAMPLE_S, failed, passed, rss_growth, verdict_lines
from zentrack.cluster.soak.fault_kinds import fault_actions
from zentrack.cluster.soak.faults import least_duration, no_fault_message, schedule


def _args(**kw) -> argparse.Namespace:
    base = dict(duration=10.0, nodes=4, kill_every=5.0, freeze_every=0.0, cut_every=0.0, fault_s=5.0,
                restart_after=3.0, seed=0)
    return argparse.Namespace(**{**base, **kw})


@pytest.mark.parametrize("kw", [dict(), dict(kill_every=0.0, freeze_every=12.0), dict(kill_every=30.0, restart_after=1.0),
                                dict(kill_every=0.0, truth_stall_every=20.0), dict(kill_every=0.0, router_every=40.0)])
def test_the_least_duration_is_the_first_that_places_a_fault(kw):
    args = _args(**kw)
    least = least_duration(args)
    assert least is not None
    assert schedule(argparse.Namespace(**{**vars(args), "duration": float(least)}))
    assert not schedule(argparse.Namespace(**{**vars(args), "duration": float(least - 1)}))
    assert f"is {least} s" in no_fault_message(args)


def test_no_fault_period_at_all_is_named():
    assert least_duration(_args(kill_every=0.0)) is None
    assert "give a fault period" in no_fault_message(_args(kill_every=0.0))


def test_the_issues_ten_second_soak_is_refused_with_exit_2_and_one_line(tmp_path, capsys):
    out = tmp_path / "soak"
    code = main(["soak", "--duration", "10", "--nodes", "4", "--kill-every", "5", "--cut-every", "0", "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--duration 10 places no fault" in err[0], err
    import zentrack.cluster.soak.command as soak

    parser = argparse.ArgumentParser()
    soak.add_arguments(parser)
    args = parser.parse_args(["--duration", "10", "--nodes", "4", "--kill-every", "5", "--cut-every", "0", "--out", "x"])
    assert f"is {least_duration(args)} s" in err[0]
    assert not (out / "report.json").exists() and not (out / "reference").exists(), "nothing ran"


def test_plan_prints_the_schedule_and_starts_and_writes_nothing(tmp_path, capsys):
    """``soak --plan``: every fault of the schedule with its undo, one line each, exit 0, no folder made."""
    out = tmp_path / "soak"
    argv = ["--duration", "120", "--nodes", "4", "--kill-every", "30", "--freeze-every", "60",
            "--cut-every", "0", "--out", str(out)]
    assert main(["soak", *argv, "--plan"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    import zentrack.cluster.soak.command as soak

    parser = argparse.ArgumentParser()
    soak.add_arguments(parser)
    events = schedule(parser.parse_args(argv))
    faults = [e for e in events if e[1] in fault_actions()]
    assert lines[0].startswith("soak plan: patrol, 4 trackers, 120 s, engine loopback")
    assert len(lines) == len(faults) + 2 and lines[-1] == f"{len(faults)} faults; nothing started (--plan)"
    for line, (t, kind, node) in zip(lines[1:], faults):
        assert line.split()[:4] == [f"{t:.1f}", "s", kind, f"node-{node}"], line
        assert {"kill": "restart", "freeze": "thaw"}[kind] in line
    assert not out.exists()
    # a plan is refused like the soak itself when the flags cannot work
    assert main(["soak", "--duration", "10", "--kill-every", "5", "--cut-every", "0", "--out", str(out), "--plan"]) == 2


def _samples(times, values, pid=1):
    return [(t, v, pid) for t, v in zip(times, values)]


def test_rss_growth_is_not_judged_without_two_samples_after_mid_run():
    short = rss_growth({"truth": _samples([0.0, 10.0], [100.0, 150.0])}, duration=10.0)
    assert short["pass"] is None and f"at least {RSS_LEAST_S:g} s" in short["not_judged"]
    grown = rss_growth({"truth": _samples([0.0, 20.0, 30.0, 40.0], [100.0, 100.0, 130.0, 150.0])}, duration=40.0)
    assert grown["pass"] is False and grown["growth_per_process"]["truth"] == pytest.approx(0.5)
    flat = rss_growth({"truth": _samples([0.0, 20.0, 30.0], [100.0, 100.0, 101.0])}, duration=40.0)
    assert flat["pass"] is True
    assert RSS_LEAST_S == 4 * RSS_SAMPLE_S


def test_the_verdict_names_only_judged_criteria():
    criteria = {"no_crash_no_nan": {"pass": True, "crashed": {}, "nan_free": True},
                "rss_growth": rss_growth({}, duration=10.0),
                "nothing_left_running": {"pass": True, "processes": []}}
    assert passed(criteria) and failed(criteria) == []
    lines = verdict_lines(criteria)
    assert any(line.startswith("NOT JUDGED  rss_growth: no long-lived process") for line in lines), lines
    assert not any(line.startswith("FAIL") for line in lines)
    criteria["nothing_left_running"] = {"pass": False, "processes": ["node-1"]}
    assert not passed(criteria) and failed(criteria) == ["nothing_left_running"]
    assert not passed({"rss_growth": rss_growth({}, duration=10.0)}), "nothing judged is no pass"
