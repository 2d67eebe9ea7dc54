"""The capacity model (zentrack.study.capacity) and ``zentrack bench capacity``: the fit recovers the costs a
synthetic bench scale JSON was made from, the priors crossing hosts are the graph's own count, predictions
scale as the message counts say, and bad input is one line with exit status 2."""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from zentrack.bench.scale_graph import ring_lattice_adjacency
from zentrack.cli import main
from zentrack.cluster.deployment.compose import host_of
from zentrack.study.capacity import (
    block_sizes,
    fit,
    fit_model,
    observations,
    prior_copies,
    router_link_messages,
    router_messages,
)

TS = 0.1
#: the costs the synthetic runs are made from (ms per step; bytes per message; bytes per step per link role)
TRACKER_A, TRACKER_B = 1.3, 0.21
ROUTER_R0, ROUTER_R1 = 0.9, 0.017
TRUTH, RECORDER = (0.4, 0.03), (0.6, 0.12)
BYTES = {"meas": 170.0, "prior": 880.0, "est": 500.0}
CONST = {"tracker_up": 30.0, "tracker_down": 12.0, "truth_up": 9.0, "recorder_down": 25.0}


def synthetic_result(n: int, d: int) -> dict:
    """One bench scale result whose CPU and link bytes follow the model's form exactly (per second at 1/TS)."""
    up = (BYTES["prior"] + BYTES["est"] + CONST["tracker_up"]) / TS
    down = (BYTES["meas"] + d * BYTES["prior"] + CONST["tracker_down"]) / TS
    links = {f"node-{i}": {"bytes_to_router_per_s": up, "bytes_from_router_per_s": down,
                           "messages_accepted_per_s": (1 + d) / TS} for i in range(n)}
    links["truth"] = {"bytes_to_router_per_s": (n * BYTES["meas"] + CONST["truth_up"]) / TS, "bytes_from_router_per_s": 5.0}
    links["recorder"] = {"bytes_to_router_per_s": 3.0, "bytes_from_router_per_s": (n * BYTES["est"] + CONST["recorder_down"]) / TS}
    handled = 3 * n + n * (2 + d)  # received: meas, prior, est per tracker; written: meas, d priors, est
    cpu = {"tracker": TRACKER_A + TRACKER_B * (1 + d), "router": ROUTER_R0 + ROUTER_R1 * handled,
           "truth": TRUTH[0] + TRUTH[1] * n, "recorder": RECORDER[0] + RECORDER[1] * n}
    return {"nodes": n, "degree": d, "router_links": {"links": links},
            "cpu_ms_per_step": {k: {"mean_ms": v} for k, v in cpu.items()}}


def synthetic_doc(sizes=(8, 16, 24), degrees=(2, 4, 6)) -> dict:
    return {"command": "bench scale", "ts": TS, "results": [synthetic_result(n, d) for d in degrees for n in sizes]}


def test_the_fit_recovers_the_costs_the_runs_were_made_from():
    model = fit_model(observations(synthetic_doc()))
    assert model.tracker.coef["const"] == pytest.approx(TRACKER_A)
    assert model.tracker.coef["messages_in"] == pytest.approx(TRACKER_B)
    assert model.tracker.coef["messages_out"] is None  # always 2 per step: not told apart from the constant
    assert model.router.coef == pytest.approx({"const": ROUTER_R0, "messages_routed": ROUTER_R1})
    assert model.truth.coef == pytest.approx({"const": TRUTH[0], "nodes": TRUTH[1]})
    assert model.recorder.coef == pytest.approx({"const": RECORDER[0], "nodes": RECORDER[1]})
    assert model.bytes.coef == pytest.approx({**{f"bytes_{k}": v for k, v in BYTES.items()},
                                              **{f"const_{k}": v for k, v in CONST.items()}})
    for f in (model.tracker, model.router, model.truth, model.recorder, model.bytes):
        assert f.rms < 1e-6 and f.max_abs < 1e-6


def test_a_noisy_fit_reports_its_residuals_and_still_lands_near_the_costs():
    rng = np.random.default_rng(3)
    x = np.column_stack([np.ones(40), rng.uniform(3, 9, 40)])
    y = 2.0 + 0.5 * x[:, 1] + rng.normal(0, 0.05, 40)
    f = fit(["const", "slope"], x.tolist(), y.tolist())
    assert f.coef["slope"] == pytest.approx(0.5, abs=0.03)
    assert 0.03 < f.rms < 0.08 and f.max_abs >= f.rms and f.observations == 40


