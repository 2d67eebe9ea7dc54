"""Attacks on a run: by a plain Zenoh peer on an insecure (default) run, where the nodes' own defences act, and
by an insider holding a tracker's certificate on a secure run, where the router refuses every forgery.

The forger (``tests/forger.py``) re-publishes round-1 priors as the next step's, moved and sent a period before
the real ones (refused as early: their sender could not have made them yet), floods a key with valid or
garbage messages (the flood guard), and forges control messages. The real priors are still fused, and every
node tracks as in the unattacked run measured in the same module. Every cluster is stopped in a ``with`` block.
"""
from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from zentrack.cluster.run.cluster import Cluster
from zentrack.config.run_setup import RunSetup
from zentrack.config.scenario_config import builtin_spec
from zentrack.config.scenario_file import load_scenario, save_scenario
from zentrack.truth.simulation.simulate import simulate

HERE = Path(__file__).parent
STEPS, ATTACK_FROM, ATTACK_STEPS, VICTIM = 400, 60, 100, 0
FLOOD_COUNT, FLOOD_PAD = 50_000, 65_000  # the flood: 50,000 valid priors of 66 KB
SECURE_STEPS = 1500


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("attack")
    return load_scenario(save_scenario(tmp / "exp2.npz", simulate(builtin_spec("exp2", nodes=6, steps=STEPS), runs=1, seed=31)))


def _rss_kb(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"no VmRSS for {pid}")


def _wait_for(cluster: Cluster, step: int, timeout: float = 90.0, beside: Cluster | None = None) -> None:
    """Until ``cluster`` recorded an estimate of ``step`` (draining ``beside``'s recorder too)."""
    end = time.time() + timeout
    while not np.isfinite(cluster.recorder.part.mean[step]).any():
        if time.time() > end:
            raise TimeoutError(f"step {step} not reached in {timeout} s")
        cluster.recorder.drain(0.1)
        if beside is not None:
            beside.recorder.drain(0.0)


def _latest_step(cluster: Cluster) -> int:
    cluster.recorder.drain(0.1)
    return int(np.flatnonzero(np.isfinite(cluster.recorder.part.mean).any(axis=(1, 2)))[-1])


def _errors(out: Path) -> np.ndarray:
    est = np.load(out / "estimates.npz")
    return np.linalg.norm(est["mean"][:, :, :3] - est["truth"][:, None, :3], axis=-1)


