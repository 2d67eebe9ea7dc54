"""Every bad value, one line: bad input to any command exits with status 2 and ONE line on stderr that names the
file, key or flag at fault and what is allowed; never a traceback, a MemoryError or an OverflowError.

Each case runs the real CLI as a subprocess (``python -m zentrack ...``) on inputs written to a temporary folder:
TOML scenarios derived from ``deploy/scenarios/exp2.toml``, damaged ``.npz`` scenario files, bad Zenoh endpoints
and JSON5 configs, unwritable output folders and absurd counts.
"""
from __future__ import annotations

import socket
import subprocess
import sys
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path

import pytest

from zentrack.config.scenario_config import builtin_spec, resolve
from zentrack.config.scenario_file import save_scenario
from zentrack.truth.simulation.simulate import simulate

pytestmark = pytest.mark.slow  # one zentrack subprocess per case (about a second each)

EXP2 = resolve("exp2")[1]

# name -> (old, new): one key of exp2.toml replaced by a bad value
TOML_CASES = {
    "steps-huge": ("steps = 1000", "steps = 99999999999"),
    "noise-overflow": ("noise_std = 0.017453292519943295", "noise_std = 1e308"),
    "sigma-negative": ("sigma_w = 1.0", "sigma_w = -1"),
    "ts-tiny": ("ts = 0.1 ", "ts = 1e-300 "),
    "radius-tiny": ("radius = 400.0", "radius = 1e-300"),
    "count-huge": ("count = 10", "count = 5000"),
    "height-huge": ("height = 50.0", "height = 1e300"),
    "p0-zero": ("p0_diag = [1.0, 1.0, 1.0, 1.0, 1.0, 1.0]", "p0_diag = [1.0, 1.0, 1.0, 1.0, 1.0, 0.0]"),
    "lumped-var-tiny": ("lumped_var = 1.0", "lumped_var = 1e-300"),
    "deadline-one": ("deadline_frac = 0.5", "deadline_frac = 1.0"),
    "seed-negative": ("seed = 0", "seed = -1"),
    "qbar-huge": ("qbar = 1e-6", "qbar = 1e300"),
}
TOML_KEYS = {
    "steps-huge": "scenario.steps", "noise-overflow": "measurement.noise_std", "sigma-negative": "plant.sigma_w",
    "ts-tiny": "scenario.ts", "radius-tiny": "sensors.radius", "count-huge": "sensors.count",
    "height-huge": "sensors.height", "p0-zero": "initial.p0_diag", "lumped-var-tiny": "initial.lumped_var",
    "deadline-one": "timing.deadline_frac", "seed-negative": "scenario.seed", "qbar-huge": "filter.qbar",
}


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bad")
    for name, (old, new) in TOML_CASES.items():
        assert old in EXP2, old
        (d / f"{name}.toml").write_text(EXP2.replace(old, new, 1))
    good = save_scenario(d / "good.npz", simulate(builtin_spec("exp2", nodes=3, steps=20), runs=1, seed=1))
    data = good.read_bytes()
    (d / "empty.npz").write_bytes(b"")
    (d / "truncated.npz").write_bytes(data[: len(data) // 2])
    corrupt = bytearray(data)
    corrupt[len(data) // 2] ^= 0xFF  # inside a member's data: the zip directory is intact, the CRC is not
    (d / "crc.npz").write_bytes(bytes(corrupt))
    (d / "bad-listen.json5").write_text('{ mode: "peer", listen: { endpoints: ["tcp/127.0.0.1:99999"] } }\n')
    (d / "unbindable.json5").write_text('{ mode: "peer", listen: { endpoints: ["tcp/192.0.2.1:7447"] } }\n')
    (d / "tls-no-key.json5").write_text('{ mode: "peer", listen: { endpoints: ["tls/127.0.0.1:0"] } }\n')
    (d / "not-json5.json5").write_text('{ listen: { endpoints: \n')
    (d / "a-file").write_text("a regular file, not a folder\n")
    return d


def taken_port() -> socket.socket:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    return s


# (case id, arguments with {d} for the inputs folder, what the one line must contain)
CASES = [
    *[(f"toml-{name}", ["truth", "--scenario", f"{{d}}/{name}.toml", "--run", "bad"], [f"{name}.toml", TOML_KEYS[name]])
      for name in TOML_CASES],
    ("toml-run-steps", ["run", "--scenario", "{d}/steps-huge.toml", "--out", "{d}/out-steps"], ["scenario.steps", "1000000"]),
    ("npz-empty", ["sim", "--scenario-file", "{d}/empty.npz"], ["empty.npz", "not a readable .npz"]),
    ("npz-crc", ["sim", "--scenario-file", "{d}/crc.npz"], ["crc.npz", "CRC"]),
    ("npz-truncated", ["sim", "--scenario-file", "{d}/truncated.npz"], ["truncated.npz", "not a readable .npz"]),
    ("npz-crc-node", ["node", "--id", "0", "--scenario-file", "{d}/crc.npz", "--run", "bad"], ["crc.npz", "CRC"]),
    ("node-connect-port", ["node", "--id", "0", "--connect", "tcp/nohost:x", "--run", "bad"], ["--connect", "tcp/nohost:x", "65535"]),
    ("truth-connect-syntax", ["truth", "--connect", "foo", "--run", "bad"], ["--connect", "'foo'", "<protocol>/<address>"]),
    ("status-connect-port", ["status", "--connect", "tcp/nohost:x"], ["--connect", "tcp/nohost:x"]),
    ("health-connect-proto", ["health", "--name", "0", "--connect", "tpc/127.0.0.1:7447"], ["--connect", "unknown protocol 'tpc'"]),
    ("viewer-listen-syntax", ["viewer", "--save", "{d}/v.rrd", "--listen", "127.0.0.1:7447", "--run", "bad"], ["--listen", "127.0.0.1:7447"]),
    ("status-config-bad-listen", ["status", "--zenoh-config", "{d}/bad-listen.json5"], ["bad-listen.json5", "listen.endpoints", "65535"]),
    ("truth-config-unbindable", ["truth", "--zenoh-config", "{d}/unbindable.json5", "--run", "bad"],
     ["unbindable.json5", "cannot open a Zenoh session", "192.0.2.1"]),
    ("truth-config-tls-no-key", ["truth", "--zenoh-config", "{d}/tls-no-key.json5", "--run", "bad"],
     ["tls-no-key.json5", "cannot open a Zenoh session", "TLS private key"]),
    ("status-config-not-json5", ["status", "--zenoh-config", "{d}/not-json5.json5"], ["not-json5.json5", "not a valid Zenoh config"]),
    ("router-listen-syntax", ["router", "--listen", "foo"], ["--listen", "'foo'"]),
    ("router-listen-port", ["router", "--listen", "tcp/127.0.0.1:x"], ["--listen", "tcp/127.0.0.1:x"]),
    ("router-listen-unbindable", ["router", "--listen", "tcp/192.0.2.1:7447"], ["--listen tcp/192.0.2.1:7447", "cannot open a Zenoh session"]),
    ("router-listen-taken", ["router", "--listen", "tcp/127.0.0.1:{port}"], ["--listen tcp/127.0.0.1:", "in use"]),
    ("router-connect-syntax", ["router", "--connect", "tcp/:7447"], ["--connect", "tcp/:7447"]),
    ("router-config-not-json5", ["router", "--zenoh-config", "{d}/not-json5.json5"], ["not-json5.json5", "not a valid Zenoh config"]),
    ("router-config-tls-no-key", ["router", "--zenoh-config", "{d}/tls-no-key.json5"], ["tls-no-key.json5", "TLS private key"]),
    ("router-config-missing", ["router", "--zenoh-config", "{d}/missing.json5"], ["missing.json5", "not a valid Zenoh config"]),
    ("run-out-under-a-file", ["run", "--out", "{d}/a-file/out", "--steps", "10", "--nodes", "2"], ["--out", "a-file", "not a folder"]),
    ("sim-json-under-a-file", ["sim", "--steps", "10", "--json", "{d}/a-file/x.json"], ["--json", "a-file"]),
    ("run-steps-huge", ["run", "--steps", "99999999999", "--out", "{d}/out-huge"], ["--steps", "1000000"]),
    ("sim-steps-huge", ["sim", "--steps", "99999999999"], ["--steps", "1000000"]),
    ("sim-node-steps", ["sim", "--runs", "5000", "--steps", "5000"], ["--runs x --steps x --nodes", "10000000"]),
    ("node-nodes-huge", ["node", "--id", "0", "--nodes", "5000", "--run", "bad"], ["--nodes", "1000"]),
    ("sim-seed-negative", ["sim", "--seed", "-1"], ["--seed"]),
    ("viewer-port-range", ["viewer", "--serve", "--web-port", "70000"], ["--web-port", "65535"]),
    ("truth-wait-timeout-negative", ["truth", "--wait-timeout", "-1", "--run", "bad"], ["--wait-timeout", "-1"]),
    ("truth-start-delay-nan", ["truth", "--start-delay", "nan", "--run", "bad"], ["--start-delay", "nan"]),
    ("run-timeout-negative", ["run", "--timeout", "-5", "--out", "{d}/out-timeout"], ["--timeout", "-5"]),
    ("run-missing-frac", ["run", "--max-missing-frac", "1.5", "--out", "{d}/out-frac"], ["--max-missing-frac", "1.5"]),
    ("node-truth-timeout-below-reconnect", ["node", "--id", "0", "--reconnect-s", "5", "--truth-timeout", "3", "--run", "bad"],
     ["--truth-timeout", "--reconnect-s"]),
    ("soak-router-without-router", ["soak", "--duration", "60", "--cut-every", "0", "--router-every", "30", "--out", "{d}/soak"],
     ["--router-every", "--router"]),
    ("soak-drain-without-stack", ["soak", "--duration", "60", "--cut-every", "0", "--drain-every", "30", "--out", "{d}/soak-drain"],
     ["--drain-every", "--engine stack"]),
    ("soak-stall-negative", ["soak", "--duration", "60", "--cut-every", "0", "--truth-stall-every", "-3", "--out", "{d}/soak-stall"],
     ["--truth-stall-every"]),
]


def run_case(inputs: Path, args: list[str]) -> tuple[list[str], subprocess.CompletedProcess]:
    """One case's command line (``{d}``: the inputs folder, ``{port}``: a port another socket holds meanwhile)
    and what ``python -m zentrack`` did with it."""
    with taken_port() as squatter:
        port = squatter.getsockname()[1]
        argv = [a.format(d=inputs, port=port) for a in args]
        # (a hang guard: four cases share the cores, and the viewer's imports alone take ~3 s of CPU)
        proc = subprocess.run([sys.executable, "-m", "zentrack", *argv], capture_output=True, text=True, timeout=120,
                              cwd=inputs, stdin=subprocess.DEVNULL)
    return argv, proc


@pytest.fixture(scope="module")
def outcomes(inputs, request) -> dict[str, Future]:
    """Every selected case's subprocess, four at a time (most of a case is the interpreter's start-up), run to
    its end: per case id, the finished future of :func:`run_case` (its ``result()`` raises what the case raised,
    in that case's test). No two cases name the same output, so they cannot disturb one another."""
    selected = {item.callspec.params["case"] for item in request.session.items
                if item.path == request.path and hasattr(item, "callspec")}
    with ThreadPoolExecutor(max_workers=4) as pool:
        return {case: pool.submit(run_case, inputs, args) for case, args, _ in CASES if case in selected}


@pytest.mark.parametrize("case, args, expected", CASES, ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_and_exit_status_2(inputs, outcomes, case, args, expected):
    argv, proc = outcomes[case].result()
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in proc.stderr, proc.stderr
    assert proc.returncode == 2, f"exit status {proc.returncode}\n{proc.stderr}"
    assert len(lines) == 1, f"{len(lines)} lines on stderr:\n{proc.stderr}"
    line = lines[0]
    assert line.startswith(f"zentrack {argv[0]}: error: "), line
    for text in expected:
        assert text.format(d=inputs) in line, f"{text!r} not in {line!r}"
    assert proc.stdout == "", proc.stdout
