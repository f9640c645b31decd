#!/usr/bin/env bash
# Make N network namespaces that behave like separate hosts, each linked to this (root) namespace by a
# veth pair: host i is 10.77.i.2 and reaches the orchestrator at 10.77.i.1. Needs root and iproute2.
#
#   deploy/netns.sh up 2        # creates zedge-host1, zedge-host2
#   ip netns exec zedge-host1 zenohedge-node --connect tcp/10.77.1.1:7447 --sim lab --group edge-a
#   deploy/netns.sh down        # removes every zedge-host* namespace
set -euo pipefail

up() {
  local n=${1:-2}
  for i in $(seq 1 "$n"); do
    local ns=zedge-host$i
    ip netns add "$ns"
    ip link add "zedge$i-o" type veth peer name "zedge$i-h"
    ip link set "zedge$i-h" netns "$ns"
    ip addr add "10.77.$i.1/24" dev "zedge$i-o"
    ip link set "zedge$i-o" up
    ip netns exec "$ns" ip addr add "10.77.$i.2/24" dev "zedge$i-h"
    ip netns exec "$ns" ip link set "zedge$i-h" up
    ip netns exec "$ns" ip link set lo up
    echo "$ns: 10.77.$i.2, orchestrator at 10.77.$i.1"
  done
}

down() {
  for ns in $(ip netns list | awk '/^zedge-host/ {print $1}'); do
    ip netns delete "$ns"
  done
  for link in $(ip -o link show | awk -F': ' '/zedge[0-9]+-o/ {print $2}' | cut -d@ -f1); do
    ip link delete "$link" 2>/dev/null || true
  done
}

case "${1:-}" in
  up) up "${2:-2}" ;;
  down) down ;;
  *) echo "usage: $0 up [N] | down" >&2; exit 2 ;;
esac
