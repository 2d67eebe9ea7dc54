"""``zentrack bench scale``: every size's misses, lost estimates, CPU per step and memory per process type, bytes
per second on each router link, the sweep over node degree and its figure."""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import pytest

from zentrack.bench.scale import cpu_per_step, cpu_seconds, figures, messages_per_s, passes, process_type, steady_window
from zentrack.bench.scale_graph import degrees, ring_lattice_adjacency, with_degree
from zentrack.bench.scale_plot import plot
from zentrack.bench.scale_probe import link_counters, link_rates, memory_mb, memory_per_type, router_sockets
from zentrack.config.scenario_config import builtin_spec
from zentrack.fusion.graphs import is_connected, ring_adjacency


def test_cpu_seconds_of_this_process_grow_with_work_and_a_dead_pid_has_none():
    before = cpu_seconds(os.getpid())
    sum(i * i for i in range(2_000_000))
    assert cpu_seconds(os.getpid()) > before
    assert cpu_seconds(2**22 + 12345) is None


def test_cpu_per_step_groups_trackers_and_keeps_the_other_types_apart():
    before = {"node-0": 1.0, "node-1": 2.0, "truth": 0.5, "recorder": 3.0}
    after = {"node-0": 1.2, "node-1": 2.4, "truth": 0.6, "recorder": 3.3, "viewer": 9.0}  # viewer: no start
    cpu = cpu_per_step(before, after, steps=100)
    assert cpu["tracker"]["processes"] == 2
    assert cpu["tracker"]["mean_ms"] == pytest.approx(3.0) and cpu["tracker"]["max_ms"] == pytest.approx(4.0)
    assert cpu["truth"]["mean_ms"] == pytest.approx(1.0) and "viewer" not in cpu


def test_a_sizes_figures_are_its_runs_counts_and_a_lost_estimate_fails_it():
    """Two trackers, 10 steps: node 1 published 10 estimates of which the recorder got 8 (2 lost), node 0 missed
    its deadline once (9 published, 9 recorded)."""
    def node(published, recorded, late):
        return {"estimates_published": published, "steps_estimated": recorded, "messages": {"late": late},
                "gaps": [[3, 3]] if recorded < 10 else []}

    summary = {"nodes": [node(9, 9, 1), node(10, 8, 0)],
               "network": {"deadline_misses": 1, "latency_ms": {"p50": 1.0}, "estimates": 17, "estimates_lost": 2}}
    r = figures(summary, 2, 10, router=False, cpu={})
    assert (r["published_estimates"], r["estimates"], r["lost_estimates"], r["expected_estimates"]) == (19, 17, 2, 20)
    assert r["published_estimates"] - r["estimates"] == r["lost_estimates"]  # node 0's miss was never published
    assert (r["deadline_misses"], r["late_priors"], r["gaps"], r["topology"]) == (1, 1, 2, "peers")
    assert not passes(r)
    clean = {"nodes": [node(10, 10, 0)] * 2,
             "network": {"deadline_misses": 0, "latency_ms": {}, "estimates": 20, "estimates_lost": 0}}
    assert passes(figures(clean, 2, 10, router=True, cpu={}))
    lost_one = {**clean, "network": {**clean["network"], "estimates": 19, "estimates_lost": 1}}
    assert not passes(figures(lost_one, 2, 10, router=True, cpu={}))


