#!/usr/bin/env bash
# Three geodesicd replicas on 127.0.0.1 sharing one graph directory, behind
# nginx configured with deploy/nginx/geodesicd.conf and run by
# deploy/nginx/geodesicd-upstreams.sh. Checks that nginx starts before any
# replica exists and routes once they are listed, that one mesh's queries
# land on one replica, over gRPC and over HTTP, that when it is killed its
# traffic moves to another that serves the graph from the shared directory,
# with nobody building it twice, and that once restarted on a new port it
# gets traffic again with nobody reloading nginx.
# The replicas' list is a file the test rewrites, standing in for the
# cluster DNS, with host and ports, since a restarted replica's new port
# stands in for a pod's new address.
# Exits 77 (skipped) when nginx is not installed.
# Usage: nginx_routing_test.sh BUILD_BIN_DIR SOURCE_DIR
set -uo pipefail
bin=$1
src=$2
nginx=$(command -v nginx || echo /usr/sbin/nginx)
[ -x "$nginx" ] || { echo "skip: nginx is not installed (scripts/setup.sh --with-nginx)"; exit 77; }
work=$(mktemp -d)
chmod 755 "$work"
failures=0
source "$src/tests/server/daemon_port.sh"
# nginx cannot report a port it picked, so its front port is one found free,
# and nginx is started again on another if that one is taken meanwhile.
free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }
pids=()
watcher=
cleanup() {
  [ -n "$watcher" ] && kill "$watcher" 2>/dev/null
  [ -f "$work/nginx.pid" ] && kill "$(cat "$work/nginx.pid")" 2>/dev/null
  for p in "${pids[@]}"; do kill -9 "$p" 2>/dev/null; done
  wait 2>/dev/null
  rm -rf "$work"
}
trap cleanup EXIT
check() {  # check NAME COMMAND...: passes when the command succeeds
  local name=$1; shift
  if "$@"; then echo "ok   $name"; else failures=$((failures + 1)); echo "FAIL $name"; fi
}
json() { python3 -c "import json,sys; d=json.load(sys.stdin); print($1)"; }
wait_until() {  # wait_until SECONDS COMMAND...: fails when COMMAND has not succeeded by then
  local deadline=$((SECONDS + $1))
  shift
  until "$@"; do
    [ "$SECONDS" -lt "$deadline" ] || return 1
    sleep 0.2
  done
}

ports=()
hports=()
start_replica() {  # start_replica I: on new ports, as a pod comes back on a new address
  rm -f "$work/ports$1"
  "$bin/geodesicd" serve --listen 127.0.0.1:0 --port-file "$work/ports$1" --graph-dir "$work/graphs" \
    --http-listen 127.0.0.1:0 --mesh-root "$src/data" --log-level info --build-threads 1 \
    2>>"$work/replica$1.log" &
  pids[$1]=$!
}
wait_replica() {
  ports[$1]=$(wait_port_file "${pids[$1]}" "$work/ports$1") ||
    { echo "replica $1 did not start"; cat "$work/replica$1.log"; exit 1; }
  hports[$1]=$(wait_port_file "${pids[$1]}" "$work/ports$1" http)
}
nginx_workers() {  # none while nginx has written no pid (pgrep -P 0 would list the kernel's)
  local master
  master=$(cat "$work/nginx.pid" 2>/dev/null) || return 0
  pgrep -P "$master" | sort -n | paste -sd ' ' -
}
only_new_workers() {  # only_new_workers "PID...": nginx has workers, none of them these
  local now
  now=" $(nginx_workers) "
  [ "$now" != "  " ] || return 1
  for p in $1; do [[ "$now" != *" $p "* ]] || return 1; done
}
list_replicas() {  # list_replicas I...: what the cluster DNS would resolve now
  local old
  old=$(nginx_workers)
  for i in "$@"; do echo "127.0.0.1 ${ports[i]} ${hports[i]}"; done > "$work/backends.new"
  mv "$work/backends.new" "$work/backends"
  # Until nginx's old workers have exited, a new connection may still reach
  # one and be routed by the old list, after another call went by the new.
  wait_until 30 only_new_workers "$old" || echo "nginx kept its old workers ($old)"
}
upstreams() {  # upstreams COMMAND...: the watcher's settings for this test
  GEODESICD_UPSTREAMS_DIR="$work/upstreams" GEODESICD_BACKENDS_FILE="$work/backends" \
    GEODESICD_RESOLVE_INTERVAL=1 GEODESICD_NGINX_BIN="$nginx" "$@"
}
watcher_script=$src/deploy/nginx/geodesicd-upstreams.sh
write_config() {
  sed -e "s|/run/geodesicd-nginx/|$work/upstreams/|" \
      -e "s/listen 50051 http2;/listen 127.0.0.1:$front http2;/" \
      -e "s/listen 8080;/listen 127.0.0.1:$hfront;/" \
      "$src/deploy/nginx/geodesicd.conf" > "$work/geodesicd.conf"
}
mkdir -m 777 "$work/tmp"
cat > "$work/nginx.conf" <<CONF
worker_processes 1;
pid $work/nginx.pid;
error_log $work/nginx-error.log warn;
events { worker_connections 256; }
http {
    access_log off;
    client_body_temp_path $work/tmp/body;
    proxy_temp_path $work/tmp/proxy;
    fastcgi_temp_path $work/tmp/fastcgi;
    uwsgi_temp_path $work/tmp/uwsgi;
    scgi_temp_path $work/tmp/scgi;
    include $work/geodesicd.conf;
}
CONF
front=$(free_port)
hfront=$(free_port)
write_config

