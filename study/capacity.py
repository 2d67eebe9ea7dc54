"""A capacity model of a realtime cluster, fitted from ``zentrack bench scale`` JSON: what N trackers of node
degree d at f steps per second cost in CPU and bytes, on one host or split over H hosts with a router each.

Form (all per step; ``f`` steps per second turns them into rates):

- tracker CPU ms = a + b·m_in + c·m_out, m_in = messages a tracker accepts (measured: its own counters),
  m_out = messages it publishes (its prior and its estimate: always 2, so c cannot be told from a and is
  folded into it; :func:`fit` says so);
- router CPU ms = r0 + r1·m_routed, m_routed = messages the router receives plus messages it writes, one per
  link (:func:`router_messages`); truth CPU ms = t0 + t1·N (it publishes N measurements), recorder CPU ms =
  q0 + q1·N (it receives N estimates);
- bytes on each link direction = Σ_kind (bytes per message of the kind)·(messages of the kind) + a constant
  per link role (keep-alives, declarations, counters): :data:`LINK_ROLES`.

Coefficients are ordinary least squares (``numpy.linalg.lstsq``) over every run of the JSON files; each fit
keeps its RMS and largest residual. Counting messages, per step:

- the truth publishes ``meas/i`` once per tracker i; tracker i publishes ``prior/i`` (subscribed by its d
  neighbours) and ``est/i`` (subscribed by the recorder; nobody subscribes ``truth`` in realtime without a
  viewer, and no rule of these runs relays scans);
- a router writes a message once per link with a subscriber behind it: to each local subscriber, and once to
  each other router with at least one subscriber behind it (Zenoh routes per face, not per subscriber);
- with H hosts the trackers split into consecutive blocks (``zentrack compose --hosts``), truth and recorder
  on host 0, routers in a full mesh (each pair linked directly): tracker i's prior crosses to host h once when
  h holds at least one of its neighbours (:func:`prior_copies`), host h's measurements come from router 0 and
  its estimates go to router 0.

Assumptions (not measured by the fit): per-step costs do not depend on the rate (the JSON is at one rate);
the router-to-router links carry the same bytes per message as the client links and no constant of their own
(their keep-alives are not in single-host runs); a router's CPU depends only on the messages it handles, not
on whether a link goes to a client or another router; a host's own router serves as if its trackers were the
whole mesh when capacities are counted (:meth:`CapacityModel.trackers_per_host`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from zentrack.config.hosts import host_of

#: messages a tracker publishes per step: its prior (round 1) and its estimate
MESSAGES_OUT = 2
#: the message kinds whose bytes the fit finds, and the link roles that each get a constant
KINDS = ("meas", "prior", "est")
LINK_ROLES = ("tracker_up", "tracker_down", "truth_up", "recorder_down")


@dataclass(frozen=True)
class Fit:
    """One least-squares fit: a coefficient per name (None: not identified by the data, folded into earlier
    columns), the residuals' RMS and largest magnitude, how many observations it had, and the RMS per group of
    observations when the fit was given groups."""

    names: tuple[str, ...]
    coef: dict[str, float | None]
    rms: float
    max_abs: float
    observations: int
    group_rms: dict[str, float] | None = None

    def predict(self, x: dict[str, float]) -> float:
        return sum(c * x[k] for k, c in self.coef.items() if c is not None)

    def to_json(self) -> dict:
        return {"coef": self.coef, "residual_rms": self.rms, "residual_max_abs": self.max_abs,
                "observations": self.observations, **({"residual_rms_by_group": self.group_rms} if self.group_rms else {})}


def fit(names: list[str], rows: list[list[float]], y: list[float], groups: list[str] | None = None) -> Fit:
    """Least squares of ``y`` on the columns ``names`` of ``rows``; a column the earlier ones already span
    (rank does not grow) is left out and gets None. ``groups``: a label per row, for the RMS per label."""
    x, target = np.asarray(rows, dtype=float), np.asarray(y, dtype=float)
    if x.ndim != 2 or x.shape[0] != target.size or x.shape[1] != len(names):
        raise ValueError(f"fit: {x.shape} rows for {len(names)} names and {target.size} values")
    if not np.all(np.isfinite(x)) or not np.all(np.isfinite(target)):
        raise ValueError("fit: the observations hold a non-finite value")
    keep: list[int] = []
    for j in range(len(names)):
        scale = np.linalg.norm(x[:, keep + [j]], axis=0)
        cols = x[:, keep + [j]] / np.where(scale > 0, scale, 1.0)
        if scale[-1] > 0 and np.linalg.matrix_rank(cols, tol=1e-9) == len(keep) + 1:
            keep.append(j)
    if len(keep) > target.size:
        raise ValueError(f"fit: {target.size} observations for {len(keep)} coefficients")
    beta = np.linalg.lstsq(x[:, keep], target, rcond=None)[0]
    resid = target - x[:, keep] @ beta
    coef: dict[str, float | None] = {n: None for n in names}
    for j, b in zip(keep, beta):
        coef[names[j]] = float(b)
    by_group = None if groups is None else {
        g: float(np.sqrt(np.mean(resid[[k for k, h in enumerate(groups) if h == g]] ** 2))) for g in dict.fromkeys(groups)}
    return Fit(tuple(names), coef, float(np.sqrt(np.mean(resid**2))), float(np.max(np.abs(resid))), target.size,
               by_group)


def block_sizes(n: int, hosts: int) -> list[int]:
    """Trackers per host when ``n`` split into ``hosts`` consecutive blocks (``zentrack compose --hosts``)."""
    sizes = [0] * hosts
    for i in range(n):
        sizes[host_of(i, n, hosts)] += 1
    return sizes


def neighbour_hosts(i: int, n: int, degree: int, hosts: int) -> set[int]:
    """Hosts of tracker i's neighbours on the ring lattice (``zentrack.bench.scale_graph``), i's own included:
    the arc i − d//2 .. i + d//2 runs through consecutive blocks, so its hosts are its first node's block and
    the next one per block start inside the arc; odd d adds the host of the node opposite, i + n/2."""
    half, start = degree // 2, (i - degree // 2) % n
    first = host_of(start, n, hosts)
    crossed = sum(1 for h in range(hosts) if 1 <= (h * n // hosts - start) % n <= 2 * half)
    out = {(first + k) % hosts for k in range(min(crossed, hosts - 1) + 1)}
    if degree % 2:
        out.add(host_of((i + n // 2) % n, n, hosts))
    return out


def prior_copies(n: int, degree: int, hosts: int) -> np.ndarray:
    """``(hosts, hosts)``: priors per step router a writes to router b (a ≠ b): the trackers of host a with at
    least one neighbour on host b."""
    out = np.zeros((hosts, hosts), dtype=int)
    for i in range(n):
        a = host_of(i, n, hosts)
        for b in neighbour_hosts(i, n, degree, hosts) - {a}:
            out[a, b] += 1
    return out


def router_messages(n: int, degree: int, hosts: int) -> list[dict[str, int]]:
    """Per host's router: messages per step it receives and writes (module docstring), and their sum."""
    sizes, copies = block_sizes(n, hosts), prior_copies(n, degree, hosts)
    out = []
    for h, local in enumerate(sizes):
        received = 2 * local + (n if h == 0 else local) + int(copies[:, h].sum()) + (n - local if h == 0 else 0)
        sent = local + local * degree + int(copies[h, :].sum()) + (n + n - local if h == 0 else local)
        out.append({"received": received, "sent": sent, "routed": received + sent})
    return out


