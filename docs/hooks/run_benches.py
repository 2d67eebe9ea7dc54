"""Run the benchmarks whose JSON the documentation's results tables are rendered from.

Each entry of ``BENCHES`` is one ``zentrack bench`` command (of ``SIMS`` one ``zentrack sim`` run); its JSON goes
to ``docs/results/<name>.json`` and gets a ``produced_by`` block (the command line, the wall time, the UTC date) so every page can say which
settings produced its figures. Run it from the repository root, niced on a shared host:

    nice -n 10 .venv/bin/python docs/hooks/run_benches.py [NAME ...]

Figures a bench draws go to ``out/docs-bench/`` (not into the site).
"""
from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"
PLOTS = Path("out") / "docs-bench"

# name -> the bench's arguments (settings chosen so that each finishes in a few minutes on 2 cores)
BENCHES: dict[str, list[str]] = {
    "speed": ["speed", "--runs", "20", "--rounds", "3"],
    "hops": ["hops", "--pings", "2000"],
    "step": ["step", "--rounds", "3", "--idle-ms", "50"],
    "paper0": ["paper0", "--runs", "20"],
    "paper3": ["paper3", "--plot", str(PLOTS / "paper3.png")],
    "paper2": ["paper2", "--runs", "20", "--plot", str(PLOTS / "paper2.png")],
    "paper1": ["paper1", "--runs", "10", "--plot", str(PLOTS / "paper1.png")],
    "accuracy": ["accuracy", "--runs", "10", "--plot", str(PLOTS / "accuracy.png")],
    "gate": ["gate", "--steps", "300"],
    "latency": ["latency", "--nodes", "10", "--duration", "30"],
    "scale": ["scale", "--sizes", "16,32,48", "--duration", "30", "--plot", str(PLOTS / "scale.png")],
    # the capacity model: fitted on its own bench scale sweep (first), checked in network namespaces (root)
    "capacity_scale": ["scale", "--sizes", "8,16,24", "--degree", "2,4,6", "--router", "--all", "--duration", "20"],
    "capacity": ["capacity", "--fit", "docs/results/capacity_scale.json", "--nodes", "16", "--check-hosts", "4",
                 "--duration", "40"],
    "capacity_24": ["capacity", "--fit", "docs/results/capacity_scale.json", "--nodes", "24", "--check-hosts", "4",
                    "--duration", "40"],
    "startup": ["startup", "--repeat", "3"],
    "multitarget": ["multitarget", "--runs", "1", "--steps", "30", "--plot", str(PLOTS / "multitarget.png")],
    "multitarget_bearing": ["multitarget", "--scenario", "mt-bearing", "--runs", "1",
                            "--plot", str(PLOTS / "multitarget_bearing.png")],
    # the catalogue's other many-target scenarios (issue 53): fifty targets (its first 100 steps: Stone Soup's JPDA
    # on fifty tracks takes minutes), targets born and dying
    "multitarget_mt50": ["multitarget", "--scenario", "mt-50", "--runs", "1", "--steps", "100",
                         "--plot", str(PLOTS / "multitarget_mt50.png")],
    "multitarget_birth_death": ["multitarget", "--scenario", "mt-birth-death", "--runs", "1",
                                "--plot", str(PLOTS / "multitarget_birth_death.png")],
    # real trajectories (issue 34): ships of New York Harbor and aircraft around Paris, on their first 200 scans;
    # radars (point sensors), cameras or photoelectric stations (bearing-only), cameras and two radars (mixed)
    "multitarget_ais": ["multitarget", "--scenario", "ais-nyharbor-radar", "--runs", "1", "--steps", "200",
                        "--plot", str(PLOTS / "multitarget_ais.png")],
    "multitarget_adsb": ["multitarget", "--scenario", "adsb-paris-radar", "--runs", "1", "--steps", "200",
                         "--plot", str(PLOTS / "multitarget_adsb.png")],
    "multitarget_ais_cameras": ["multitarget", "--scenario", "ais-nyharbor-cameras", "--runs", "1", "--steps", "200",
                                "--plot", str(PLOTS / "multitarget_ais_cameras.png")],
    "multitarget_ais_mixed": ["multitarget", "--scenario", "ais-nyharbor", "--runs", "1", "--steps", "200",
                              "--plot", str(PLOTS / "multitarget_ais_mixed.png")],
    "multitarget_adsb_stations": ["multitarget", "--scenario", "adsb-paris", "--runs", "1", "--steps", "200",
                                  "--plot", str(PLOTS / "multitarget_adsb_stations.png")],
    "paper4": ["paper4", "--runs", "5", "--plot", str(PLOTS / "paper4.png")],
    # sensors of their own (issue 52): late and reordered detections per method, Stone Soup beside them
    "async": ["async", "--plot", str(PLOTS / "async.png")],
    # a bearing-only tracker cut off from both neighbours (issue 54): error and NEES per update rule
    "isolated": ["isolated", "--runs", "20", "--plot", str(PLOTS / "isolated.png")],
    # the soak hour's split of step 10800 in memory (issue 54 item 2): a restart beside the bound of its reach
    "split": ["split", "--plot", str(PLOTS / "split.png")],
}


