#!/bin/sh
# Keeps the replicas listed in nginx's geodesicd upstreams (geodesicd.conf)
# on their current addresses, and lets nginx start before any replica does.
#
# nginx (open source) resolves an upstream server's name only when it reads
# its configuration, and refuses the whole configuration when one name does
# not resolve. So this script writes the two server lists that geodesicd.conf
# includes, from the names that resolve now, starts nginx, and every few
# seconds writes them again, reloading nginx when they change. Each server
# keeps its name as written: nginx places a server on its hash ring by that
# name and port, so a pod that comes back with a new address keeps its
# meshes. The addresses a name resolved to are written beside it, as a
# comment, so that a new address alone changes the file and reloads nginx.
#
#   geodesicd-upstreams.sh render             write the server lists once
#   geodesicd-upstreams.sh run [NGINX_ARGS]   write them, run nginx (in the
#       foreground, as this script's child: the main configuration must not
#       say `daemon`) and keep them current until nginx exits
#
# Environment:
#   GEODESICD_UPSTREAMS_DIR   where grpc-servers.conf and http-servers.conf
#                             go; geodesicd.conf includes them from the
#                             default, /run/geodesicd-nginx
#   GEODESICD_BACKENDS_CMD    a command printing the replicas, one a line:
#                             HOST GRPC_PORT HTTP_PORT
#   GEODESICD_BACKENDS_FILE   or a file of such lines (missing: none yet)
#   Neither set: the StatefulSet's pods, GEODESICD_REPLICAS (3) names from
#   GEODESICD_REPLICA_NAME (printf, geodesicd-%d.geodesicd-headless) on ports
#   GEODESICD_GRPC_PORT (50051) and GEODESICD_HTTP_PORT (8080).
#   GEODESICD_RESOLVE_INTERVAL  seconds between looks (5)
#   GEODESICD_SERVER_PARAMS   appended to each server line
#   GEODESICD_NGINX_BIN       the nginx binary (nginx); not NGINX, which
#                             nginx reads as sockets handed over to it
set -u

dir=${GEODESICD_UPSTREAMS_DIR:-/run/geodesicd-nginx}
interval=${GEODESICD_RESOLVE_INTERVAL:-5}
# One failed connection takes a replica off the ring for a while, so that
# calls fail over at once rather than each waiting for the dead one.
params=${GEODESICD_SERVER_PARAMS:-max_fails=1 fail_timeout=10s}
nginx=${GEODESICD_NGINX_BIN:-nginx}

log() { echo "geodesicd-upstreams: $*" >&2; }

list_backends() {
  if [ -n "${GEODESICD_BACKENDS_CMD:-}" ]; then
    sh -c "$GEODESICD_BACKENDS_CMD"
  elif [ -n "${GEODESICD_BACKENDS_FILE:-}" ]; then
    [ ! -e "$GEODESICD_BACKENDS_FILE" ] || cat "$GEODESICD_BACKENDS_FILE"
  else
    i=0
    while [ "$i" -lt "${GEODESICD_REPLICAS:-3}" ]; do
      # shellcheck disable=SC2059  # the name's format is the setting
      printf "${GEODESICD_REPLICA_NAME:-geodesicd-%d.geodesicd-headless}" "$i"
      echo " ${GEODESICD_GRPC_PORT:-50051} ${GEODESICD_HTTP_PORT:-8080}"
      i=$((i + 1))
    done
  fi
}

# Writes $dir/{grpc,http}-servers.conf.new. A lister that fails says nothing
# about the replicas: the lists in use stay, and with none yet, nginx starts
# on the placeholder.
render() {
  if ! list_backends > "$dir/backends.new"; then
    log "listing the replicas failed"
    [ ! -e "$dir/grpc-servers.conf" ] || return 1
    : > "$dir/backends.new"
  fi
  : > "$dir/grpc-servers.conf.new"
  : > "$dir/http-servers.conf.new"
  while read -r host grpc_port http_port _; do
    case $host in '' | '#'*) continue ;; esac
    # getaddrinfo, as nginx itself resolves the name when it reloads.
    addrs=$(getent ahosts "$host" < /dev/null | awk '{ print $1 }' | sort -u | paste -sd ' ' -)
    if [ -z "$addrs" ]; then
      for f in grpc http; do echo "# $host does not resolve" >> "$dir/$f-servers.conf.new"; done
      continue
    fi
    case $host in *:*) name="[$host]" ;; *) name=$host ;; esac
    echo "server $name:$grpc_port $params;  # $addrs" >> "$dir/grpc-servers.conf.new"
    echo "server $name:$http_port $params;  # $addrs" >> "$dir/http-servers.conf.new"
  done < "$dir/backends.new"
  if ! grep -q '^server' "$dir/http-servers.conf.new"; then
    # An upstream needs a server; one marked down makes nginx answer 502
    # (gRPC: UNAVAILABLE) until a replica resolves.
    for f in grpc http; do
      echo "server 127.0.0.1:1 down;  # no replica resolves" >> "$dir/$f-servers.conf.new"
    done
  fi
}

