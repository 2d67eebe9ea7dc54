#!/usr/bin/env bash
# Swarm worker nodes in network namespaces on this one machine (root): a multi-node Docker Swarm to test on,
# without a second machine. Each worker is a Docker engine of its own, as a second machine would have:
#   - its own network namespace `ztsw<i>`, on a bridge `ztsw0` with this host (10.99.0.1; worker i at
#     10.99.0.<i+1>): swarm's management (2377/tcp), gossip (7946) and overlay VXLAN (4789/udp) cross it;
#   - its own mount and UTS namespaces (host name `ztsw<i>`; a tmpfs over /run/containerd and its own
#     /etc/docker, so that it starts its own containerd and has its own engine key);
#   - its own data root, exec root, socket and containerd namespace under $STATE (/run) and $DATA (/var/lib).
# `up` starts them, makes this host's engine the swarm's manager when it is in no swarm (`docker swarm init` on
# 10.99.0.1), joins each worker, labels every node `zentrack.zone=<its host name>` (the stack spreads its
# trackers over that label) and loads the image into each worker (`docker save | docker load`; the stack is
# deployed with --resolve-image never). `down` undoes all of it: the workers leave and are removed from the
# node list, their engines stop, their namespaces, bridge, firewall rules and data go, and the host leaves the
# swarm if `up` made it (with $SWN_LOGS set, each worker engine's log is copied there first). `env <i>` prints
# the DOCKER_HOST of worker i; `status` the swarm's nodes.
#
# usage: bash deploy/swarm-nodes.sh up [--workers N] [--image IMAGE]
#        bash deploy/swarm-nodes.sh down | status | env I
# Sourced (by deploy/stack-test.sh), it defines swarm_nodes_up / swarm_nodes_down and runs nothing; a caller that
# sets SWN_OWNER to its pid has its workers taken down by the next `up` if it is killed before its own `down`.
set -uo pipefail

SWN_STATE=/run/zentrack-swarm
SWN_DATA=/var/lib/zentrack-swarm
SWN_BRIDGE=ztsw0
SWN_HOST_IP=10.99.0.1
SWN_PREFIX=10.99.0

swn_log() { echo "swarm-nodes: $*" >&2; }
swn_fail() { echo "swarm-nodes: FAILED: $*" >&2; return 1; }
swn_sock() { echo "unix://$SWN_STATE/ztsw$1/docker.sock"; }
swn_workers() { ls -d "$SWN_STATE"/ztsw[0-9]* 2>/dev/null | sed 's|.*/ztsw||' | sort -n; }

swn_owner_gone() {  # the workers were brought up by a script (SWN_OWNER) that is no longer running
    local pid
    pid=$(cat "$SWN_STATE/owner.pid" 2>/dev/null) || return 1
    case "$pid" in ''|*[!0-9]*) return 1 ;; esac
    ! kill -0 "$pid" 2>/dev/null
}

swn_fw() {  # $1: -A or -D; bridged traffic between the nodes passes this host's FORWARD chain (br_netfilter)
    iptables -w "$1" FORWARD -i "$SWN_BRIDGE" -o "$SWN_BRIDGE" -j ACCEPT 2>/dev/null
}

