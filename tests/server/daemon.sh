# The shell tests' daemon fixture and checks, sourced (it defines functions
# and runs nothing). Daemons listen on 127.0.0.1 port 0 and name the ports
# they bound in --port-file: a port found free a moment earlier may be taken
# by another test by the time the daemon binds it.
#
#   daemon_start BIN WORK [SERVE_FLAGS...]
#       "$BIN/geodesicd serve" with SERVE_FLAGS, its stderr appended to
#       $WORK/daemon.log; sets daemon (its pid), port (gRPC), and http_port
#       and metrics_port (empty unless it listens there). Fails, printing the
#       log, if the daemon exits or names no port within 60 s.
#   daemon_stop [PID]     SIGTERM, then SIGKILL if it lives on after 30 s
#   daemon_kill [PID]     SIGKILL
#   daemon_cleanup        stops every daemon started here: for an EXIT trap
#   daemon_fail MESSAGE   prints MESSAGE and the log, and exits 1
#   retry_for SECONDS COMMAND...   runs COMMAND until it succeeds, for at
#                                  most SECONDS
#
#   check NAME COMMAND...   counts a pass or a failure (passes, failures)
#   same_number A B         both finite numbers, and equal as printed
#   same_file A B           both non-empty files, byte for byte equal
#   different_files A B     both non-empty files, not equal
# Comparisons insist that each side is real: two commands that both failed
# print the same nothing, and two missing or empty files compare equal.

daemon_pids=()
daemon=
port=
http_port=
metrics_port=
daemon_log=
daemon_starts=0
: "${passes:=0}" "${failures:=0}"

#   port=$(wait_port_file PID FILE [KEY])
# prints the port under KEY (grpc unless given) once the daemon PID has
# written FILE, and fails if the daemon exits first or within 60 s does not.
wait_port_file() {
  local pid=$1 file=$2 key=${3:-grpc}
  for _ in $(seq 600); do
    if [ -s "$file" ]; then
      python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))[sys.argv[2]])' "$file" "$key"
      return
    fi
    kill -0 "$pid" 2>/dev/null || return 1
    sleep 0.1
  done
  return 1
}

# The port under KEY in a port file, or nothing if it has none.
port_in() {
  python3 -c 'import json, sys; print(json.load(open(sys.argv[1])).get(sys.argv[2], ""))' "$1" "$2"
}

daemon_start() {
  local bin=$1 work=$2
  shift 2
  daemon_starts=$((daemon_starts + 1))
  # One file per start: a restarted daemon's file is never mistaken for the
  # last one's.
  local ports="$work/ports.$daemon_starts"
  daemon_log=$work/daemon.log
  "$bin/geodesicd" serve --listen 127.0.0.1:0 --port-file "$ports" "$@" 2>>"$daemon_log" &
  daemon=$!
  daemon_pids+=("$daemon")
  if ! port=$(wait_port_file "$daemon" "$ports"); then
    echo "geodesicd did not start"
    cat "$daemon_log"
    return 1
  fi
  http_port=$(port_in "$ports" http)
  metrics_port=$(port_in "$ports" metrics)
}

# A stopped daemon's pid is forgotten: the system may give it to another
# process, which cleanup must not signal.
daemon_forget() {
  local pid kept=()
  for pid in "${daemon_pids[@]}"; do [ "$pid" = "$1" ] || kept+=("$pid"); done
  daemon_pids=("${kept[@]}")
}

daemon_stop() {
  local pid=${1:-$daemon}
  [ -n "$pid" ] || return 0
  kill -TERM "$pid" 2>/dev/null
  for _ in $(seq 300); do
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.1
  done
  kill -9 "$pid" 2>/dev/null
  wait "$pid" 2>/dev/null
  daemon_forget "$pid"
}

daemon_kill() {
  local pid=${1:-$daemon}
  [ -n "$pid" ] || return 0
  kill -9 "$pid" 2>/dev/null
  wait "$pid" 2>/dev/null
  daemon_forget "$pid"
}

daemon_cleanup() {
  local pid
  for pid in "${daemon_pids[@]}"; do daemon_stop "$pid"; done
}

daemon_fail() {
  echo "$1"
  [ -n "$daemon_log" ] && cat "$daemon_log"
  exit 1
}

retry_for() {
  local until=$((SECONDS + $1))
  shift
  until "$@"; do
    [ "$SECONDS" -lt "$until" ] || return 1
    sleep 0.1
  done
}

check() {
  local name=$1
  shift
  if "$@"; then
    passes=$((passes + 1))
    echo "ok   $name"
  else
    failures=$((failures + 1))
    echo "FAIL $name"
  fi
}

json() { python3 -c "import json,sys; d=json.load(sys.stdin); print($1)"; }
quietly() { "$@" >/dev/null 2>&1; }

is_number() { [[ $1 =~ ^-?[0-9]+(\.[0-9]*)?([eE][-+]?[0-9]+)?$ ]]; }

same_number() {
  is_number "$1" || { echo "     not a number: '$1'"; return 1; }
  is_number "$2" || { echo "     not a number: '$2'"; return 1; }
  [ "$1" = "$2" ] || { echo "     $1 != $2"; return 1; }
}

same_file() {
  [ -s "$1" ] || { echo "     missing or empty: $1"; return 1; }
  [ -s "$2" ] || { echo "     missing or empty: $2"; return 1; }
  cmp -s "$1" "$2"
}

different_files() {
  [ -s "$1" ] || { echo "     missing or empty: $1"; return 1; }
  [ -s "$2" ] || { echo "     missing or empty: $2"; return 1; }
  ! cmp -s "$1" "$2"
}
