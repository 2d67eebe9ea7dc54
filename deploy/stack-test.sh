# The Docker Swarm variants of deploy/docker-test.sh (`--variants stack,stack-secure`); sourced by it, never run
# alone: it uses that script's IMAGE, NODES, STACK_STEPS, OUT, PROJECT, log, fail, check_run and the image it built.
# Per variant, on a single-node swarm (`docker swarm init` on loopback, left again at the end), or with
# --swarm-workers N on a swarm of this host and N namespace workers (deploy/swarm-nodes.sh, torn down at the end):
#   - `zentrack compose --stack --router-hosts <the swarm's host>`: a router on the host linked to the hub
#     router, every tracker its client (checked from the trackers' and the routers' logs); secure: the
#     certificates of `zentrack certs` as swarm secrets and configs, the routers' naming both routers;
#     `docker stack deploy`, every task's container healthy (deploy-to-healthy seconds);
#   - a tracker task killed (`docker kill` of its container): swarm starts a replacement with the same slot
#     (kill-to-replaced seconds); the replacement warm-starts and publishes again, the steps without its
#     estimates read from the recorder's estimates.npz (kill-to-republished steps and seconds);
#   - with workers: the trackers spread over every node; the worker holding the most of them drained (`docker
#     node update --availability drain`): swarm starts its trackers, same slots, on the other nodes, nothing of
#     the stack runs on the drained engine, and each moved tracker publishes again within 20 steps of its
#     replacement's start (drain-to-republished steps, read from estimates.npz by the step times); the node
#     made active again, its router running again;
#   - a rolling update of the tracker service (`docker service update --force`) that completes, not rolled
#     back, while truth still runs;
#   - the run's checks (the recorder exits 0, every tracker a finite RMSE, median RMSE within 1.5x loopback);
#   - `docker stack rm`, and nothing of the stack left (containers, networks, volumes, secrets, configs).
# `stack_leave` (at the end, and from the EXIT trap) leaves the swarm it joined and removes docker_gwbridge
# when swarm init made it; with workers it takes them down (swarm_nodes_down) and checks that no namespace,
# bridge, engine or data of theirs is left.

SWARM_JOINED=0              # 1: swarm init on loopback; 2: deploy/swarm-nodes.sh workers
SWARM_WORKERS=${SWARM_WORKERS:-0}
SWARM_UP_S=0
GWBRIDGE_BEFORE=1
STACK_KILL_SLOT=2          # the task slot killed (tracker id 1)
STACK_KILL_AFTER_S=2          # seconds of run before the kill
# seconds between two looks for a replacement task: each look is a `docker ps` on every engine, and at 0.2 s
# they took CPU from the very replacements being timed (a drained secure tracker published 21 steps after its
# start, limit 20; 4-14 in the runs before); the start itself is read from the container (State.StartedAt)
POLL_S=1
STACK_UPDATE_PARALLELISM=3  # the rolling update in two batches of three trackers: it must end within the run
STACK_UPDATE_TIMEOUT_S=300
STACK_HEALTH_TIMEOUT_S=300  # every task healthy: generous, a loaded host starts ten Python processes slowly

# shellcheck source=deploy/swarm-nodes.sh
. "$(dirname "${BASH_SOURCE[0]}")/swarm-nodes.sh"

stack_join() {
    [ "$(docker info -f '{{.Swarm.LocalNodeState}}')" = active ] && [ "$SWARM_WORKERS" = 0 ] && return 0
    if [ "$SWARM_WORKERS" -gt 0 ]; then
        [ "$SWARM_JOINED" = 2 ] && return 0
        local t0
        t0=$(now)
        SWARM_JOINED=2
        SWN_LOGS=$OUT/swarm-workers  # the workers' engine logs, kept when they go
        SWN_OWNER=$$                 # a later run takes the workers down if this one is killed before it does
        swarm_nodes_up "$SWARM_WORKERS" "$IMAGE" || fail "swarm workers in namespaces (deploy/swarm-nodes.sh)"
        SWARM_UP_S=$(since "$t0" "$(now)")
        log "swarm of this host and $SWARM_WORKERS namespace workers, the image loaded on each, in $SWARM_UP_S s"
        return 0
    fi
    docker network inspect docker_gwbridge >/dev/null 2>&1 || GWBRIDGE_BEFORE=0
    docker swarm init --advertise-addr 127.0.0.1 --listen-addr 127.0.0.1:2377 >"$OUT/swarm-init.log" 2>&1 \
        || fail "docker swarm init: $(tail -3 "$OUT/swarm-init.log")"
    SWARM_JOINED=1
    log "single-node swarm on loopback"
}