@pytest.mark.slow
def test_bench_scale_reports_every_size_with_lost_estimates_and_cpu(tmp_path):
    """Every figure of a size is the run's own: checked against the run's summary.json, node by node (lost =
    published and never recorded, so a bench that dropped, double-counted or made up a figure fails)."""
    from zentrack.cli import main

    out, runs = tmp_path / "scale.json", tmp_path / "runs"
    assert main(["bench", "scale", "--sizes", "2,3", "--duration", "18", "--all", "--json", str(out),
                 "--out", str(runs)]) == 0
    data = json.loads(out.read_text())
    assert [r["nodes"] for r in data["results"]] == [2, 3]
    for r in data["results"]:
        summary = json.loads((runs / f"n{r['nodes']}" / "summary.json").read_text())
        nodes = summary["nodes"]
        assert len(nodes) == r["nodes"] and r["expected_estimates"] == r["nodes"] * 180
        published = [n["estimates_published"] for n in nodes]
        recorded = [n["steps_estimated"] for n in nodes]
        assert r["published_estimates"] == sum(published) > 0
        assert r["estimates"] == sum(recorded) == summary["network"]["estimates"] <= r["expected_estimates"]
        assert r["lost_estimates"] == sum(max(0, p - k) for p, k in zip(published, recorded, strict=True))
        assert r["deadline_misses"] == summary["network"]["deadline_misses"]
        assert r["passes"] == (r["deadline_misses"] == 0 and r["lost_estimates"] == 0
                               and r["estimates"] == r["expected_estimates"])
        cpu = r["cpu_ms_per_step"]
        assert cpu["tracker"]["processes"] == r["nodes"] and 0 < cpu["tracker"]["mean_ms"] < 100
        assert {"truth", "recorder"} <= set(cpu)
    assert [r["topology"] for r in data["results"]] == ["peers", "peers"]  # auto: a mesh up to 12 trackers
    passing = [r["nodes"] for r in data["results"] if r["passes"]]
    assert data["largest_passing_n"] == (max(passing) if passing else None)