# The watcher's lists, before nginx runs on them: names stay as written (the
# ring places a replica by its name, which a pod keeps across addresses), a
# name that does not resolve is left out, and none at all is a placeholder.
placeholder() { [ "$(grep -c '^server .* down;' "$work/upstreams/$1-servers.conf")" = 1 ]; }
upstreams sh "$watcher_script" render 2>>"$work/watcher.log"
check "with no replica listed, both upstreams hold one server marked down" \
  eval 'placeholder grpc && placeholder http'
check "nginx accepts the deploy configuration" "$nginx" -t -q -c "$work/nginx.conf" -p "$work"
GEODESICD_UPSTREAMS_DIR="$work/render" \
  GEODESICD_BACKENDS_CMD='printf "localhost 1001 1002\ngeodesicd-9.invalid 1003 1004\n"' \
  sh "$watcher_script" render 2>>"$work/watcher.log"
check "a name is kept as written, one that does not resolve is left out" \
  eval 'grep -q "^server localhost:1001 " "$work/render/grpc-servers.conf" &&
        grep -q "^server localhost:1002 " "$work/render/http-servers.conf" &&
        ! grep -q "^server geodesicd-9" "$work/render/grpc-servers.conf" "$work/render/http-servers.conf"'

http_status() {  # http_status PATH: prints the HTTP status through nginx, nothing when none answers
  python3 - "$hfront" "$1" <<'PY'
import sys, urllib.error, urllib.request
try:
    print(urllib.request.urlopen(f"http://127.0.0.1:{sys.argv[1]}{sys.argv[2]}", timeout=10).status)
except urllib.error.HTTPError as e:
    print(e.code)
except OSError:
    pass
PY
}
started_or_gone() { ! kill -0 "$watcher" 2>/dev/null || [ -n "$(http_status /v1/meshes)" ]; }
for _ in 1 2 3 4 5; do
  upstreams sh "$watcher_script" run -c "$work/nginx.conf" -p "$work" 2>>"$work/watcher.log" &
  watcher=$!
  wait_until 20 started_or_gone
  kill -0 "$watcher" 2>/dev/null && break
  front=$(free_port)
  hfront=$(free_port)
  write_config
done
status=$(http_status /v1/meshes)
check "nginx started before any replica exists and answers HTTP with 502 ($status)" \
  test "$status" = 502
unavailable=$(timeout 60 "$bin/geodesic" --server "127.0.0.1:$front" --timeout 10 meshes 2>&1 | tail -n 1)
# UNAVAILABLE alone could be nobody listening; 502 says nginx answered.
check "and gRPC with UNAVAILABLE ($unavailable)" eval '[[ "$unavailable" == *UNAVAILABLE*502* ]]'

