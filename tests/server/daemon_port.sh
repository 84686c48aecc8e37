# Sourced by the shell tests. Daemons listen on 127.0.0.1:0 and write the
# ports they bound to --port-file; racing other tests for a port found free a
# moment earlier made them flaky.
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