def router_link_messages(n: int, degree: int, hosts: int) -> dict[tuple[int, int], dict[str, int]]:
    """Per ordered router pair (a, b): messages per step of each kind router a writes to router b."""
    sizes, copies = block_sizes(n, hosts), prior_copies(n, degree, hosts)
    return {(a, b): {"meas": sizes[b] if a == 0 else 0, "prior": int(copies[a, b]), "est": sizes[a] if b == 0 else 0}
            for a in range(hosts) for b in range(hosts) if a != b}


def routed_per_tracker(degree: int) -> int:
    """Messages a one-host mesh's router handles per step per tracker: 3 received (measurement, prior,
    estimate), 2 + d written (measurement, d prior copies, estimate)."""
    return router_messages(1, degree, 1)[0]["routed"]


def link_counts(role: str, n: int, degree: int) -> dict[str, int]:
    """Messages per step of each kind on one link direction of a role (module docstring)."""
    return {"tracker_up": {"prior": 1, "est": 1}, "tracker_down": {"meas": 1, "prior": degree},
            "truth_up": {"meas": n}, "recorder_down": {"est": n}}[role]


@dataclass(frozen=True)
class CapacityModel:
    """The fitted costs (:func:`fit_model`) and what they predict for N, degree, hosts and rate."""

    tracker: Fit
    router: Fit
    truth: Fit
    recorder: Fit
    bytes: Fit

    def tracker_ms(self, degree: int) -> float:
        return self.tracker.predict({"const": 1.0, "messages_in": 1.0 + degree, "messages_out": MESSAGES_OUT})

    def router_ms(self, routed: float) -> float:
        return self.router.predict({"const": 1.0, "messages_routed": routed})

    def link_bytes(self, role: str, n: int, degree: int) -> float:
        """Bytes per step on one link direction of ``role``."""
        counts = link_counts(role, n, degree)
        return self.bytes.predict({**{f"bytes_{k}": counts.get(k, 0) for k in KINDS},
                                   **{f"const_{r}": float(r == role) for r in LINK_ROLES}})

    def router_link_bytes(self, messages: dict[str, int]) -> float:
        return self.bytes.predict({**{f"bytes_{k}": messages[k] for k in KINDS},
                                   **{f"const_{r}": 0.0 for r in LINK_ROLES}})

    def trackers_per_host(self, degree: int, rate: float, cores: float, budget: float) -> dict[str, float]:
        """Trackers one host holds at ``budget`` of ``cores``: trackers alone (cores × budget / tracker CPU), and
        beside the host's own router serving them as a one-host mesh (n·tracker + r0 + r1·n·(5 + d) within it)."""
        per_step_ms = cores * budget * 1e3 / rate
        per_tracker = self.tracker_ms(degree)
        r0, r1 = self.router.coef["const"] or 0.0, self.router.coef["messages_routed"] or 0.0
        return {"trackers_only": per_step_ms / per_tracker,
                "with_router": max(0.0, (per_step_ms - r0) / (per_tracker + r1 * routed_per_tracker(degree)))}

    def trackers_per_router(self, degree: int, rate: float, router_cores: float, budget: float) -> float:
        """Trackers one router serves within ``budget`` of ``router_cores`` (r0 + r1·n·(5 + d): a one-host mesh's
        messages; cross-host copies add to it)."""
        r0, r1 = self.router.coef["const"] or 0.0, self.router.coef["messages_routed"] or 0.0
        room = router_cores * budget * 1e3 / rate - r0
        return float("inf") if r1 <= 0 else max(0.0, room / (r1 * routed_per_tracker(degree)))

    def predict(self, n: int, degree: int, hosts: int, rate: float, cores: float = 2.0, budget: float = 0.7,
                router_cores: float = 1.0) -> dict:
        """Every prediction for one deployment, as JSON-ready numbers (CPU per step, bytes per second)."""
        routers = router_messages(n, degree, hosts)
        links = {f"router-{a}->router-{b}": self.router_link_bytes(m) * rate
                 for (a, b), m in router_link_messages(n, degree, hosts).items()}
        per_router = self.trackers_per_router(degree, rate, router_cores, budget)
        return {
            "nodes": n, "degree": degree, "hosts": hosts, "rate_hz": rate, "cores": cores, "budget": budget,
            "router_cores": router_cores, "trackers_per_host": block_sizes(n, hosts),
            "cpu_ms_per_step": {"tracker": self.tracker_ms(degree),
                                "router": [self.router_ms(m["routed"]) for m in routers],
                                "truth": self.truth.predict({"const": 1.0, "nodes": n}),
                                "recorder": self.recorder.predict({"const": 1.0, "nodes": n})},
            "router_messages_per_step": routers,
            "bytes_per_s": {**{role: self.link_bytes(role, n, degree) * rate for role in LINK_ROLES}, **links},
            "capacity": {**self.trackers_per_host(degree, rate, cores, budget), "trackers_per_router": per_router,
                         "routers_per_mesh": math.ceil(n / per_router) if per_router > 0 else None},
        }

    def to_json(self) -> dict:
        return {k: getattr(self, k).to_json() for k in ("tracker", "router", "truth", "recorder", "bytes")}