cli() { timeout 120 "$bin/geodesic" --server "127.0.0.1:$front" --timeout 60 "$@" 2>>"$work/cli.log"; }
for i in 0 1 2; do start_replica "$i"; done
for i in 0 1 2; do wait_replica "$i"; done
list_replicas 0 1 2
routed=false
wait_until 30 eval 'cli meshes >/dev/null 2>&1' && routed=true
check "once the replicas are listed nginx routes to them, with no reload by hand" $routed
show_logs() { for f in "$work"/*.log; do echo "--- $f"; tail -n 5 "$f"; done; }
# Nothing after this can pass without routing: stop before minutes of timeouts.
$routed || { show_logs; exit 1; }
requests() { grep -c "method=Distance mesh=spot" "$work/replica$1.log"; }

state=$(cli --json --eps 0.01 graph --wait | json 'd["state"]')
check "graph built through nginx" test "$state" = ready
for _ in $(seq 20); do cli --eps 0.01 distance --from v:1 --to v:2000 >/dev/null; done
counts=$(for i in 0 1 2; do requests "$i"; done | tr '\n' ' ')
owner=-1
for i in 0 1 2; do [ "$(requests "$i")" = 20 ] && owner=$i; done
check "all 20 queries for spot landed on one replica ($counts)" test "$owner" -ge 0
check "the graph file is in the shared directory" test -n "$(ls "$work/graphs" | grep 'eps0.01-r[0-9]*.dgg$')"

# Over HTTP: the mesh in the URL picks the replica. The HTTP ring is not
# the gRPC one (nginx hashes each replica's address with its port), so the
# HTTP owner may be another replica, but it is one replica.
# An HTTP client requests the graph as it queries it, through nginx, and
# the HTTP owner maps the graph file the gRPC owner wrote.
http() {  # http PATH [BODY]: prints the JSON reply
  python3 - "$hfront" "$@" <<'PY'
import json, sys, urllib.request
url = f"http://127.0.0.1:{sys.argv[1]}{sys.argv[2]}"
body = sys.argv[3].encode() if len(sys.argv) > 3 else None
req = urllib.request.Request(url, data=body, headers={"Content-Type": "application/json"})
print(json.dumps(json.load(urllib.request.urlopen(req, timeout=60))))
PY
}
http_distance() {
  http /v1/meshes/spot/distance '{"pairs": [["v:1", "v:2000"]], "eps": 0.01}' | json 'd["distances"][0]'
}
http /v1/meshes/spot/graph '{"eps": 0.01}' >/dev/null 2>>"$work/cli.log"
hstate=
for _ in $(seq 100); do
  hstate=$(http '/v1/meshes/spot/graph?eps=0.01' 2>>"$work/cli.log" | json 'd["state"]')
  [ "$hstate" = READY ] && break
  sleep 0.1
done
check "graph requested over HTTP through nginx ($hstate)" test "$hstate" = READY
before=()
for i in 0 1 2; do before[i]=$(requests "$i"); done
hd=
for _ in $(seq 20); do hd=$(http_distance 2>>"$work/cli.log"); done
gd=$(cli --json --eps 0.01 distance --from v:1 --to v:2000 | json 'd[0]["distance"]')
check "HTTP through nginx answers as gRPC does ($hd, $gd)" eval '[ -n "$hd" ] && [ "$hd" = "$gd" ]'
hcounts=$(for i in 0 1 2; do echo $(($(requests "$i") - before[i])); done | tr '\n' ' ')
howner=-1
for i in 0 1 2; do [ $(($(requests "$i") - before[i])) -ge 20 ] && howner=$i; done
check "all 20 HTTP queries for spot landed on one replica ($hcounts)" test "$howner" -ge 0

kill -9 "${pids[owner]}"
wait "${pids[owner]}" 2>/dev/null
d=$(cli --json --eps 0.01 distance --from v:1 --to v:2000 | json 'd[0]["distance"]' 2>/dev/null)
state=
for _ in 1 2 3; do  # the survivor may first answer UNAVAILABLE until it maps the graph
  state=$(cli --json --eps 0.01 graph --wait | json 'd["state"]')
  [ "$state" = ready ] && break
done
# Replicas follow the shared catalog, so each requested the graph before the
# kill, and whichever took the graph directory's build lock first built it
# (not always the owner: its record reaches the catalog before its build
# starts). What matters is that nobody builds it again.
builds=$(cat "$work"/replica*.log | grep -c 'graph_build_started mesh=spot params="eps 0.01,')
check "after kill -9 of the owner, another replica serves the shared graph ($state), built once in all ($builds)" \
  eval '[ "$state" = ready ] && [ "$builds" = 1 ]'
for _ in $(seq 10); do cli --eps 0.01 distance --from v:1 --to v:2000 >/dev/null; done
moved=-1
for i in 0 1 2; do [ "$i" != "$owner" ] && [ "$(requests "$i")" -ge 10 ] && moved=$i; done
check "queries moved to one surviving replica ($moved)" test "$moved" -ge 0

# The owner comes back on new ports and the list says so; nginx must follow
# by itself. A new port moves it on the ring here (a pod keeps its name, and
# so its place), so the check is that it owns a share of the mesh names
# again, over both protocols: calls for meshes that do not exist, which every
# replica answers (NOT_FOUND) and logs with the mesh's name.
start_replica "$owner"
wait_replica "$owner"
list_replicas 0 1 2
probes=30
probed() { grep -c "method=$1 mesh=probe" "$work/replica$owner.log"; }
probe_round() {
  for n in $(seq "$probes"); do cli --mesh "probe$n" snap 0,0,0 >/dev/null 2>&1; done
  python3 - "$hfront" "$probes" <<'PY'
import sys, urllib.error, urllib.request
for n in range(1, int(sys.argv[2]) + 1):
    try:
        urllib.request.urlopen(f"http://127.0.0.1:{sys.argv[1]}/v1/meshes/probe{n}/graph?eps=0.01",
                               timeout=10)
    except (urllib.error.HTTPError, OSError):
        pass
PY
  [ "$(probed Snap)" -gt 0 ] && [ "$(probed GetGraph)" -gt 0 ]
}
wait_until 30 probe_round
check "the owner restarted on a new port gets mesh names over gRPC again, unreloaded ($(probed Snap) calls)" \
  test "$(probed Snap)" -gt 0
check "and over HTTP ($(probed GetGraph) calls)" test "$(probed GetGraph)" -gt 0
for i in 0 1 2; do before[i]=$(requests "$i"); done
answered=0
for _ in $(seq 10); do cli --eps 0.01 distance --from v:1 --to v:2000 >/dev/null && answered=$((answered + 1)); done
back=-1
for i in 0 1 2; do [ $(($(requests "$i") - before[i])) = 10 ] && back=$i; done
check "after the change spot's 10 queries are answered ($answered) on one replica ($back)" \
  eval '[ "$answered" = 10 ] && [ "$back" -ge 0 ]'
[ "$failures" = 0 ] || show_logs
exit $((failures > 0))
