#!/usr/bin/env bash
# zentrack shell orchestrator: a cluster of separate processes on this host, managed from a run folder.
set -euo pipefail

usage() {
    cat <<'EOF'
usage: deploy/cluster.sh [--dir DIR] COMMAND [ARGS]

Commands
  up [options]      start truth, N trackers (and optionally a router and a viewer); returns when every
                    tracker's liveliness token is visible. A scenario with sensors of their own
                    ([sensor_timing]) also gets one sensor process per sensor (sensor-<S>)
      --nodes N         trackers (default 4)
      --scenario S      a catalogue scenario (`zentrack scenarios` lists them) or a TOML path (default exp2)
      --timing T        realtime | lockstep (default realtime; --mode, its old name, still works for one release)
      --steps K         steps truth publishes (default 36000 = 1 h at 10 Hz)
      --router          start a Zenoh router; every process connects to it as a client
      --hosts H         the multi-host topology on this machine (implies --router): H routers linked to each
                        other, the trackers split into H consecutive blocks, each block the clients of its
                        own host's router; truth and viewer on host 0's router
      --viewer          start the Rerun viewer, recording to DIR/recording.rrd
      --zenoh-config F  a Zenoh JSON5 file for every process, merged over zentrack's safe defaults
                        (loopback listen, no multicast scouting); the cluster's endpoints override its
      --secure [DIR]    secure mode (implies --router): mutual TLS with the certificates in DIR
                        (`zentrack certs --out DIR --nodes N [--sensors N]`), or without DIR made in --dir's certs/,
                        the router enforcing access control
  down              stop every process of the cluster (SIGTERM, then SIGKILL after 5 s); leaves none behind
  status            live processes from Zenoh liveliness (not PIDs), then the PID table
  logs [NAME]       last lines of a process's log (NAME: truth, router, viewer, sensor-<S> or a node id); all
                    without NAME
  kill NODE         SIGKILL tracker NODE (a crash); NODE may be sensor-<S>, a sensor of its own
  restart NODE      kill tracker NODE if it runs, start it again, return when its token is back
  freeze NODE       SIGSTOP tracker NODE (a hang: others notice after its 1 s lease)
  thaw NODE         SIGCONT tracker NODE
  kill-router H     SIGKILL host H's router (0 with one router)
  restart-router H  kill host H's router if it runs and start it again (its trackers reconnect by themselves)

Options
  --dir DIR         run folder with pids/, logs/, cluster.env (default ./out/cluster)
  -h, --help        this text

Environment
  ZENTRACK          the zentrack executable (default: zentrack on PATH, else .venv/bin/zentrack of this repo)
EOF
}

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
dir="out/cluster"
while [ $# -gt 0 ]; do
    case "$1" in
        --dir) dir="$2"; shift 2 ;;
        -h|--help) usage; exit 0 ;;
        *) break ;;
    esac