def test_one_degree_only_cannot_tell_the_bytes_of_a_prior_from_the_links_constant():
    model = fit_model(observations(synthetic_doc(degrees=(4,))))
    # router -> tracker = meas + 4 priors + a constant: with d fixed the constant is not identified (the prior's
    # slope takes it), and neither is the tracker CPU's slope in messages in; what was measured still fits
    assert model.bytes.coef["const_tracker_down"] is None and model.tracker.coef["messages_in"] is None
    assert model.bytes.coef["bytes_prior"] != pytest.approx(BYTES["prior"])
    assert model.link_bytes("tracker_down", 16, 4) == pytest.approx(BYTES["meas"] + 4 * BYTES["prior"]
                                                                    + CONST["tracker_down"])
    assert model.bytes.rms < 1e-6


@pytest.mark.parametrize("n, d, hosts", [(n, d, h) for n, d in [(8, 2), (16, 2), (16, 4), (24, 6), (10, 3), (12, 5),
                                                                   (9, 8), (7, 6), (30, 7)]
                                          for h in (1, 2, 3, 4, 5, 8) if h <= n])
def test_priors_crossing_hosts_are_the_graphs_own_count(n, d, hosts):
    adj = ring_lattice_adjacency(n, d)
    brute = np.zeros((hosts, hosts), dtype=int)
    for i in range(n):
        for h in {host_of(int(j), n, hosts) for j in np.flatnonzero(adj[i])} - {host_of(i, n, hosts)}:
            brute[host_of(i, n, hosts), h] += 1
    assert np.array_equal(prior_copies(n, d, hosts), brute)


def test_every_message_written_is_received_once_and_each_tracker_gets_its_own():
    for n, d, hosts in [(16, 2, 4), (24, 6, 3), (12, 5, 2), (16, 4, 1)]:
        routers, links = router_messages(n, d, hosts), router_link_messages(n, d, hosts)
        between = sum(sum(m.values()) for m in links.values())
        # received from clients: 3 per tracker (truth's meas, prior, est), plus what routers write to routers
        assert sum(r["received"] for r in routers) == 3 * n + between
        # written to clients: meas and d priors to every tracker, every estimate to the recorder
        assert sum(r["sent"] for r in routers) == n * (2 + d) + between
        assert sum(block_sizes(n, hosts)) == n


def test_predictions_scale_as_the_message_counts_say():
    model = fit_model(observations(synthetic_doc()))
    p = {d: model.predict(16, d, 1, 10.0)["bytes_per_s"] for d in (2, 4, 6, 8)}
    down = [p[d]["tracker_down"] for d in (2, 4, 6, 8)]
    assert np.diff(down) == pytest.approx([2 * BYTES["prior"] * 10.0] * 3)  # linear in degree, a prior per neighbour
    assert len({round(p[d]["tracker_up"], 6) for d in p}) == 1  # what a tracker sends does not grow with degree
    truth = [model.predict(n, 2, 1, 10.0)["bytes_per_s"]["truth_up"] for n in (8, 16, 32)]
    assert truth[2] - truth[1] == pytest.approx(2 * (truth[1] - truth[0]))  # linear in N
    assert model.predict(16, 2, 1, 20.0)["bytes_per_s"]["tracker_up"] == pytest.approx(2 * p[2]["tracker_up"])
    slow, fast = model.predict(16, 2, 1, 5.0)["capacity"], model.predict(16, 2, 1, 10.0)["capacity"]
    assert slow["trackers_only"] == pytest.approx(2 * fast["trackers_only"])  # twice the rate: half the trackers
    assert fast["with_router"] < fast["trackers_only"]
    one, four = model.predict(16, 2, 1, 10.0), model.predict(16, 2, 4, 10.0)
    assert not any(k.startswith("router-") for k in one["bytes_per_s"])
    # on 4 hosts router 0 still handles every measurement and estimate, the others only their own block's
    assert four["cpu_ms_per_step"]["router"][0] > max(four["cpu_ms_per_step"]["router"][1:])
    assert four["cpu_ms_per_step"]["router"][0] < one["cpu_ms_per_step"]["router"][0]
    # router 1 sends router 0 its 4 trackers' estimates and node 4's prior (node 3, a neighbour, is on host 0)
    assert four["bytes_per_s"]["router-1->router-0"] == pytest.approx(10.0 * (4 * BYTES["est"] + BYTES["prior"]))