def test_memory_of_a_process_has_rss_above_pss_and_grows_with_what_it_touches():
    # a fresh interpreter, not this worker: an earlier in-process test may have frozen this worker's heap
    # (freeze_heap), and a new block then reuses freed pages already resident (a suite saw RSS 685.7 MB before
    # and after touching 40 MB)
    child = subprocess.Popen([sys.executable, "-c", "import sys, numpy as np; print('ready', flush=True); "
                              "sys.stdin.readline(); b = np.ones(40_000_000 // 8); print('touched', flush=True); "
                              "sys.stdin.readline()"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert child.stdin is not None and child.stdout is not None
    try:
        assert child.stdout.readline().strip() == "ready"
        before = memory_mb(child.pid)
        assert before is not None and 10 < before["rss_mb"] and 0 < before["pss_mb"] <= before["rss_mb"]
        child.stdin.write("\n")
        child.stdin.flush()
        assert child.stdout.readline().strip() == "touched"  # 40 MB, every page written
        after = memory_mb(child.pid)
        assert after["rss_mb"] - before["rss_mb"] > 35 and after["pss_mb"] - before["pss_mb"] > 35
        child.stdin.write("\n")
        child.stdin.flush()
        assert child.wait(timeout=30) == 0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait(timeout=10)
    assert memory_mb(2**22 + 12345) is None


def test_memory_per_type_groups_trackers_with_mean_and_max():
    samples = {"node-0": {"rss_mb": 50.0, "pss_mb": 20.0}, "node-1": {"rss_mb": 70.0, "pss_mb": 30.0},
               "router": {"rss_mb": 40.0, "pss_mb": 25.0}}
    mem = memory_per_type(samples, process_type)
    assert mem["tracker"] == {"rss_mean_mb": 60.0, "rss_max_mb": 70.0, "pss_mean_mb": 25.0, "pss_max_mb": 30.0,
                              "processes": 2}
    assert mem["router"]["processes"] == 1 and set(mem) == {"tracker", "router"}


def test_router_sockets_count_the_bytes_each_way_and_name_the_peer_by_its_pid():
    """A listening socket stands in for the router, a connection from this process for a peer: the bytes
    sent each way show up on the listening side's socket, the link named after the connecting pid."""
    with socket.create_server(("127.0.0.1", 0)) as server:
        port = server.getsockname()[1]
        with socket.create_connection(("127.0.0.1", port)) as client:
            side, _ = server.accept()
            with side:
                client.sendall(b"x" * 100_000)
                got = 0
                while got < 100_000:
                    got += len(side.recv(65536))
                side.sendall(b"y" * 3_000)
                assert len(client.recv(65536)) > 0
                sockets = router_sockets(port)
    assert sockets is not None, "ss (iproute2) is needed for the router links"
    links = link_counters(sockets, port, {os.getpid(): "node-7"})
    assert list(links) == ["node-7"]
    assert links["node-7"]["bytes_received"] == 100_000 and links["node-7"]["bytes_sent"] == 3_000
    assert links["node-7"]["data_segs_in"] >= 1 and links["node-7"]["data_segs_out"] >= 1


def test_link_rates_are_the_counters_differences_per_second_per_link_type_and_in_total():
    def c(sent, received, segs_out=0, segs_in=0):
        return {"bytes_sent": sent, "bytes_received": received, "data_segs_out": segs_out, "data_segs_in": segs_in}

    before = {"node-0": c(100, 50), "node-1": c(0, 0), "truth": c(0, 0), "gone": c(5, 5)}
    after = {"node-0": c(300, 150, 4, 2), "node-1": c(400, 200, 6, 2), "truth": c(10, 1000, 1, 10), "new": c(9, 9)}
    r = link_rates(before, after, 2.0, process_type)
    assert set(r["links"]) == {"node-0", "node-1", "truth"}  # only links seen at both samples
    assert r["links"]["node-0"] == {"bytes_to_router_per_s": 50.0, "bytes_from_router_per_s": 100.0,
                                    "segments_to_router_per_s": 1.0, "segments_from_router_per_s": 2.0}
    assert r["per_type"]["tracker"] == {"mean_bytes_per_s": 225.0, "max_bytes_per_s": 300.0, "links": 2}
    assert r["bytes_to_router_per_s"] == 50 + 100 + 500 and r["bytes_from_router_per_s"] == 100 + 200 + 5
    assert r["total_bytes_per_s"] == 955.0 and r["segments_per_s"] == (6 + 8 + 11) / 2


def test_messages_per_s_is_per_tracker_step_at_the_run_rate():
    before = {"node-0": (100, 3000), "node-1": (100, 3000), "node-2": (50, 10)}
    after = {"node-0": (200, 6000), "node-1": (100, 3000), "node-2": (60, 60)}  # node-1: no new counters
    assert messages_per_s(before, after, 0.1) == {"node-0": 300.0, "node-2": 50.0}


def test_a_short_run_keeps_a_steady_state_and_a_long_one_leaves_out_10_s_and_5_s():
    assert steady_window(60.0) == (10.0, 45.0) and steady_window(30.0) == (10.0, 15.0)
    warmup, steady = steady_window(12.0)
    assert warmup == 4.0 and steady == pytest.approx(6.0)


@pytest.mark.parametrize("n,d", [(8, 2), (8, 3), (9, 4), (10, 5), (16, 7), (5, 4)])
def test_ring_lattice_links_every_node_to_d_others_both_ways(n, d):
    adj = ring_lattice_adjacency(n, d)
    assert (adj.sum(axis=1) == d).all() and (adj == adj.T).all() and not adj.diagonal().any()
    assert is_connected(adj)
    assert adj[0, 1] and adj[0, n - 1], "the ring's own links stay"


def test_degree_2_is_the_scenarios_ring_and_the_spec_takes_the_lattice():
    assert (ring_lattice_adjacency(12, 2) == ring_adjacency(12)).all()
    spec = with_degree(builtin_spec("exp2", nodes=8, steps=5), 4)
    assert spec.graph == "explicit" and (spec.adjacency.sum(axis=1) == 4).all()


@pytest.mark.parametrize("n,d,words", [(4, 4, "at least 5 nodes"), (5, 3, "even size")])
def test_a_degree_the_size_cannot_have_is_refused_naming_both(n, d, words):
    with pytest.raises(ValueError, match=words) as err:
        ring_lattice_adjacency(n, d)
    assert f"--degree {d}" in str(err.value) and str(n) in str(err.value)


@pytest.mark.parametrize("text", ["1", "0,2", "two", ""])
def test_degrees_below_2_or_not_numbers_are_refused(text):
    import argparse

    with pytest.raises(argparse.ArgumentTypeError):
        degrees(text)
    assert degrees("4,2,4") == [2, 4]


@pytest.mark.parametrize("argv", [["--degree", "1"], ["--degree", "x"], ["--sizes", "4,8", "--degree", "4"],
                                  ["--sizes", "6,7", "--degree", "3"]])
def test_bench_scale_refuses_a_bad_degree_in_one_line_with_exit_2_before_starting(argv, capsys, monkeypatch):
    from zentrack.bench import scale
    from zentrack.cli import main

    monkeypatch.setattr(scale, "measure", lambda *a: pytest.fail("a cluster started"))
    try:
        code = main(["bench", "scale", *argv, "--duration", "12"])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--degree" in err, err


def test_the_largest_passing_size_is_per_degree_asked_for_and_the_table_has_memory_and_links(tmp_path, capsys,
                                                                                           monkeypatch):
    """Runs faked (measure replaced): 8 trackers fail at degree 4 only; the scenario's ring of 2 trackers has
    degree 1, and still counts for the ring's sweep."""
    from zentrack.bench import scale
    from zentrack.cli import main

    def fake(n, d, args):
        ok = not (n == 8 and d == 4)
        summary = {"nodes": [], "network": {"deadline_misses": 0 if ok else 3, "latency_ms": {"p99": 7.0},
                                            "estimates": n * 120, "estimates_lost": 0}}
        links = link_rates({"node-0": dict.fromkeys(("bytes_sent", "bytes_received", "data_segs_out",
                                                     "data_segs_in"), 0)},
                           {"node-0": {"bytes_sent": 2000 * n, "bytes_received": 1000, "data_segs_out": 30,
                                       "data_segs_in": 20}}, 1.0, process_type)
        mem = {"tracker": {"rss_mean_mb": 54.5, "rss_max_mb": 55.0, "pss_mean_mb": 25.0, "pss_max_mb": 26.0,
                           "processes": n}}
        return figures(summary, n, 120, True, {}, memory=mem, links=links, degree=1 if n == 2 else d or 2)

    monkeypatch.setattr(scale, "measure", fake)
    out = tmp_path / "s.json"
    assert main(["bench", "scale", "--sizes", "6,8", "--degree", "2,4", "--duration", "12", "--all",
                 "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    assert data["largest_passing_n_by_degree"] == {"2": 8, "4": 6} and data["largest_passing_n"] == 8
    assert [(r["nodes"], r["degree_requested"]) for r in data["results"]] == [(6, 2), (8, 2), (6, 4), (8, 4)]
    text = capsys.readouterr().out
    assert "tracker RSS MB" in text and data["results"][0]["memory_mb"]["tracker"]["processes"] == 6
    assert "N = 8, degree 4: router links 0.017 MB/s in all" in text  # 16 000 + 1 000 bytes in 1 s
    assert main(["bench", "scale", "--sizes", "2,3", "--duration", "12", "--all", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["largest_passing_n"] == 3  # the ring's sweep, not its degree-1 run


def result(n, d, tracker_ms, rss, total):
    return {"nodes": n, "degree": d, "latency_ms": {"p99": 5.0 + n / 10}, "router_links": {
        "total_bytes_per_s": total, "per_type": {"tracker": {"mean_bytes_per_s": total / n}}},
            "cpu_ms_per_step": {k: {"mean_ms": tracker_ms * f} for k, f in (("tracker", 1), ("router", 0.2 * n))},
            "memory_mb": {k: {"rss_mean_mb": rss, "pss_mean_mb": rss / 2} for k in ("tracker", "router")}}


def test_the_figure_draws_cost_against_n_and_against_degree(tmp_path, monkeypatch):
    from zentrack.bench import scale_plot

    figures_drawn = []
    real = scale_plot.save_png_svg
    monkeypatch.setattr(scale_plot, "save_png_svg", lambda fig, path: figures_drawn.append(fig) or real(fig, path))
    results = [result(n, d, 2.0 + d / 10, 55.0, 1e4 * n * d) for d in (2, 4) for n in (8, 16)]
    paths = plot(results, tmp_path / "scale.png")
    assert paths == [tmp_path / "scale.png", tmp_path / "scale.svg"] and paths[0].stat().st_size > 5_000
    axes = figures_drawn[0].axes
    assert len(axes) == 8, "a row against N, a row against degree"
    assert [ax.get_xlabel() for ax in axes[::4]] == ["trackers N", "neighbours per node"]
    by_n_cpu = {line.get_label(): list(line.get_xdata()) for line in axes[0].get_lines()}
    assert by_n_cpu == {"tracker": [8, 16], "router": [8, 16]}  # at degree 2 only
    tracker_by_d = next(line for line in axes[4].get_lines() if line.get_label() == "tracker")
    assert list(tracker_by_d.get_xdata()) == [2, 4] and list(tracker_by_d.get_ydata()) == [2.2, 2.4]  # at N = 16
    net = {line.get_label(): list(line.get_ydata()) for line in axes[3].get_lines()}
    assert net["all links"] == [160.0, 320.0]  # kB/s: 1e4 * n * 2 bytes/s
    one_size = plot([result(8, d, 2.0, 55.0, 1e5) for d in (2, 4)], tmp_path / "d.png")
    assert one_size[0].exists() and len(figures_drawn[1].axes) == 4  # one size: only the degree row


@pytest.mark.slow
def test_bench_scale_measures_memory_and_router_links_and_more_nodes_send_more_bytes(tmp_path):
    """Two sizes through a router, 12 s each: every process's memory and every router link are the run's own
    (a link per tracker, the truth and the recorder), and 8 trackers move more bytes than 4."""
    from zentrack.cli import main

    out = tmp_path / "scale.json"
    assert main(["bench", "scale", "--sizes", "4,8", "--duration", "12", "--router", "--all", "--json", str(out),
                 "--plot", str(tmp_path / "scale.png")]) == 0
    data = json.loads(out.read_text())
    assert (tmp_path / "scale.png").stat().st_size > 5_000
    for r in data["results"]:
        assert r["topology"] == "router" and r["degree"] == 2
        mem = r["memory_mb"]
        assert set(mem) == {"tracker", "router", "truth", "recorder"} and mem["tracker"]["processes"] == r["nodes"]
        for m in mem.values():
            assert 10 < m["rss_mean_mb"] <= m["rss_max_mb"] and 0 < m["pss_mean_mb"] <= m["rss_mean_mb"]
        links = r["router_links"]["links"]
        assert set(links) == {f"node-{i}" for i in range(r["nodes"])} | {"truth", "recorder"}
        for name, link in links.items():
            assert link["bytes_to_router_per_s"] > 0 and link["bytes_from_router_per_s"] > 0, name
        # the truth mostly sends (measurements), the recorder mostly receives (estimates)
        assert links["truth"]["bytes_to_router_per_s"] > links["truth"]["bytes_from_router_per_s"]
        assert links["recorder"]["bytes_from_router_per_s"] > links["recorder"]["bytes_to_router_per_s"]
        # a tracker accepts its own 10 measurements a second and more from its two neighbours
        assert all(link["messages_accepted_per_s"] > 10 for n, link in links.items() if n.startswith("node"))
    small, large = data["results"]
    assert large["router_links"]["total_bytes_per_s"] > 1.5 * small["router_links"]["total_bytes_per_s"]