done
[ $# -ge 1 ] || { usage >&2; exit 2; }
cmd="$1"; shift

if [ -z "${ZENTRACK:-}" ]; then
    if command -v zentrack >/dev/null 2>&1; then ZENTRACK="$(command -v zentrack)";
    else ZENTRACK="$here/../.venv/bin/zentrack"; fi
fi
[ -x "$ZENTRACK" ] || { echo "cluster.sh: no zentrack executable ($ZENTRACK); run deploy/quickstart.sh or set ZENTRACK" >&2; exit 2; }

die() { echo "cluster.sh: $*" >&2; exit 2; }
# "; did you mean 'kill'?" for a mistyped word ($1) among the known ones (the rest): zentrack's own suggester
suggest() {
    local py
    py="$(sed -n '1s/^#!//p' "$ZENTRACK")"
    [ -x "$py" ] && "$py" -c 'import sys; from zentrack.common.suggest import did_you_mean
print(did_you_mean(sys.argv[1], sys.argv[2:]))' "$@" 2>/dev/null
}
pidfile() { echo "$dir/pids/$1.pid"; }
is_running() { local f; f="$(pidfile "$1")"; [ -f "$f" ] && kill -0 "$(cat "$f")" 2>/dev/null; }
is_frozen() {  # is_frozen NAME: its process is stopped (state T in /proc/<pid>/stat, after the "(comm)" field)
    local stat; stat="$(cat "/proc/$(cat "$(pidfile "$1")")/stat" 2>/dev/null)" || return 1
    stat="${stat##*) }"; [ "${stat%% *}" = T ]
}
load_env() {
    [ -f "$dir/cluster.env" ] || die "no cluster in $dir (run: cluster.sh --dir $dir up)"
    . "$dir/cluster.env"
    TIMING="${TIMING:-${MODE:-realtime}}"  # MODE: a cluster.env written before the timing had its name
}

zenoh_file() { [ -n "${ZENOH_CONFIG:-}" ] && echo "--zenoh-config $ZENOH_CONFIG" || true; }

host_port() {  # host_port H: the port of host H's router (PORT is host 0's)
    local ports; IFS=, read -r -a ports <<< "${PORTS:-$PORT}"; echo "${ports[$1]}"
}

host_of() {  # host_of NODE: the host of a tracker, the trackers split into HOSTS consecutive blocks
    local h=0; while [ "$1" -ge $(( (h + 1) * NODES / ${HOSTS:-1} )) ]; do h=$((h + 1)); done; echo "$h"
}

router_name() { [ "${HOSTS:-1}" -gt 1 ] && echo "router-$1" || echo router; }

zenoh_args() {  # connection flags for every process but the hub; zenoh_args H: a client of host H's router
    local port; port="$(host_port "${1:-0}")"
    if [ -n "${SECURE:-}" ]; then echo "--zenoh-mode client --connect tls/127.0.0.1:$port --secure $SECURE $(zenoh_file)";
    elif [ "$ROUTER" = 1 ]; then echo "--zenoh-mode client --connect tcp/127.0.0.1:$port $(zenoh_file)";
    else echo "--connect tcp/127.0.0.1:$port $(zenoh_file)"; fi
}

router_cmd() {  # the command line of host $1's router: it listens on its port and links to every router before it
    local h="$1" k links=()
    for ((k = 0; k < h; k++)); do links+=(--connect "tcp/127.0.0.1:$(host_port "$k")"); done
    echo router --listen "tcp/127.0.0.1:$(host_port "$h")" "${links[@]}" $(zenoh_file)
}

start() {  # start NAME ARGS...: detached, in its own session, log and pid file in the run folder
    local name="$1"; shift
    setsid "$ZENTRACK" "$@" >>"$dir/logs/$name.log" 2>&1 < /dev/null &
    echo $! > "$(pidfile "$name")"
    printf '%s\n' "$*" > "$dir/cmd/$name"
}

live_nodes() {  # space-separated live tracker ids from liveliness
    "$ZENTRACK" status --run "$RUN" $(zenoh_args) --json --timeout 2 2>/dev/null \
        | python3 -c 'import json,sys; print(" ".join(map(str, json.load(sys.stdin)["nodes"])))'
}

wait_for() {  # wait_for CONDITION-COMMAND TIMEOUT MESSAGE
    local end=$(( $(date +%s) + $2 ))
    while ! eval "$1"; do
        [ "$(date +%s)" -lt "$end" ] || die "$3"
        sleep 0.2
    done
}

sensor_count() {  # sensor_count SCENARIO NODES: the sensors of their own the scenario has ([sensor_timing]), or 0,
    # then the flags that tell a secure router about them (--sensors S, and --takes when not tracker i: sensor i)
    local py
    py="$(sed -n '1s/^#!//p' "$ZENTRACK")"
    "$py" -c 'import sys; from zentrack.config.scenario_config import load_scenario_config, resize
from zentrack.transport.router import access_flags
try:
    cfg = resize(load_scenario_config(sys.argv[1], multitarget=True), int(sys.argv[2]))
except ValueError as exc:
    sys.exit(" ".join(str(exc).split()))
t = cfg.sensor_timing
print(0 if t is None else " ".join([str(t.sensors), *access_flags("r", int(sys.argv[2]), t.sensors, t.takes)[4:]]))' "$1" "$2"
}

sensor_cmd() {  # the command line of sensor $1 (a sensor of its own)
    echo sensor --id "$1" --scenario "$SCENARIO" --nodes "$NODES" --steps "$STEPS" --timing "$TIMING" \
        --run "$RUN" --lease-ms 1000 $(zenoh_args)
}

node_cmd() {  # the command line of tracker $1
    echo node --id "$1" --scenario "$SCENARIO" --nodes "$NODES" --steps "$STEPS" --timing "$TIMING" \
        --run "$RUN" --lease-ms 1000 --out "$dir" $(zenoh_args "$(host_of "$1")")
}

case "$cmd" in
up)
    nodes=4; scenario=exp2; timing=realtime; steps=36000; router=0; viewer=0; zenoh_config=""; secure=""; hosts=1
    while [ $# -gt 0 ]; do
        case "$1" in
            --nodes) nodes="$2"; shift 2 ;;
            --scenario) scenario="$2"; shift 2 ;;
            --timing) timing="$2"; shift 2 ;;
            --mode) echo "cluster.sh: warning: up --mode $2 is deprecated and goes in the next release; use --timing $2" >&2
                    timing="$2"; shift 2 ;;
            --steps) steps="$2"; shift 2 ;;
            --router) router=1; shift ;;
            --hosts) hosts="$2"; router=1; shift 2 ;;
            --viewer) viewer=1; shift ;;
            --zenoh-config) zenoh_config="$2"; shift 2 ;;
            --secure) router=1
                      if [ $# -ge 2 ] && [[ "$2" != --* ]]; then secure="$2"; shift 2; else secure=MAKE; shift; fi ;;
            *) die "up: unknown option $1$(suggest "$1" --nodes --scenario --timing --steps --router --hosts --viewer --zenoh-config --secure) (see --help)" ;;
        esac
    done
    [[ "$nodes" =~ ^[1-9][0-9]*$ ]] || die "up: --nodes must be a positive whole number, got $nodes"
    [[ "$steps" =~ ^[1-9][0-9]*$ ]] || die "up: --steps must be a positive whole number, got $steps"
    [[ "$hosts" =~ ^[1-9][0-9]*$ ]] && [ "$hosts" -le "$nodes" ] || die "up: --hosts must be a whole number from 1 to --nodes ($nodes), got $hosts"
    [ "$hosts" = 1 ] || [ -z "$secure" ] || die "up: --hosts with --secure: secure mode has one router's certificate and access control; a multi-host secure topology is not supported"
    case "$timing" in realtime|lockstep) ;; *) die "up: --timing must be realtime or lockstep, got $timing" ;; esac
    if [ -n "$zenoh_config" ]; then
        [ -f "$zenoh_config" ] || die "up: --zenoh-config: no such file: $zenoh_config"
        zenoh_config="$(cd "$(dirname "$zenoh_config")" && pwd)/$(basename "$zenoh_config")"
        [[ "$zenoh_config" != *[[:space:]]* ]] || die "up: --zenoh-config: the path must not contain spaces"
    fi
    found="$(sensor_count "$scenario" "$nodes" 2>&1)" || die "up: ${found##*$'\n'}"
    read -r sensors sensor_access <<< "$found"
    certs_flags="--nodes $nodes$([ "$sensors" = 0 ] || echo " --sensors $sensors")"
    if [ -n "$secure" ] && [ "$secure" != MAKE ]; then
        [ -f "$secure/ca.pem" ] && [ -f "$secure/router.pem" ] || die "up: --secure: no certificates in $secure (zentrack certs --out $secure $certs_flags)"
        [ -f "$secure/node-$((nodes - 1)).pem" ] || die "up: --secure: no certificate for node-$((nodes - 1)) in $secure (zentrack certs --out $secure $certs_flags)"
        [ "$sensors" = 0 ] || [ -f "$secure/sensor-$((sensors - 1)).pem" ] || die "up: --secure: no certificate for sensor-$((sensors - 1)) in $secure (zentrack certs --out $secure $certs_flags)"
        secure="$(cd "$secure" && pwd)"
        [[ "$secure" != *[[:space:]]* ]] || die "up: --secure: the path must not contain spaces"
    fi
    if [ -d "$dir/pids" ]; then
        for f in "$dir"/pids/*.pid; do
            [ -e "$f" ] && kill -0 "$(cat "$f")" 2>/dev/null && die "a cluster is already up in $dir (cluster.sh --dir $dir down)"
        done
    fi
    mkdir -p "$dir/pids" "$dir/logs" "$dir/cmd"
    rm -f "$dir"/pids/*.pid
    if [ "$secure" = MAKE ]; then  # --secure without a folder: this cluster's own certificates
        "$ZENTRACK" certs --out "$dir/certs" $certs_flags >/dev/null || die "up: --secure: the certificates could not be made in $dir/certs"
        secure="$(cd "$dir/certs" && pwd)"
        [[ "$secure" != *[[:space:]]* ]] || die "up: --secure: the path must not contain spaces"
    fi
    ports="$(python3 -c '
import socket, sys
socks = [socket.socket() for _ in range(int(sys.argv[1]))]
for s in socks: s.bind(("127.0.0.1", 0))
print(",".join(str(s.getsockname()[1]) for s in socks))' "$hosts")"
    port="${ports%%,*}"
    run="c$(date +%s)x$$"
    cat > "$dir/cluster.env" <<ENV
RUN=$run
PORT=$port
PORTS=$ports
HOSTS=$hosts
NODES=$nodes
SCENARIO=$scenario
TIMING=$timing
STEPS=$steps
SENSORS=$sensors
ROUTER=$router
VIEWER=$viewer
ZENOH_CONFIG=$zenoh_config
SECURE=$secure
ENV
    load_env
    waits=()
    if [ -n "$secure" ]; then
        start router router --listen "tls/127.0.0.1:$port" --secure "$secure" --run "$run" --nodes "$nodes" \
            $sensor_access $(zenoh_file)
        hub=($(zenoh_args))
    elif [ "$router" = 1 ]; then
        for ((h = 0; h < hosts; h++)); do start "$(router_name "$h")" $(router_cmd "$h"); done
        hub=(--zenoh-mode client --connect "tcp/127.0.0.1:$port" $(zenoh_file))
    else
        hub=(--listen "tcp/127.0.0.1:$port" $(zenoh_file))  # truth is the hub the others connect to
    fi
    [ "$viewer" = 1 ] && waits=(--wait-for viewer)
    for ((s = 0; s < sensors; s++)); do waits+=(--wait-for "sensor-$s"); done  # the truth starts once they are up
    start truth truth --scenario "$scenario" --nodes "$nodes" --steps "$steps" --timing "$timing" --run "$run" \
        --wait-timeout 120 "${hub[@]}" "${waits[@]}"
    sleep 1
    is_running truth || { tail -n 5 "$dir/logs/truth.log" >&2; rm -f "$dir"/pids/*.pid; die "up: truth did not start (log above)"; }
    for ((s = 0; s < sensors; s++)); do start "sensor-$s" $(sensor_cmd "$s"); done
    for ((i = 0; i < nodes; i++)); do start "node-$i" $(node_cmd "$i"); done
    if [ "$viewer" = 1 ]; then
        start viewer viewer --scenario "$scenario" --nodes "$nodes" --steps "$steps" --run "$run" \
            --save "$dir/recording.rrd" $(zenoh_args)
    fi
    wait_for '[ "$(live_nodes | wc -w)" -ge "$nodes" ]' 60 "up: not every tracker came up within 60 s (see $dir/logs)"
    echo "cluster $run up: $nodes trackers$([ "$hosts" -gt 1 ] && echo " on $hosts hosts (routers on ports $ports)"), $scenario, $timing, folder $dir"
    ;;
down)
    [ -d "$dir/pids" ] || { echo "nothing to stop in $dir"; exit 0; }
    for f in "$dir"/pids/*.pid; do
        [ -e "$f" ] || continue
        pid="$(cat "$f")"
        kill -CONT -- "-$pid" 2>/dev/null || true   # a frozen process cannot handle SIGTERM
        kill -TERM -- "-$pid" 2>/dev/null || true
    done
    end=$(( $(date +%s) + 5 ))
    for f in "$dir"/pids/*.pid; do
        [ -e "$f" ] || continue
        pid="$(cat "$f")"
        while kill -0 "$pid" 2>/dev/null && [ "$(date +%s)" -lt "$end" ]; do sleep 0.1; done
        kill -KILL -- "-$pid" 2>/dev/null || true
        rm -f "$f"
    done
    echo "cluster in $dir is down"
    ;;
status)
    load_env
    echo "run $RUN ($NODES trackers, $SCENARIO, $TIMING, port${PORTS:+s} ${PORTS:-$PORT})"
    "$ZENTRACK" status --run "$RUN" $(zenoh_args) --timeout 2 || echo "(no answer from the cluster)"
    for f in "$dir"/pids/*.pid; do
        [ -e "$f" ] || continue
        name="$(basename "$f" .pid)"; pid="$(cat "$f")"
        state="$(ps -o stat= -p "$pid" 2>/dev/null || true)"
        case "$state" in ""|Z*) s=dead ;; T*) s=frozen ;; *) s=running ;; esac
        printf '  %-10s pid %-8s %s\n' "$name" "$pid" "$s"
    done
    ;;
logs)
    if [ $# -ge 1 ]; then
        name="$1"; [[ "$name" =~ ^[0-9]+$ ]] && name="node-$name" || true
        [ -f "$dir/logs/$name.log" ] || die "logs: no log for $1 in $dir/logs"
        tail -n 50 "$dir/logs/$name.log"
    else
        for f in "$dir"/logs/*.log; do echo "== $(basename "$f")"; tail -n 5 "$f"; done
    fi
    ;;
kill-router|restart-router)
    load_env
    [ "$ROUTER" = 1 ] || die "$cmd: this cluster has no router (up --router or --hosts)"
    [ $# -eq 1 ] && [[ "$1" =~ ^[0-9]+$ ]] && [ "$1" -lt "${HOSTS:-1}" ] || die "$cmd: give a host from 0 to $((${HOSTS:-1} - 1))"
    [ -z "${SECURE:-}" ] || die "$cmd: not in secure mode (its router takes the access control's flags)"
    name="$(router_name "$1")"; f="$(pidfile "$name")"
    if [ "$cmd" = kill-router ]; then
        is_running "$name" || die "kill-router: $name is not running"; kill -KILL "$(cat "$f")"; echo "$name killed"
    else
        if is_running "$name"; then kill -KILL "$(cat "$f")"; sleep 0.2; fi
        start "$name" $(router_cmd "$1")
        sleep 0.5
        is_running "$name" || die "restart-router: $name exited at once (see $dir/logs/$name.log)"
        echo "$name restarted"
    fi
    ;;
kill|restart|freeze|thaw)
    load_env
    if [ $# -eq 1 ] && [[ "$1" =~ ^sensor-([0-9]+)$ ]]; then  # a sensor of its own
        [ "${BASH_REMATCH[1]}" -lt "${SENSORS:-0}" ] || die "$cmd: this cluster has ${SENSORS:-0} sensor process(es)"
        name="$1"; f="$(pidfile "$name")"
        case "$cmd" in
            kill) is_running "$name" || die "kill: $name is not running"; kill -KILL "$(cat "$f")"; echo "$name killed" ;;
            freeze) is_running "$name" || die "freeze: $name is not running"; kill -STOP "$(cat "$f")"; echo "$name frozen" ;;
            thaw) is_running "$name" || die "thaw: $name is not running"; kill -CONT "$(cat "$f")"; echo "$name thawed" ;;
            restart)
                if is_running "$name"; then kill -KILL "$(cat "$f")"; sleep 0.2; fi
                start "$name" $(sensor_cmd "${BASH_REMATCH[1]}")
                sleep 0.5
                is_running "$name" || die "restart: $name exited at once (see $dir/logs/$name.log)"
                echo "$name restarted"
                ;;
        esac
        exit 0
    fi
    [ $# -eq 1 ] && [[ "$1" =~ ^[0-9]+$ ]] && [ "$1" -lt "$NODES" ] || die "$cmd: give a tracker id from 0 to $((NODES - 1))"
    name="node-$1"; f="$(pidfile "$name")"
    case "$cmd" in
        kill) is_running "$name" || die "kill: $name is not running"; kill -KILL "$(cat "$f")"; echo "$name killed" ;;
        freeze) is_running "$name" || die "freeze: $name is not running"
                is_frozen "$name" && { echo "$name is already frozen (thaw $1 resumes it)"; exit 0; }
                kill -STOP "$(cat "$f")"; echo "$name frozen" ;;
        thaw) is_running "$name" || die "thaw: $name is not running"
              is_frozen "$name" || { echo "$name is running, not frozen: nothing to thaw"; exit 0; }
              kill -CONT "$(cat "$f")"; echo "$name thawed" ;;
        restart)
            if is_running "$name"; then kill -KILL "$(cat "$f")"; sleep 0.2; fi
            start "$name" $(node_cmd "$1")
            wait_for "live_nodes | tr ' ' '\n' | grep -qx '$1'" 30 "restart: $name did not come back within 30 s"
            echo "$name restarted"
            ;;
    esac
    ;;
*) echo "cluster.sh: unknown command '$cmd'$(suggest "$cmd" up down status logs kill restart freeze thaw kill-router restart-router)" >&2
   echo "commands: up, down, status, logs, kill, restart, freeze, thaw, kill-router, restart-router (deploy/cluster.sh --help)" >&2
   exit 2 ;;
esac