def _run(scn, out: Path, gate: float = 1e-3, attack: list[str] | None = None,
         also: list[list[str]] = (), beside: Path | None = None) -> tuple[dict, np.ndarray, dict | None]:
    """One realtime run, attacked from step ATTACK_FROM by ``forger.py ATTACK...`` (and at the same time by a
    forger per entry of ``also``); the first forger's report gets the nodes' memory (kB) before the attack and
    20 steps after it ended, the step at which it ended, and the other forgers' reports (``also``). With
    ``beside``, an unattacked run of the same scenario in that folder goes on at the same time, its own cluster,
    so that both take the host's same load; the report gets its summary and errors (``beside``)."""
    setup = RunSetup.from_data(scn, "teskf", 1e-6, None, "realtime", 0.5, "test")
    setup.gate = gate
    reports = [out / f"forger-{n}.json" for n in range(1 + len(also))]
    memory: dict = {}
    with contextlib.ExitStack() as stack:
        cluster = stack.enter_context(Cluster(setup, out))
        reference = stack.enter_context(Cluster(setup, beside)) if beside is not None else None
        for c in (cluster, reference):
            if c is not None:
                c.start()
        forgers: list[subprocess.Popen] = []
        try:
            if attack:
                _wait_for(cluster, ATTACK_FROM, beside=reference)
                pids = {i: cluster.procs[f"node-{i}"].pid for i in range(scn.nodes)}
                memory["before"] = {i: _rss_kb(pid) for i, pid in pids.items()}
                for report, args in zip(reports, [attack, *also]):
                    forgers.append(subprocess.Popen(
                        [sys.executable, str(HERE / "forger.py"), f"tcp/127.0.0.1:{cluster.port}", cluster.run_name,
                         str(report), *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT))
                end = time.time() + 120
                while any(f.poll() is None for f in forgers) and time.time() < end:
                    cluster.recorder.drain(0.1)
                    if reference is not None:
                        reference.recorder.drain(0.0)
                for f in forgers:
                    assert f.poll() == 0, f.communicate()[0]
                memory["ended_at"] = _latest_step(cluster)
                _wait_for(cluster, min(memory["ended_at"] + 20, scn.steps - 1), beside=reference)
                memory["after"] = {i: _rss_kb(pid) for i, pid in pids.items()}
            if reference is not None:  # both runs' recorders drained until both truths have ended
                end = time.time() + 180
                while any(c.procs["truth"].poll() is None for c in (cluster, reference)) and time.time() < end:
                    cluster.recorder.drain(0.05)
                    reference.recorder.drain(0.05)
                assert reference.wait(timeout=max(1.0, end - time.time())) == 0
            assert cluster.wait(timeout=180) == 0
        finally:
            for f in forgers:
                if f.poll() is None:
                    f.kill()
                    f.wait(timeout=10)
        summary = cluster.write_results()
        beside_summary = reference.write_results() if reference is not None else None
    err = _errors(out)
    if not attack:
        return summary, err, None
    first = json.loads(reports[0].read_text())
    extra = {"beside": (beside_summary, _errors(beside))} if beside is not None else {}
    return summary, err, {**first, **memory, "also": [json.loads(r.read_text()) for r in reports[1:]], **extra}


@pytest.fixture(scope="module")
def clean(scenario, tmp_path_factory):
    """The unattacked run: its summary, its errors and its output folder."""
    out = tmp_path_factory.mktemp("clean") / "run"
    summary, err, _ = _run(scenario, out)
    return summary, err, out


def _rmse(err: np.ndarray, steps: slice) -> np.ndarray:
    return np.sqrt(np.nanmean(err[steps] ** 2, axis=0))


# The forged-control test judges deadline misses, which the host's load makes as well as an attack: its unattacked
# reference runs beside it, at the same time, as its own cluster (`_run(beside=...)`), so that both take the
# same load. Against a reference made at another time, the forged run missed 6-8 deadlines beside two other
# real-time tests (runs 15 and 17 of docs/testing.md) and 6 in CI of stop 63, with 0 in both runs alone, beside
# a busy loop and beside the fast suite on 5 workers.
@pytest.mark.slow
def test_forged_stops_and_starts_are_refused_and_the_run_goes_on(scenario, tmp_path):
    """The truth's control messages forged during an insecure realtime run: a stop long before the end while
    the truth is alive, and a start with a t0 two minutes earlier, both 50 times. Every tracker refuses them
    (counted ``conflict``), keeps estimating every step to the end and tracks as in the unattacked run made at
    the same time, missing no more deadlines than it."""
    attacked, err, report = _run(scenario, tmp_path / "ctl", attack=["ctl", "stop", "50"],
                                 also=[["ctl", "start", "50"]], beside=tmp_path / "reference")
    clean, clean_err = report["beside"]
    assert report["sent"] == 50 and report["also"][0]["sent"] == 50
    for n in attacked["nodes"]:
        # every forged start is a conflict; the stops hold the node for up to 3 s waiting for the truth to leave
        # and count one conflict per such wait (50 stops 0.1 s apart: 2)
        conflicts = n["messages"]["rejected"].get("conflict", 0) + sum(n["messages"]["dropped"].values())
        assert 50 + 1 <= conflicts <= 50 + 3, n["messages"]
        assert n["steps_estimated"] >= STEPS - 5 and n["final_report"], n
    for n in clean["nodes"]:  # the reference was not attacked
        assert not n["messages"]["rejected"].get("conflict"), n["messages"]
    after = slice(ATTACK_FROM, STEPS)
    assert np.all(_rmse(err, after) < 1.5 * _rmse(clean_err, after)), (_rmse(err, after), _rmse(clean_err, after))
    assert attacked["network"]["deadline_misses"] <= clean["network"]["deadline_misses"] + 5, (
        attacked["miss_notes"], clean["miss_notes"])


@pytest.mark.slow
def test_a_token_of_a_tracker_the_run_does_not_have_is_not_a_participant(tmp_path):
    scn = load_scenario(save_scenario(tmp_path / "exp2.npz", simulate(builtin_spec("exp2", nodes=3, steps=40), runs=1, seed=2)))
    setup = RunSetup.from_data(scn, "teskf", 1e-6, None, "lockstep", 0.5, "test")
    with Cluster(setup, tmp_path / "run", truth_args=["--step-timeout", "20"]) as cluster:
        token = subprocess.Popen([sys.executable, str(HERE / "forger.py"), f"tcp/127.0.0.1:{cluster.port}",
                                  cluster.run_name, str(tmp_path / "token.json"), "token", "9", "60"],
                                 stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        try:
            cluster.start()
            t0 = time.time()
            assert cluster.wait(timeout=150) == 0  # not stalled for the step timeout (40 x 20 s), not aborted
            took = time.time() - t0
            summary = cluster.write_results()
            assert token.wait(timeout=30) == 0, token.communicate()[0]  # it saw the stop: held through the run
        finally:
            if token.poll() is None:
                token.kill()
                token.wait(timeout=10)
    assert took < 20, took
    assert json.loads((tmp_path / "token.json").read_text())["held_until_stop"]
    assert all(n["steps_estimated"] == 40 for n in summary["nodes"])
    truth_log = (tmp_path / "run" / "logs" / "truth.log").read_text()
    assert "participants [0, 1, 2]" in truth_log
    assert "alive/9 is not one of the run's 3 trackers; ignored" in truth_log


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    from zentrack.cluster.deployment.certs import make_certificates

    folder = tmp_path_factory.mktemp("certs")
    make_certificates(folder, nodes=6)
    return folder


def _secure_lockstep(scn, outs: dict[str, Path], certs: Path, attacks: dict[str, list[list[str]]]) -> dict[str, tuple[dict, np.ndarray, list[dict]]]:
    """Secure lockstep runs of ``scn``, one per entry of ``outs``, side by side (a lockstep run's estimates do not
    depend on its timing); each run's attacks (``attacks[name]``) are forgers holding node 1's certificate,
    started with its cluster. Returns, per run, its summary, its estimates and its forgers' reports."""
    setup = RunSetup.from_data(scn, "teskf", 1e-6, None, "lockstep", 0.5, "test")
    env = {**os.environ, "FORGER_SECURE": f"{certs}:node-1"}
    forgers: list[subprocess.Popen] = []
    with contextlib.ExitStack() as stack:
        clusters = {name: stack.enter_context(Cluster(setup, out, run=f"{name}{os.getpid()}", secure=str(certs)))
                    for name, out in outs.items()}  # (each its own run name: they start in the same millisecond)
        try:
            for name, cluster in clusters.items():
                cluster.start()
                for n, attack in enumerate(attacks.get(name, [])):
                    forgers.append(subprocess.Popen(
                        [sys.executable, str(HERE / "forger.py"), cluster.endpoint, cluster.run_name,
                         str(outs[name] / f"forger-{n}.json"), *attack], env=env, stdout=subprocess.PIPE,
                        stderr=subprocess.STDOUT))
            for cluster in clusters.values():  # (the estimates of one run queue in its recorder meanwhile)
                assert cluster.wait(timeout=300) == 0
            for f in forgers:
                assert f.wait(timeout=120) == 0, f.communicate()[0]
        finally:
            for f in forgers:
                if f.poll() is None:
                    f.kill()
                    f.wait(timeout=10)
        summaries = {name: cluster.write_results() for name, cluster in clusters.items()}
    return {name: (summaries[name], np.load(out / "estimates.npz")["mean"],
                   [json.loads((out / f"forger-{n}.json").read_text()) for n in range(len(attacks.get(name, [])))])
            for name, out in outs.items()}


@pytest.mark.slow
def test_in_secure_mode_an_insiders_forgeries_never_reach_anyone(certs, tmp_path):
    scn = load_scenario(save_scenario(tmp_path / "exp2.npz", simulate(builtin_spec("exp2", nodes=6, steps=SECURE_STEPS),
                                                                      runs=1, seed=31)))
    attacks = [["prior", "0", "1000", "50"], ["ctl", "stop", "50"], ["ctl", "start", "50"], ["token", "0", "300"],
               ["flood", "0", "2000", "65000"]]
    runs = _secure_lockstep(scn, {"clean": tmp_path / "clean", "attacked": tmp_path / "attacked"}, certs,
                            {"attacked": attacks})
    (clean, clean_mean, _), (attacked, mean, reports) = runs["clean"], runs["attacked"]
    assert reports[0]["forged"] == 50 and reports[4]["sent"] == 2000  # the forger did publish ...
    assert reports[3]["held_until_stop"]  # ... and held node 0's token through the whole run
    np.testing.assert_array_equal(mean, clean_mean)  # ... and nothing changed, bit for bit
    for n in attacked["nodes"]:  # nothing forged even reached a node: the router dropped it
        msgs = n["messages"]
        assert msgs["rejected"] == {} and msgs["dropped"] == {} and msgs["gated"] == 0, msgs
        assert n["deadline_misses"] == 0 and n["steps_estimated"] == SECURE_STEPS
    for key in ("deadline_misses", "estimates_lost", "gated"):
        assert attacked["network"][key] == clean["network"][key], key
    # (priors that arrive after a node's last fusion, as the run ends, are counted or not: not an outcome)
    assert abs(attacked["network"]["priors_received"] - clean["network"]["priors_received"]) <= 2 * scn.nodes


DUP_STEPS = 300  # per node: the forger re-issues every node's prior early, three copies each, for 300 steps
GARBAGE_RATE, GARBAGE_S = 2000.0, 15.0  # undecodable messages per second on meas/0, for this long
#: the forged copies' effect is judged after the garbage flood (a Python forger at 2000 msg/s takes most of a
#: core of the 2-core host): from this many steps after the attacks began
DUP_JUDGED_FROM = 200


def _mean_pairs_fused(estimates: Path, first: int, last: int) -> np.ndarray:
    """Per node, the mean number of pairs fused over the steps ``first..last`` it estimated."""
    est = np.load(estimates)
    have = np.isfinite(est["mean"][first:last + 1, :, 0])
    return np.array([est["fused"][first:last + 1, i][have[:, i]].mean() for i in range(have.shape[1])])


def _rmse_window(err: np.ndarray, first: int, last: int) -> np.ndarray:
    return _rmse(err, slice(first, min(last + 1, err.shape[0])))


@pytest.mark.slow
@pytest.mark.loads_host  # (a flood takes most of a core)
def test_a_flood_is_dropped_before_decoding_and_leaves_no_trace_after_20_steps(scenario, clean, tmp_path):
    clean, clean_err, _ = clean
    flooded, err, report = _run(scenario, tmp_path / "flood", attack=["flood", str(VICTIM), str(FLOOD_COUNT), str(FLOOD_PAD)])
    assert report["sent"] == FLOOD_COUNT
    print(f"flood: {FLOOD_COUNT} x {FLOOD_PAD // 1000} KB in {report['seconds']:.1f} s, ended at step "
          f"{report['ended_at']}; memory kB before {report['before']}, 20 steps after {report['after']}")
    after = slice(report["ended_at"] + 20, STEPS)
    assert after.start < STEPS - 50, "the flood must end early enough to see the network recover"
    for i in (1, 5):  # node 0's neighbours took the flood
        dropped = flooded["nodes"][i]["messages"]["dropped"]
        rejected = flooded["nodes"][i]["messages"]["rejected"]
        assert sum(dropped.values()) + sum(rejected.values()) >= 0.9 * FLOOD_COUNT, (dropped, rejected)
        assert sum(dropped.values()) >= 0.5 * FLOOD_COUNT, dropped  # most never even decoded
        assert report["after"][i] <= 1.1 * report["before"][i], report
    # 20 steps after the flood every node estimates every step, with its unattacked accuracy
    assert np.isfinite(err[after]).all()
    assert np.all(_rmse(err, after) < 1.5 * _rmse(clean_err, after)), (_rmse(err, after), _rmse(clean_err, after))


@pytest.mark.slow
@pytest.mark.loads_host  # (a flood takes most of a core)
def test_early_copies_of_every_prior_and_a_garbage_flood_cannot_evict_the_real_messages(scenario, clean, tmp_path):
    """The issue's attacks, at once. (1) Every step, for every node, a copy of its prior biased by +50 m
    (inside the gate) and two decoys 1 and 2 km off, sent a period before the real one: every copy sent in
    time is refused as early (its sender could not have made it yet), the real priors are fused, and the network
    tracks within 1.25x its unattacked error. (2) 2000 undecodable messages a second on ``meas/0`` for 15 s: node 0's flood
    guard drops them without using up the bucket the truth's measurements need, so node 0 coasts no more than
    unattacked. The summary counts what was refused, per kind; the unattacked run refused nothing early and
    its gate (almost) no honest message."""
    clean, clean_err, clean_out = clean
    attacked, err, report = _run(scenario, tmp_path / "dup", attack=["dup", "50,1000,2000", str(DUP_STEPS)],
                                 also=[["garbage", "meas/0", str(GARBAGE_RATE), str(GARBAGE_S)]])
    assert report["finished"] and len(report["forged"]) == scenario.nodes, report
    first, last = report["first_step"] + DUP_JUDGED_FROM, report["last_step"]
    assert last - first >= 50, (first, last)
    ratio = _rmse_window(err, first, last) / _rmse_window(clean_err, first, last)
    print(f"forged duplicates: steps {first}-{last}, RMSE ratio per node {np.round(ratio, 2)}")
    # the network within 1.25x; no node near what a fused forgery does (before the early rule: 8-155x)
    assert np.median(ratio) <= 1.25 and np.max(ratio) <= 2.0, ratio
    refused = attacked["network"]["refused"]
    # every node hears two neighbours' priors: each forged 3 times per step. While the garbage forger takes a
    # core, the copying forger falls behind: a copy it sends after the real prior is not early (it conflicts
    # with the real one: node/diffusion/fusion_policy.py). Every copy sent outside the flood's steps is early.
    garbage = report["also"][0]
    flood_steps = int(np.ceil(garbage["seconds"] / scenario.ts))
    assert refused.get("early", 0) >= 0.9 * 3 * 2 * (DUP_STEPS - flood_steps) * scenario.nodes, (refused, garbage)
    # the real priors were fused as in the clean run, in the steps judged (after the flood)
    pairs = {run: _mean_pairs_fused(path / "estimates.npz", first, last)
             for run, path in (("attacked", tmp_path / "dup"), ("clean", clean_out))}
    assert np.all(pairs["attacked"] > pairs["clean"] - 0.1), pairs
    assert garbage["sent"] >= 0.5 * GARBAGE_RATE * GARBAGE_S, garbage
    n0, c0 = attacked["nodes"][0], clean["nodes"][0]
    assert sum(n0["messages"]["dropped"].values()) + n0["messages"]["rejected"].get("undecodable", 0) >= 0.9 * garbage["sent"]
    assert n0["coasted_steps"] <= c0["coasted_steps"] + 3, (n0["coasted_steps"], c0["coasted_steps"], n0["messages"])
    honest = clean["network"]
    assert not honest["refused"].get("early") and honest["gated"] <= 1e-3 * honest["priors_received"] + 2, honest