def test_bench_capacity_prints_the_fit_and_writes_its_json(tmp_path, capsys):
    src, out = tmp_path / "scale.json", tmp_path / "capacity.json"
    src.write_text(json.dumps(synthetic_doc()))
    assert main(["bench", "capacity", "--fit", str(src), "--nodes", "24", "--hosts", "3", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "not identified" in text and "router-2->router-0" in text
    doc = json.loads(out.read_text())
    assert doc["prediction"]["hosts"] == 3 and len(doc["prediction"]["cpu_ms_per_step"]["router"]) == 3
    assert doc["model"]["router"]["coef"]["messages_routed"] == pytest.approx(ROUTER_R1)


@pytest.mark.parametrize("content, args, words", [
    (None, [], "cannot read"),
    ("no file", [], "--fit: give at least one"),
    ("{not json", [], "cannot read json"),
    (json.dumps({"command": "bench step"}), [], "not the json of"),
    (json.dumps({"command": "bench scale", "ts": TS, "results": [{"nodes": 8, "router_links": None,
                                                          "cpu_ms_per_step": {}}]}), [], "no run"),
    (json.dumps(synthetic_doc(sizes=(8,), degrees=(2,))), [], "at least two sizes or degrees"),
    ("scale", ["--nodes", "9", "--degree", "3"], "even size"),
    ("scale", ["--budget", "1.5"], "--budget"),
    ("scale", ["--nodes", "4", "--hosts", "5"], "at most --nodes"),
    ("scale", ["--check-hosts", "4", "--degree", "4"], "--degree must be 2"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, content, args, words):
    path = tmp_path / "scale.json"
    if content not in (None, "no file"):
        path.write_text(json.dumps(synthetic_doc()) if content == "scale" else content)
    assert main(["bench", "capacity", *(["--fit", str(path)] if content != "no file" else []), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err.lower(), err


@pytest.mark.slow
@pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces need root (CI runs as root)")
def test_four_hosts_in_namespaces_carry_the_bytes_the_model_predicts(tmp_path, capsys):
    """8 trackers over 4 hosts for 20 s (about 45 s in all): every link the model names is measured, the client
    links within 10 % of the prediction, the router links within 25 % (or idle where no message crosses)."""
    fit_file = Path(__file__).resolve().parent.parent / "docs" / "results" / "capacity_scale.json"
    out = tmp_path / "check.json"
    assert main(["bench", "capacity", "--fit", str(fit_file), "--nodes", "8", "--check-hosts", "4",
                 "--duration", "20", "--check-dir", str(tmp_path / "run"), "--json", str(out)]) == 0
    assert "measured/predicted" in capsys.readouterr().out
    check = json.loads(out.read_text())["check"]
    want, got = check["prediction"]["bytes_per_s"], check["measured"]["bytes_per_s"]
    assert want.keys() == got.keys()
    for k in ("tracker_up", "tracker_down", "truth_up", "recorder_down"):
        assert got[k] == pytest.approx(want[k], rel=0.1), k
    for k, v in want.items():
        if k.startswith("router-"):
            assert (got[k] == pytest.approx(v, rel=0.25)) if v else got[k] < 100, (k, v, got[k])
    assert check["measured"]["run"]["estimates_lost"] == 0
    assert not [n for n in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout.split()
                if n.startswith("ztcap-")]  # the harness is down


def test_a_links_rate_is_over_its_own_two_readings():
    """``bench capacity --check-hosts``: the links are read one after another by a process each; under load the
    second reading of a link came 0.5 s later after its start than the first, and a rate over the sampling's
    window (5 s in the test's run) was 10 % high (run 29). Each link's rate is over its own readings."""
    from zentrack.bench.capacity_check import COUNTERS, measured

    zero = {k: 0 for k in COUNTERS}
    links0 = {("router-0", "node-0"): {**zero, "at": 100.0}, ("router-0", "truth"): {**zero, "at": 100.2},
              ("router-0", "recorder"): {**zero, "at": 100.4}}
    links1 = {("router-0", "node-0"): {**zero, "bytes_received": 11_000, "bytes_sent": 5_500, "at": 105.5},
              ("router-0", "truth"): {**zero, "bytes_received": 4_000, "at": 105.2},
              ("router-0", "recorder"): {**zero, "bytes_sent": 8_000, "at": 104.4}}
    rates = measured({}, {}, links0, links1, seconds=5.0, ts=0.1)["bytes_per_s"]
    assert rates["tracker_up"] == pytest.approx(2_000.0) and rates["tracker_down"] == pytest.approx(1_000.0)
    assert rates["truth_up"] == pytest.approx(800.0) and rates["recorder_down"] == pytest.approx(2_000.0)