# name -> `zentrack sim`'s arguments: the real-trajectory figures zentrack's own methods give on whole runs (the
# many-target bench runs Stone Soup too, on the first 200 scans; no bench takes a single target on a recorded path)
REAL_FILTERS = ["--runs", "50", "--filter", "teskf,eskf,ekf,ukf,ckf", "--fusion", "ci,centralized"]
SIMS: dict[str, list[str]] = {
    "real_sim_ais_nyharbor": ["--scenario", "ais-nyharbor"],
    "real_sim_ais_nyharbor_cameras": ["--scenario", "ais-nyharbor-cameras"],
    "real_sim_adsb_paris": ["--scenario", "adsb-paris"],
    "real_sim_ais_nyharbor_radar": ["--scenario", "ais-nyharbor-radar"],
    "real_sim_adsb_paris_radar": ["--scenario", "adsb-paris-radar"],
    "real_single_ais_vessel": ["--scenario", "ais-vessel", *REAL_FILTERS],
    "real_single_adsb_aircraft": ["--scenario", "adsb-aircraft", *REAL_FILTERS],
    "real_single_exp2": ["--scenario", "exp2", *REAL_FILTERS],
}


# name -> the command of a run too long for this runner (a live cluster or a soak: minutes to hours): its JSON
# is the run's report, copied into docs/results/ with a produced_by block naming that command
LONG_RUNS: dict[str, str] = {
    "soak_hour_patrol": "zentrack soak --duration 3600 --nodes 8 --kill-every 45 --freeze-every 90 --cut-every 120 "
                        "--truth-stall-every 100 --truth-kill-every 200 --router-every 150 --out out/soak1h",
    "soak_hour_patrol_rejudged": "zentrack soak --rejudge --out out/soak1h",
    "soak_hour_patrol_bound": "zentrack soak --duration 3600 --nodes 8 --kill-every 45 --freeze-every 90 --cut-every 120 "
                              "--truth-stall-every 100 --truth-kill-every 200 --router-every 150 --out out/soak1h",
    "multitarget_live_pmbm": "zentrack run --scenario mt-50 --tracker pmbm --out out/mt50-pmbm && zentrack run "
                             "--scenario mt-50 --out out/mt50-gnn",
    "multitarget_live_adsb": "zentrack run --scenario adsb-paris-radar --tracker pmbm --steps 200 --out out/adsb-pmbm "
                             "&& zentrack run --scenario adsb-paris-radar --steps 200 --out out/adsb-gnn",
    "multitarget_soak_pmbm": "zentrack soak --scenario mt-50-pmbm.toml --duration 150 --kill-every 30 --freeze-every 0 "
                             "--cut-every 0 --out out/soak-mt-pmbm",
    "soak_stack30": "bash deploy/swarm-nodes.sh up --workers 2 --image zentrack:latest && zentrack soak --engine stack "
                    "--image zentrack:latest --duration 1800 --nodes 6 --kill-every 50 --freeze-every 0 --cut-every 0 "
                    "--drain-every 50 --out out/stack30",
}


def run_bench(name: str) -> int:
    """Run one bench (or sim) into docs/results/<name>.json and stamp how it was produced; return its exit
    status."""
    out = RESULTS / f"{name}.json"
    command = ["bench", *BENCHES[name]] if name in BENCHES else ["sim", *SIMS[name]]
    args = ["zentrack", *command, "--json", str(out.relative_to(ROOT))]
    (ROOT / PLOTS).mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()[0]
    t0 = time.monotonic()
    exe = str(Path(sys.executable).parent / "zentrack")
    status = subprocess.run([exe, *args[1:]], cwd=ROOT).returncode
    wall = time.monotonic() - t0
    if out.exists():
        data = json.loads(out.read_text())
        data["produced_by"] = {"command": shlex.join(args), "wall_s": round(wall, 1),
                               "date": datetime.now(UTC).strftime("%Y-%m-%d"), "exit_status": status,
                               "load_avg_1min_at_start": round(load_before, 1)}
        out.write_text(json.dumps(data, indent=1) + "\n")
    print(f"{name}: exit {status}, {wall:.0f} s -> {out.relative_to(ROOT)}", flush=True)
    return status


def main(argv: list[str]) -> int:
    names = argv or [*BENCHES, *SIMS]
    long = [n for n in names if n in LONG_RUNS]
    if long:
        print(f"run_benches: {long[0]} is a long run (a live cluster or a soak); run it by hand: {LONG_RUNS[long[0]]}", file=sys.stderr)
        return 2
    unknown = [n for n in names if n not in BENCHES and n not in SIMS]
    if unknown:
        print(f"run_benches: unknown bench {unknown[0]!r} (known: {', '.join([*BENCHES, *SIMS])})", file=sys.stderr)
        return 2
    return max(run_bench(n) for n in names)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