def observations(doc: dict, source: str = "JSON") -> list[dict]:
    """Per run of one bench scale JSON with router links: N, degree, and the measured per-step figures."""
    if not isinstance(doc, dict) or doc.get("command") != "bench scale" or not isinstance(doc.get("results"), list):
        raise ValueError(f"{source}: not the JSON of `zentrack bench scale --json` (no command 'bench scale', results)")
    ts, out = float(doc.get("ts", 0.1)), []
    for r in doc["results"]:
        try:
            links, cpu = r["router_links"], r["cpu_ms_per_step"]
            if not links or not {"tracker", "router", "truth", "recorder"} <= cpu.keys():
                continue
            trackers = [v for k, v in links["links"].items() if k.startswith("node")]
            accepted = [v["messages_accepted_per_s"] * ts for v in trackers if "messages_accepted_per_s" in v]
            if not trackers or not accepted:
                continue

            out.append({
                "nodes": int(r["nodes"]), "degree": int(r["degree"]), "ts": ts,
                "cpu": {k: float(cpu[k]["mean_ms"]) for k in ("tracker", "router", "truth", "recorder")},
                "messages_in": float(np.mean(accepted)),
                "bytes": {"tracker_up": float(np.mean([v["bytes_to_router_per_s"] for v in trackers])) * ts,
                          "tracker_down": float(np.mean([v["bytes_from_router_per_s"] for v in trackers])) * ts,
                          "truth_up": float(links["links"]["truth"]["bytes_to_router_per_s"]) * ts,
                          "recorder_down": float(links["links"]["recorder"]["bytes_from_router_per_s"]) * ts}})
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{source}: a result lacks {exc} (not bench scale JSON of this version)") from None
    return out