changed() {
  for f in grpc http; do
    cmp -s "$dir/$f-servers.conf.new" "$dir/$f-servers.conf" || return 0
  done
  return 1
}

install_new() {
  for f in grpc http; do mv -f "$dir/$f-servers.conf.new" "$dir/$f-servers.conf"; done
}

# A HUP that comes before nginx handles it (its configuration is still being
# read, and resolving names can take a while) ends nginx instead. Where /proc
# cannot tell, nginx is taken to be up.
handles_hup() {
  caught=$(awk '/^SigCgt:/ { print $2 }' "/proc/$nginx_pid/status" 2>/dev/null)
  case $caught in
    '' | *[13579bdfBDF]) return 0 ;;
    *) return 1 ;;
  esac
}

# Each round: write the lists again and, when they changed, check the whole
# configuration before reloading, so that a name that stopped resolving in
# between leaves the running configuration alone until the next round.
update() {
  handles_hup || return
  render || return
  changed || return
  for f in grpc http; do
    if [ -e "$dir/$f-servers.conf" ]; then
      cp "$dir/$f-servers.conf" "$dir/$f-servers.conf.old"
    else
      rm -f "$dir/$f-servers.conf.old"
    fi
  done
  install_new
  if "$nginx" -t -q "$@" 2> "$dir/test.log"; then
    log "replicas: $(awk '/^server/ { print $2 }' "$dir/grpc-servers.conf" | paste -sd ' ' -)"
    kill -HUP "$nginx_pid"
  else
    log "not reloading: $(cat "$dir/test.log")"
    for f in grpc http; do
      if [ -e "$dir/$f-servers.conf.old" ]; then
        mv -f "$dir/$f-servers.conf.old" "$dir/$f-servers.conf"
      fi
    done
  fi
}

mode=${1:-}
case $mode in
  render | run) shift ;;
  *)
    echo "usage: $0 render | run [NGINX_ARGS...]" >&2
    exit 2
    ;;
esac
mkdir -p "$dir" || exit 1
if [ "$mode" = render ]; then
  render || exit 1
  install_new
  exit 0
fi

nginx_pid=
stopping=
# shellcheck disable=SC2317  # called from the traps
stop() {
  stopping=$1
  [ -z "$nginx_pid" ] || kill -"$1" "$nginx_pid" 2>/dev/null
}
# TERM (Kubernetes stopping the pod) lets the calls in flight finish; INT
# does not. A HUP meant for nginx (this script may be the container's first
# process) reaches it once nginx can take it.
trap 'stop QUIT' TERM QUIT
trap 'stop TERM' INT
trap '[ -z "$nginx_pid" ] || ! handles_hup || kill -HUP "$nginx_pid" 2>/dev/null' HUP
# With no name resolving, nginx starts on the placeholder.
render || exit 1
install_new
"$nginx" "$@" -g 'daemon off;' &
nginx_pid=$!
[ -z "$stopping" ] || kill -"$stopping" "$nginx_pid"
while [ -z "$stopping" ] && kill -0 "$nginx_pid" 2>/dev/null; do
  # A signal ends the wait, not the sleep; so the wait.
  sleep "$interval" &
  wait $! 2>/dev/null
  [ -z "$stopping" ] && kill -0 "$nginx_pid" 2>/dev/null && update "$@"
done
while :; do
  wait "$nginx_pid"
  status=$?
  kill -0 "$nginx_pid" 2>/dev/null || break
done
exit "$status"
