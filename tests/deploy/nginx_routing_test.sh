#!/usr/bin/env bash
# Three geodesicd replicas on 127.0.0.1 sharing one graph directory, behind
# nginx configured with deploy/nginx/geodesicd.conf. Checks that one mesh's
# queries land on one replica, over gRPC and over HTTP, and that when it is
# killed its traffic moves to another that maps the graph from the shared
# directory, not rebuilding.
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
cleanup() {
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

ports=()
hports=()
for i in 0 1 2; do
  "$bin/geodesicd" serve --listen 127.0.0.1:0 --port-file "$work/ports$i" --graph-dir "$work/graphs" \
    --http-listen 127.0.0.1:0 --mesh-root "$src/data" --log-level info --build-threads 1 \
    2>"$work/replica$i.log" &
  pids[i]=$!
done
for i in 0 1 2; do
  ports[i]=$(wait_port_file "${pids[i]}" "$work/ports$i") ||
    { echo "replica $i did not start"; cat "$work/replica$i.log"; exit 1; }
  hports[i]=$(wait_port_file "${pids[i]}" "$work/ports$i" http)
done
write_config() {
  sed -e "s/geodesicd-\([0-9]\)\.geodesicd-headless:50051/127.0.0.1:PORT\1/" \
      -e "s/geodesicd-\([0-9]\)\.geodesicd-headless:8080/127.0.0.1:HPORT\1/" \
      -e "s/listen 50051 http2;/listen 127.0.0.1:$front http2;/" \
      -e "s/listen 8080;/listen 127.0.0.1:$hfront;/" \
      -e "s/127.0.0.1:PORT0/127.0.0.1:${ports[0]}/" -e "s/127.0.0.1:PORT1/127.0.0.1:${ports[1]}/" \
      -e "s/127.0.0.1:PORT2/127.0.0.1:${ports[2]}/" \
      -e "s/127.0.0.1:HPORT0/127.0.0.1:${hports[0]}/" \
      -e "s/127.0.0.1:HPORT1/127.0.0.1:${hports[1]}/" \
      -e "s/127.0.0.1:HPORT2/127.0.0.1:${hports[2]}/" \
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
check "nginx accepts the deploy configuration" "$nginx" -t -q -c "$work/nginx.conf" -p "$work"
for _ in 1 2 3 4 5; do
  "$nginx" -c "$work/nginx.conf" -p "$work" 2>>"$work/nginx-error.log" && break
  front=$(free_port)
  hfront=$(free_port)
  write_config
done

cli() { timeout 120 "$bin/geodesic" --server "127.0.0.1:$front" --timeout 60 "$@" 2>>"$work/cli.log"; }
for _ in $(seq 100); do cli meshes >/dev/null 2>&1 && break; sleep 0.1; done
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
check "HTTP through nginx answers as gRPC does ($hd, $gd)" test "$hd" = "$gd"
hcounts=$(for i in 0 1 2; do echo $(($(requests "$i") - before[i])); done | tr '\n' ' ')
howner=-1
for i in 0 1 2; do [ $(($(requests "$i") - before[i])) -ge 20 ] && howner=$i; done
check "all 20 HTTP queries for spot landed on one replica ($hcounts)" test "$howner" -ge 0

kill -9 "${pids[owner]}"
wait "${pids[owner]}" 2>/dev/null
d=$(cli --json --eps 0.01 distance --from v:1 --to v:2000 | json 'd[0]["distance"]' 2>/dev/null)
from_file=
for _ in 1 2 3; do  # the survivor may first answer UNAVAILABLE until it maps the graph
  from_file=$(cli --json --eps 0.01 graph --wait | json 'd["from_file"]')
  [ "$from_file" = True ] && break
done
check "after kill -9 of the owner, another replica maps the shared graph (from_file=$from_file)" \
  test "$from_file" = True
for _ in $(seq 10); do cli --eps 0.01 distance --from v:1 --to v:2000 >/dev/null; done
moved=-1
for i in 0 1 2; do [ "$i" != "$owner" ] && [ "$(requests "$i")" -ge 10 ] && moved=$i; done
check "queries moved to one surviving replica ($moved)" test "$moved" -ge 0
[ "$failures" = 0 ] || for f in "$work"/*.log; do echo "--- $f"; tail -n 5 "$f"; done
exit $((failures > 0))