def fit_model(obs: list[dict]) -> CapacityModel:
    """The model's coefficients from the runs of :func:`observations` (at least two sizes or degrees)."""
    if len({(o["nodes"], o["degree"]) for o in obs}) < 2:
        raise ValueError("the fit needs runs of at least two sizes or degrees through a router (bench scale "
                         "--router with --sizes and/or --degree); found "
                         f"{sorted({(o['nodes'], o['degree']) for o in obs})}")
    tracker = fit(["const", "messages_in", "messages_out"], [[1.0, o["messages_in"], MESSAGES_OUT] for o in obs],
                  [o["cpu"]["tracker"] for o in obs])
    router = fit(["const", "messages_routed"],
                 [[1.0, router_messages(o["nodes"], o["degree"], 1)[0]["routed"]] for o in obs],
                 [o["cpu"]["router"] for o in obs])
    truth = fit(["const", "nodes"], [[1.0, o["nodes"]] for o in obs], [o["cpu"]["truth"] for o in obs])
    recorder = fit(["const", "nodes"], [[1.0, o["nodes"]] for o in obs], [o["cpu"]["recorder"] for o in obs])
    names = [f"bytes_{k}" for k in KINDS] + [f"const_{r}" for r in LINK_ROLES]
    rows, y, roles = [], [], []
    for o in obs:
        for role in LINK_ROLES:
            roles.append(role)
            counts = link_counts(role, o["nodes"], o["degree"])
            rows.append([counts.get(k, 0) for k in KINDS] + [float(r == role) for r in LINK_ROLES])
            y.append(o["bytes"][role])
    return CapacityModel(tracker, router, truth, recorder, fit(names, rows, y, roles))