swn_start_worker() {
    local i=$1 name="ztsw$1" dir="$SWN_STATE/ztsw$1"
    mkdir -p "$dir/exec" "$dir/etc" "$SWN_DATA/$name"
    echo '{}' >"$dir/etc/daemon.json"
    ip netns add "$name" || return 1
    ip link add "$name-h" type veth peer name "$name-n" || return 1
    ip link set "$name-h" master "$SWN_BRIDGE" up
    ip link set "$name-n" netns "$name"
    ip -n "$name" addr add "$SWN_PREFIX.$((i + 1))/24" dev "$name-n"
    ip -n "$name" link set "$name-n" up
    ip -n "$name" link set lo up
    ip -n "$name" route add default via "$SWN_HOST_IP"
    # DOCKER_SERVICE_PREFER_OFFLINE_IMAGE: a task whose image is loaded starts without trying a registry first
    DOCKER_SERVICE_PREFER_OFFLINE_IMAGE=1 setsid unshare --mount --uts --propagation private sh -c "
        hostname $name && mount -t tmpfs tmpfs /run/containerd && mount --bind $dir/etc /etc/docker &&
        exec nsenter --net=/run/netns/$name dockerd --data-root $SWN_DATA/$name --exec-root $dir/exec \
            --pidfile $dir/dockerd.pid -H $(swn_sock "$i") --containerd-namespace $name \
            --containerd-plugins-namespace $name-plugins" >"$dir/dockerd.log" 2>&1 </dev/null &
    echo $! >"$dir/launcher.pid"
    local deadline=$(( $(date +%s) + 60 ))
    until docker -H "$(swn_sock "$i")" info >/dev/null 2>&1; do
        [ "$(date +%s)" -lt "$deadline" ] || { swn_fail "worker $name's engine did not answer in 60 s: $(tail -2 "$dir/dockerd.log")"; return 1; }
        sleep 0.5
    done
}

swarm_nodes_up() {  # $1 workers, $2 image (may be empty)
    local workers=$1 image=${2:-} state addr token i
    [ "$(id -u)" = 0 ] || { swn_fail "needs root (network namespaces and Docker engines)"; return 1; }
    docker info >/dev/null 2>&1 || { swn_fail "this host's Docker engine does not answer (start dockerd first)"; return 1; }
    if [ -n "$(swn_workers)" ]; then
        # workers of a run that was killed (its pid recorded, no longer running) are taken down; any others are
        # somebody's: left alone
        swn_owner_gone || { swn_fail "workers are up already ($SWN_STATE): bash deploy/swarm-nodes.sh down first"; return 1; }
        swn_log "workers of a run that ended without taking them down (pid $(cat "$SWN_STATE/owner.pid")): taking them down"
        swarm_nodes_down
    fi
    [ -z "$image" ] || docker image inspect "$image" >/dev/null 2>&1 || { swn_fail "no image $image on this host"; return 1; }
    state=$(docker info -f '{{.Swarm.LocalNodeState}}')
    addr=$(docker info -f '{{.Swarm.NodeAddr}}')
    if [ "$state" = active ] && [ "$addr" != "$SWN_HOST_IP" ]; then
        swn_fail "this engine is in a swarm on $addr, which namespaces cannot reach: docker swarm leave --force first"; return 1
    fi
    mkdir -p "$SWN_STATE"
    [ -z "${SWN_OWNER:-}" ] || echo "$SWN_OWNER" >"$SWN_STATE/owner.pid"  # a script's pid: stale once it has ended
    ip link add "$SWN_BRIDGE" type bridge 2>/dev/null
    ip addr add "$SWN_HOST_IP/24" dev "$SWN_BRIDGE" 2>/dev/null
    ip link set "$SWN_BRIDGE" up
    swn_fw -A
    if [ "$state" != active ]; then
        docker network inspect docker_gwbridge >/dev/null 2>&1 || touch "$SWN_STATE/made-gwbridge"
        docker swarm init --advertise-addr "$SWN_HOST_IP" --listen-addr "$SWN_HOST_IP:2377" >"$SWN_STATE/init.log" 2>&1 \
            || { swn_fail "docker swarm init: $(tail -2 "$SWN_STATE/init.log")"; return 1; }
        touch "$SWN_STATE/made-swarm"
    fi
    docker node update --label-add "zentrack.zone=$(docker info -f '{{.Name}}')" "$(docker info -f '{{.Swarm.NodeID}}')" >/dev/null
    token=$(docker swarm join-token -q worker)
    for i in $(seq 1 "$workers"); do
        swn_start_worker "$i" || return 1
        docker -H "$(swn_sock "$i")" swarm join --token "$token" --advertise-addr "$SWN_PREFIX.$((i + 1))" \
            --listen-addr "$SWN_PREFIX.$((i + 1)):2377" "$SWN_HOST_IP:2377" >/dev/null \
            || { swn_fail "worker ztsw$i did not join"; return 1; }
        docker node update --label-add "zentrack.zone=ztsw$i" \
            "$(docker -H "$(swn_sock "$i")" info -f '{{.Swarm.NodeID}}')" >/dev/null
        if [ -n "$image" ]; then
            docker save "$image" | docker -H "$(swn_sock "$i")" load >/dev/null \
                || { swn_fail "loading $image into ztsw$i"; return 1; }
        fi
        swn_log "worker ztsw$i joined at $SWN_PREFIX.$((i + 1))${image:+, $image loaded}"
    done
}