stack_leave() {
    if [ "$SWARM_JOINED" = 2 ]; then
        # swarm-nodes.sh is written for `set -u` alone (a worker already gone is not an error): `|| true` runs it
        # without the caller's errexit
        swarm_nodes_down || true
        SWARM_JOINED=0
        return 0
    fi
    [ "$SWARM_JOINED" = 1 ] || return 0
    docker swarm leave --force >/dev/null 2>&1
    SWARM_JOINED=0
    if [ "$GWBRIDGE_BEFORE" = 0 ]; then docker network rm docker_gwbridge >/dev/null 2>&1; fi
}

# what the namespace workers left (empty when nothing): namespaces, bridge, engines, state and data
workers_left() {
    local left=""
    ip netns list 2>/dev/null | grep -q '^ztsw' && left="$left namespaces($(ip netns list | grep -o '^ztsw[0-9]*' | paste -sd,))"
    ip link show "$SWN_BRIDGE" >/dev/null 2>&1 && left="$left bridge $SWN_BRIDGE"
    pgrep -f "dockerd.*$SWN_DATA" >/dev/null && left="$left worker engines"
    [ -e "$SWN_STATE" ] && left="$left $SWN_STATE"
    [ -e "$SWN_DATA" ] && left="$left $SWN_DATA"
    echo "$left"
}

# the engines that run the stack's tasks: `local` (this host's) and each namespace worker's socket
stack_engines() {
    echo local
    if [ "$SWARM_WORKERS" -gt 0 ]; then
        for i in $(swn_workers); do swn_sock "$i"; done
    fi
}

# docker on engine $1 (`local`: this host's)
dk() {
    local engine=$1
    shift
    if [ "$engine" = local ]; then docker "$@"; else docker -H "$engine" "$@"; fi
}

# the stack's containers (running or not) on this host's engine, or one service's there (router, truth,
# viewer and recorder are placed on the manager, this host)
stack_containers() {
    docker ps -a -q --filter "label=com.docker.stack.namespace=$V_STACK" ${1:+--filter "label=com.docker.swarm.service.name=${V_STACK}_$1"}
}

# how many of the stack's containers are healthy, on every engine
stack_healthy() {
    local engine ids n=0
    for engine in $(stack_engines); do
        ids=$(dk "$engine" ps -a -q --filter "label=com.docker.stack.namespace=$V_STACK")
        [ -n "$ids" ] || continue
        n=$((n + $(dk "$engine" inspect -f '{{if .State.Health}}{{.State.Health.Status}}{{end}}' $ids 2>/dev/null | grep -c '^healthy$' || true)))
    done
    echo "$n"
}

# "<engine> <container id>" of the running tracker task in slot $1, on whichever engine runs it
slot_container() {
    local engine
    for engine in $(stack_engines); do
        dk "$engine" ps --filter "label=com.docker.swarm.service.name=${V_STACK}_node" --format '{{.ID}} {{.Names}}' \
            | awk -v p="${V_STACK}_node.$1." -v e="$engine" 'index($2, p) == 1 {print e, $1}'
    done | head -1
}

# the UTC start of container $2 on engine $1, in seconds since the epoch
started_at() {
    python3 -c "import datetime, sys; s = sys.argv[1].rstrip('Z'); print(datetime.datetime.fromisoformat(s[:26]).replace(tzinfo=datetime.timezone.utc).timestamp())" \
        "$(dk "$1" inspect -f '{{.State.StartedAt}}' "$2")"
}

