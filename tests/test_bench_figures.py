"""Every paper bench and ``bench accuracy`` draws its figure with matplotlib and writes it as PNG and SVG: each
``plot`` fed the figures its bench computes (small made-up numbers of the same shape), the Axes read back.
The benches end to end (their JSON, their tables) are tested in test_cli.py, test_paper3.py,
test_eot_network.py and test_bench_accuracy.py."""
from __future__ import annotations

import numpy as np

from zentrack.bench import accuracy, paper0, paper1, paper2, paper3, paper4


def st(median: float) -> dict:
    return {"median": median, "q25": 0.9 * median, "q75": 1.1 * median, "n": 2}


def written(paths, tmp_path, stem):
    assert paths == [tmp_path / f"{stem}.png", tmp_path / f"{stem}.svg"]
    assert all(p.stat().st_size > 5_000 for p in paths)


def test_paper0_draws_ours_beside_the_papers_row(tmp_path, monkeypatch):
    exps = {"2": {"scenario": "exp2", "steps": 40, "nodes": 10, "runs": 2, "cols": ("p", "v", "tot"), "filters": {
        name: {"paper": None if row is None else dict(zip(("p", "v", "tot", "time_s"), row)),
               "rmse": {c: st(v) for c, v in zip(("p", "v", "tot"), (7.0, 8.0, 10.6 if name != "dekf" else 70.0))},
               "rmse_over_sqrt_bound": {"p": st(1.2), "v": st(1.1)}}
        for name, row in paper0.PAPER_TABLE3.items()}}}
    figures = []
    real = paper0.save_png_svg
    monkeypatch.setattr(paper0, "save_png_svg", lambda fig, path: figures.append(fig) or real(fig, path))
    written(paper0.plot(exps, tmp_path / "p0.png"), tmp_path, "p0")
    rmse_ax, ratio_ax = figures[0].axes[:2]
    assert rmse_ax.get_yscale() == "log", "DEKF's 70 m beside 10 m: a log scale"
    crosses = [line for line in rmse_ax.get_lines() if line.get_marker() == "x"]
    assert len(crosses) == 5, "the paper's five rows (CTESKF has none)"
    assert [t.get_text() for t in rmse_ax.get_xticklabels()] == [n.upper() for n in paper0.PAPER_TABLE3]
    assert ratio_ax.get_ylabel() == "RMSE p / sqrt(PCRLB)"


def test_paper1_draws_fused_locals_and_the_bound(tmp_path):
    k = 30
    curves = {name: {"fused_p": list(np.linspace(5, 3, k)), "fused_v": list(np.linspace(2, 1, k)),
                     "local_p": [list(np.linspace(6, 4, k))] * 3, "local_v": [list(np.linspace(3, 2, k))] * 3}
              for name in paper1.COLORS}
    written(paper1.plot(curves, np.full(k, 2.0), np.full(k, 0.8), 0.5, tmp_path / "p1.png"), tmp_path, "p1")


def test_paper2_draws_every_method_and_the_sweep(tmp_path):
    rows = {m: {"rmse_p": 400.0 + i, "rmse_v": 40.0 + i} for i, m in enumerate(paper2.METHODS + paper2.REFERENCES)}
    out = {"runs": 2, "scenarios": {"dce-ici": {"rows": rows, "l_star": 11.8, "paper_dce_ici": {"rmse_p": 684.19,
                                                                                                "rmse_v": 23.41},
                                                "bound": {"sqrt_pcrlb_p_mean": 573.0, "sqrt_pcrlb_v_mean": 51.7}}},
           "rmse_vs_rounds": {"scenario": "dce-ici", "L": [1, 2, 4, 12], "rmse_p": [499, 435, 422, 421],
                              "rmse_v": [41, 39.3, 39.4, 39.5]}}
    written(paper2.plot(out, tmp_path / "p2.png"), tmp_path, "p2")
    no_sweep = {"runs": 1, "scenarios": {"dce-ici": {**out["scenarios"]["dce-ici"], "rows": {"dce-ici": rows["dce-ici"]}}}}
    written(paper2.plot(no_sweep, tmp_path / "p2b.png"), tmp_path, "p2b")  # --no-sweep: still a figure


def test_paper3_and_paper4_draw_one_panel_per_case(tmp_path):
    curves3 = {s: {f: list(np.linspace(8, 12, 20) + (60 if f == "lin" else 0)) for f in paper3.FILTERS}
               for s in ("seckf-power", "seckf-turn")}
    written(paper3.plot(curves3, 400, tmp_path / "p3.png"), tmp_path, "p3")
    curves4 = {f"eot-s2 lambda={r}": {m: list(np.linspace(30, 10, 12)) for m in ("ceot", "ci L=6", "cm L=6", "deot")}
               for r in (5, 10)}
    metrics = {case: "GW distance (m)" for case in curves4}
    written(paper4.plot(curves4, metrics, tmp_path / "p4.png"), tmp_path, "p4")


def test_accuracy_names_every_rule_once_on_its_axis(tmp_path, monkeypatch):
    rows = [{"filter": "c" + f, "rule": None, "bytes_per_node_step": 0,
             "rmse_over_sqrt_bound": {"p": st(1.05)}} for f in ("teskf", "ekf")]
    rows += [{"filter": "d" + f, "rule": r, "bytes_per_node_step": b,
              "rmse_over_sqrt_bound": {"p": st(9.0 if f == "ekf" and r == "ci" else 1.3)}}
             for f in ("teskf", "ekf") for r, b in (("ci", 329), ("ci-fast", 329), ("ci+share", 522))]
    figures = []
    real = accuracy.save_png_svg
    monkeypatch.setattr(accuracy, "save_png_svg", lambda fig, path: figures.append(fig) or real(fig, path))
    results = [{"scenario": "exp2", "nodes": 10, "steps": 60, "runs": 2, "rows": rows}]
    written(accuracy.plot(results, tmp_path / "acc.png"), tmp_path, "acc")
    ax = figures[0].axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["ci\n329 B", "ci-fast\n329 B", "ci+share\n522 B"]
    assert ax.get_xlabel() == "fusion rule (payload bytes per node per step)"
    assert ax.get_ylabel() == "position RMSE / sqrt(PCRLB)"
    assert ax.get_ylim()[1] <= accuracy.PLOT_CAP * 1.05, "DEKF's 9 is drawn at the cap"
    assert any(line.get_marker() == "^" for line in ax.get_lines()), "as a triangle"