swarm_nodes_down() {
    local i dir pid id
    for i in $(swn_workers); do
        dir="$SWN_STATE/ztsw$i"
        if docker -H "$(swn_sock "$i")" info >/dev/null 2>&1; then
            id=$(docker -H "$(swn_sock "$i")" info -f '{{.Swarm.NodeID}}')
            docker -H "$(swn_sock "$i")" swarm leave --force >/dev/null 2>&1
            [ -n "$id" ] && docker node rm --force "$id" >/dev/null 2>&1
        fi
        pid=$(cat "$dir/dockerd.pid" 2>/dev/null || cat "$dir/launcher.pid" 2>/dev/null)
        if [ -n "$pid" ]; then
            kill "$pid" 2>/dev/null
            for _ in $(seq 1 200); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
            kill -9 "$pid" 2>/dev/null
        fi
        # the worker's containerd and container shims die with their engine's mount namespace; wait for them
        for _ in $(seq 1 100); do pgrep -f "containerd.*$dir/exec" >/dev/null || break; sleep 0.1; done
        pkill -9 -f "containerd.*$dir/exec" 2>/dev/null
        ip netns del "ztsw$i" 2>/dev/null
        ip link del "ztsw$i-h" 2>/dev/null
        if [ -n "${SWN_LOGS:-}" ]; then  # the worker engine's log, kept where the caller asks
            mkdir -p "$SWN_LOGS" && cp "$dir/dockerd.log" "$SWN_LOGS/ztsw$i-dockerd.log" 2>/dev/null
        fi
        rm -rf "$SWN_DATA/ztsw$i" "$dir"
    done
    if [ -f "$SWN_STATE/made-swarm" ]; then
        docker swarm leave --force >/dev/null 2>&1
        [ -f "$SWN_STATE/made-gwbridge" ] && docker network rm docker_gwbridge >/dev/null 2>&1
    fi
    swn_fw -D
    ip link del "$SWN_BRIDGE" 2>/dev/null
    rm -rf "$SWN_STATE"
    rmdir "$SWN_DATA" 2>/dev/null
    return 0
}

if [ "${BASH_SOURCE[0]}" = "$0" ]; then
    cmd=${1:-}; shift || true
    workers=1 image=""
    while [ $# -gt 0 ]; do
        case "$1" in
            --workers) workers=$2; shift 2 ;;
            --image) image=$2; shift 2 ;;
            *) [ "$cmd" = env ] && break; echo "swarm-nodes: unknown argument $1 (see the header of $0)" >&2; exit 2 ;;
        esac
    done
    case "$cmd" in
        up)
            case "$workers" in ''|*[!0-9]*|0) echo "swarm-nodes: --workers takes a positive integer, got '$workers'" >&2; exit 2 ;; esac
            [ "$workers" -le 200 ] || { echo "swarm-nodes: --workers: at most 200" >&2; exit 2; }
            swarm_nodes_up "$workers" "$image" || { swarm_nodes_down; exit 1; }
            docker node ls ;;
        down) swarm_nodes_down; swn_log "workers gone, bridge and namespaces removed" ;;
        status) swn_workers | sed 's/^/worker ztsw/'; docker node ls 2>/dev/null ;;
        env) [ -d "$SWN_STATE/ztsw${1:-x}" ] || { echo "swarm-nodes: no worker ${1:-}" >&2; exit 2; }; echo "DOCKER_HOST=$(swn_sock "$1")" ;;
        *) echo "swarm-nodes: say up, down, status or env I (see the header of $0)" >&2; exit 2 ;;
    esac
fi