# the stack's containers and networks (and volumes, with $1 = volumes) left on any engine
stack_left() {
    local engine label="label=com.docker.stack.namespace=$V_STACK" left=""
    for engine in $(stack_engines); do
        left="$left $(dk "$engine" ps -a -q --filter "$label") $(dk "$engine" network ls -q --filter "$label")"
        [ "${1:-}" = volumes ] && left="$left $(dk "$engine" volume ls -q --filter "name=${V_STACK}_")"
    done
    echo $left
}

now() { date +%s.%N; }
since() { python3 -c "import sys; print(round(float(sys.argv[2]) - float(sys.argv[1]), 2))" "$1" "$2"; }

stack_down() {
    docker stack rm "$V_STACK" >/dev/null 2>&1
    local deadline=$(( $(date +%s) + 120 )) engine
    while [ "$(date +%s)" -lt "$deadline" ] && [ -n "$(stack_left)" ]; do sleep 1; done
    for engine in $(stack_engines); do  # stack rm keeps named volumes, on every node that made one
        dk "$engine" volume rm "${V_STACK}_recordings" >/dev/null 2>&1 || true
    done
}

# On a swarm with workers: the trackers must be spread over every node; the worker holding the most of them is
# drained. Sets DRAIN_NODE, DRAIN_MOVED (the moved tracker ids, comma-separated), T_DRAIN, DRAIN_STARTED (each
# replacement's start, comma-separated, in DRAIN_MOVED's order) and DRAIN_MOVED_S (drain to every replacement
# running, which for a task with a health check is swarm's word for healthy); the node is active again, its
# router running, when it returns.
stack_drain() {
    local manager placed spread deadline tasks slot started=() engine_id waiting drained_engine
    manager=$(docker info -f '{{.Name}}')
    placed=$(docker service ps "${V_STACK}_node" --filter desired-state=running --format '{{.Node}} {{.Name}}')
    echo "$placed" >"$V_OUT/trackers-placed.txt"
    spread=$(echo "$placed" | awk '{print $1}' | sort -u | wc -l)
    [ "$spread" -eq $((SWARM_WORKERS + 1)) ] || fail "the trackers run on $spread of $((SWARM_WORKERS + 1)) nodes (see $V_OUT/trackers-placed.txt)"
    DRAIN_NODE=$(echo "$placed" | awk -v m="$manager" '$1 != m {n[$1]++} END {for (h in n) print n[h], h}' \
        | sort -k1,1nr -k2 | awk 'NR == 1 {print $2}')
    DRAIN_MOVED=$(echo "$placed" | awk -v h="$DRAIN_NODE" '$1 == h {split($2, a, "."); print a[2] - 1}' | sort -n | paste -sd, -)
    log "trackers on all $spread nodes; draining $DRAIN_NODE (trackers $DRAIN_MOVED)"
    T_DRAIN=$(now)
    docker node update --availability drain "$DRAIN_NODE" >/dev/null || fail "docker node update --availability drain $DRAIN_NODE"
    deadline=$(( $(date +%s) + 60 ))
    while :; do
        tasks=$(docker service ps "${V_STACK}_node" --filter desired-state=running --format '{{.Node}} {{.Name}} {{.CurrentState}}')
        waiting=0
        for slot in ${DRAIN_MOVED//,/ }; do
            echo "$tasks" | awk -v p="${V_STACK}_node.$((slot + 1))" -v h="$DRAIN_NODE" \
                '$2 == p && $1 != h && $3 == "Running" {ok = 1} END {exit !ok}' || waiting=1
        done
        [ "$waiting" = 0 ] && break
        [ "$(date +%s)" -lt "$deadline" ] || fail "the trackers $DRAIN_MOVED of drained $DRAIN_NODE were not all running elsewhere within 60 s"
        sleep "$POLL_S"
    done
    DRAIN_MOVED_S=$(since "$T_DRAIN" "$(now)")
    for slot in ${DRAIN_MOVED//,/ }; do
        engine_id=$(slot_container $((slot + 1)))
        [ -n "$engine_id" ] || fail "tracker $slot: no running container after the drain"
        started+=("$(started_at $engine_id)")
    done
    DRAIN_STARTED=$(IFS=,; echo "${started[*]}")
    drained_engine=$(swn_sock "${DRAIN_NODE#ztsw}")
    [ -z "$(dk "$drained_engine" ps -q --filter "label=com.docker.stack.namespace=$V_STACK")" ] \
        || fail "stack containers still run on drained $DRAIN_NODE: $(dk "$drained_engine" ps --format '{{.Names}}')"
    log "drained $DRAIN_NODE: trackers $DRAIN_MOVED healthy on the other nodes $DRAIN_MOVED_S s later (swarm counts a task with a health check as running once healthy), nothing of the stack left on it"
    docker node update --availability active "$DRAIN_NODE" >/dev/null || fail "docker node update --availability active $DRAIN_NODE"
    deadline=$(( $(date +%s) + 60 ))
    until docker service ps "${V_STACK}_router-$DRAIN_NODE" --filter desired-state=running --format '{{.CurrentState}}' | grep -q '^Running'; do
        [ "$(date +%s)" -lt "$deadline" ] || fail "$DRAIN_NODE active again, but its router not running within 60 s"
        sleep 0.5
    done
    log "$DRAIN_NODE active again, its router running"
}

run_stack_variant() {
    local variant=$1 secure=() routers=() hosts=""
    V_OUT=$OUT/$variant
    V_STACK=$PROJECT${variant//-/}
    mkdir -p "$V_OUT"
    stack_join
    hosts=$(docker node ls --format '{{.Hostname}}' | paste -sd, -)
    routers=(--router-hosts "$hosts")
    if [ "$variant" = stack-secure ]; then
        secure=(--secure)
        rm -rf "$V_OUT/certs"
        local names=(--host router)
        for h in ${hosts//,/ }; do names+=(--host "router-$h"); done
        docker run --rm --user 0 -v "$V_OUT:/out" "$IMAGE" zentrack certs --out /out/certs --nodes "$NODES" "${names[@]}" \
            >"$V_OUT/certs.log" 2>&1 || fail "zentrack certs: $(tail -3 "$V_OUT/certs.log")"
        rm -f "$V_OUT/certs/ca.key"  # the CA key signs; no service needs it (the secrets carry each role's key)
    fi
    # the killed tracker misses the steps of its restart and of its update: allow them in the recorder's check
    docker run --rm "$IMAGE" zentrack compose --stack --nodes "$NODES" --steps "$STACK_STEPS" --run "$V_STACK" \
        --image "$IMAGE" --max-missing-frac 0.4 "${secure[@]}" "${routers[@]}" >"$V_OUT/stack.yml"
    log "stack deploy: $NODES trackers, $STACK_STEPS steps (stack $V_STACK)${secure[*]:+, secure}${hosts:+, a router on $hosts linked to the hub}"
    local t_deploy t_healthy t_kill t_replaced t_update
    t_deploy=$(now)
    docker stack deploy --resolve-image never -c "$V_OUT/stack.yml" "$V_STACK" >"$V_OUT/deploy.log" 2>&1 || fail "stack deploy: $(tail -5 "$V_OUT/deploy.log")"

    local expected=$((NODES + 4 + $(echo "$hosts" | tr , '\n' | grep -c .))) healthy=0 deadline=$(( $(date +%s) + STACK_HEALTH_TIMEOUT_S ))
    while [ "$(date +%s)" -lt "$deadline" ]; do
        healthy=$(stack_healthy)
        [ "$healthy" -ge "$expected" ] && break
        sleep 0.5
    done
    docker stack ps --no-trunc "$V_STACK" >"$V_OUT/tasks-deploy.txt" 2>&1
    [ "$healthy" -ge "$expected" ] || fail "$healthy of $expected tasks healthy within ${STACK_HEALTH_TIMEOUT_S} s (see $V_OUT/tasks-deploy.txt)"
    t_healthy=$(now)
    log "all $expected tasks healthy $(since "$t_deploy" "$t_healthy") s after deploy"

    sleep "$STACK_KILL_AFTER_S"
    local victim replacement=""
    victim=$(slot_container "$STACK_KILL_SLOT")
    [ -n "$victim" ] || fail "no running tracker task in slot $STACK_KILL_SLOT"
    t_kill=$(now)
    dk "${victim% *}" kill "${victim#* }" >/dev/null || fail "docker kill $victim"
    deadline=$(( $(date +%s) + 60 ))
    while [ "$(date +%s)" -lt "$deadline" ]; do
        replacement=$(slot_container "$STACK_KILL_SLOT")
        [ -n "$replacement" ] && [ "$replacement" != "$victim" ] && break
        replacement=""
        sleep "$POLL_S"
    done
    [ -n "$replacement" ] || fail "swarm started no replacement in slot $STACK_KILL_SLOT within 60 s"
    t_replaced=$(started_at $replacement)
    log "tracker slot $STACK_KILL_SLOT killed; replacement (${replacement/ / }) started $(since "$t_kill" "$t_replaced") s later"

    local drain_args=()
    [ "$SWARM_WORKERS" -gt 0 ] && { stack_drain; drain_args=("$T_DRAIN" "$DRAIN_MOVED" "$DRAIN_STARTED"); }

    t_update=$(now)
    docker service update --detach --force --quiet --update-parallelism "$STACK_UPDATE_PARALLELISM" "${V_STACK}_node" \
        >"$V_OUT/update.log" 2>&1 || fail "rolling update of ${V_STACK}_node: $(tail -3 "$V_OUT/update.log")"
    local state="" truth_state
    deadline=$(( $(date +%s) + STACK_UPDATE_TIMEOUT_S ))
    while [ "$(date +%s)" -lt "$deadline" ]; do
        state=$(docker service inspect -f '{{if .UpdateStatus}}{{.UpdateStatus.State}}{{end}}' "${V_STACK}_node")
        case "$state" in completed|paused|rollback_*) break ;; esac
        sleep 1
    done
    truth_state=$(docker inspect -f '{{.State.Running}}' "$(stack_containers truth | head -1)")
    [ "$state" = completed ] || fail "the rolling update ended '$state', not completed"
    [ "$truth_state" = true ] || fail "the run ended before the rolling update did: make --steps longer"
    local update_s
    update_s=$(since "$t_update" "$(now)")
    log "rolling update of $NODES trackers completed in $update_s s with truth running"

    local recorder code
    recorder=$(stack_containers recorder | tail -1)  # the first (oldest) task's container
    code=$(timeout "$RUN_TIMEOUT_S" docker wait "$recorder") || fail "the run did not end within $RUN_TIMEOUT_S s"
    docker logs "$recorder" >"$V_OUT/recorder.log" 2>&1
    [ "$code" = 0 ] || fail "the recorder exited $code: $(grep -m3 FAILED "$V_OUT/recorder.log")"
    if [ "$variant" = stack-secure ]; then
        docker logs "$(stack_containers router | head -1)" >"$V_OUT/router.log" 2>&1 || fail "cannot read the router's log"
        grep -q "access control on" "$V_OUT/router.log" || fail "the router's log does not say access control is on"
        dk "${replacement% *}" logs "${replacement#* }" >"$V_OUT/node-replacement.log" 2>&1 || true
        grep -q "mutual TLS as node-$((STACK_KILL_SLOT - 1))" "$V_OUT/node-replacement.log" \
            || fail "the replacement tracker's log does not say it runs mutual TLS as node-$((STACK_KILL_SLOT - 1))"
        log "stack-secure: the router enforced access control and the replacement ran mutual TLS with its slot's key"
    fi
    docker stack ps --no-trunc "$V_STACK" >"$V_OUT/tasks-end.txt" 2>&1
    for s in $(docker stack services --format '{{.Name}}' "$V_STACK"); do
        timeout 30 docker service logs --raw "$s" >"$V_OUT/${s#"${V_STACK}_"}.log" 2>&1 || true  # it can hang on a replaced task
    done

    if [ -n "$hosts" ]; then
        python3 - "$V_OUT" "$hosts" "$NODES" <<'EOF' || fail "the trackers did not use their host's router (see $V_OUT/node.log)"
import re, sys
out, hosts, nodes = sys.argv[1], sys.argv[2].split(","), int(sys.argv[3])
zid = lambda name: re.findall(r"router ([0-9a-f]+): mode router", open(f"{out}/{name}.log").read())
local = {z for h in hosts for z in zid(f"router-{h}")}
hub = set(zid("router"))
text = open(f"{out}/node.log").read()
took = re.findall(r"client of router ([0-9a-f]+|none yet)", text)
# a tracker opened while its host's router did not answer (that router restarting after a drain, or stopped
# before the tracker in one) takes the hub, the next of its --connect, and says so first
fell_back = len(re.findall(r"no router answered at tcp/router-[^:]+:7447; trying tcp/router:7447", text))
on_hub = sum(z in hub for z in took)
if not local or not hub or sum(z in local for z in took) < nodes or set(took) - local - hub or on_hub > fell_back:
    sys.exit(f"host routers {sorted(local)}, hub {sorted(hub)}: the trackers' sessions took {sorted(set(took))} "
             f"({len(took)} sessions, {on_hub} on the hub, {fell_back} fell back to it)")
print(f"{len(took)} tracker sessions, every one a client of its host's router but {on_hub} that fell back to the hub")
EOF
        log "every tracker session a client of its host's router (or of the hub when that router did not answer), linked to the hub"
    fi
    check_run "${V_STACK}_recordings" "$V_OUT" "$STACK_STEPS" "$((STACK_KILL_SLOT - 1))" "$t_kill" "$t_replaced" \
        "${drain_args[@]}" \
        || fail "checks: $(tail -5 "$V_OUT/checks.json")"
    python3 - "$V_OUT" "$(since "$t_deploy" "$t_healthy")" "$(since "$t_kill" "$t_replaced")" "$update_s" \
        "$SWARM_WORKERS" "$SWARM_UP_S" "${DRAIN_NODE:-}" "${DRAIN_MOVED_S:-0}" <<'EOF' \
        || fail "a replacement rejoined too late (see $V_OUT/checks.json)"
import json, sys
out, healthy, replaced, update, workers, swarm_up, drained, moved_s = sys.argv[1:]
checks = json.load(open(f"{out}/checks.json"))
TS = 0.1  # exp2's sample period
after_start = checks["republished_after_start_steps"]
checks.update(deploy_to_healthy_s=float(healthy), kill_to_replacement_started_s=float(replaced),
              kill_to_republished_s=round(checks["kill_gap_steps"] * TS, 1),
              rolling_update_s=float(update), rolling_update="completed", swarm_workers=int(workers),
              swarm_up_s=float(swarm_up))
late = [] if after_start <= 20 else [f"the replacement published again {after_start} steps after it started (limit 20)"]
if drained:
    checks.update(drained_node=drained, drain_to_replacements_healthy_s=float(moved_s))
    late += [f"tracker {i}, moved off {drained}, published again {n} steps after its replacement started (limit 20)"
             for i, n in checks["drain_republished_after_start_steps"].items() if n > 20]
json.dump(checks, open(f"{out}/checks.json", "w"))
if late:
    sys.exit("; ".join(late))
EOF

    stack_down
    local left
    left="$(stack_left volumes) $(docker secret ls -q --filter "label=com.docker.stack.namespace=$V_STACK") $(docker config ls -q --filter "label=com.docker.stack.namespace=$V_STACK")"
    [ -z "$(echo $left)" ] || fail "left behind after stack rm: $left"
    V_STACK=""
}
