#!/usr/bin/env bash
# Security: bearer-token authentication, TLS, and mutual TLS, with
# certificates generated here (openssl). Health checks stay open so that
# orchestrator probes need no secret.
# Usage: security_test.sh BUILD_BIN_DIR SOURCE_DIR
set -uo pipefail
bin=$1
src=$2
work=$(mktemp -d)
source "$(dirname "$0")/daemon.sh"
trap 'daemon_cleanup; rm -rf "$work"' EXIT
# The port file is written once the listener accepts connections; the
# client needs a token or TLS, so readiness is not probed with a call.
start_daemon() {
  daemon_start "$bin" "$work" --graph-dir "$work/graphs" --mesh-root "$src/data" \
    --log-level warning --default-epsilon 0.02 "$@" || exit 1
}
stop_daemon() { daemon_stop; }
cli() { timeout 60 "$bin/geodesic" --server "127.0.0.1:$port" --timeout 20 "$@"; }
fails_with() {  # fails_with CODE COMMAND...: the command fails and prints CODE
  local code=$1; shift
  ! "$@" >/dev/null 2>"$work/err" && grep -q "$code" "$work/err"
}
py_client() {  # py_client [TOKEN [CA CERT KEY]]: the Python client lists meshes
  /usr/bin/python3 - "$port" "$src" "$@" <<'PY'
import sys
sys.path.insert(0, f"{sys.argv[2]}/client/python")
from geodesic_client import Client
args = sys.argv[3:]
read = lambda path: open(path, "rb").read()
tls = dict(root_certificates=read(args[1]), certificate_chain=read(args[2]),
           private_key=read(args[3])) if len(args) > 1 else {}
with Client(f"127.0.0.1:{sys.argv[1]}", timeout=20, token=args[0] if args else None, **tls) as c:
    assert [m.name for m in c.meshes()] == ["spot"]
PY
}
health() {  # grpc.health.v1 Check over plaintext: prints SERVING or the error
  /usr/bin/python3 - "$port" <<'PY'
import grpc, sys
channel = grpc.insecure_channel(f"127.0.0.1:{sys.argv[1]}")
check = channel.unary_unary("/grpc.health.v1.Health/Check",
                            request_serializer=lambda m: m, response_deserializer=lambda m: m)
print("SERVING" if check(b"", timeout=10) == b"\x08\x01" else "NOT_SERVING")
PY
}

# Bearer token.
printf 's3cret-token\n' > "$work/token"
printf 'wrong-token' > "$work/wrong"
start_daemon --auth-token-file "$work/token"
check "no token: UNAUTHENTICATED" fails_with UNAUTHENTICATED cli meshes
check "wrong token: UNAUTHENTICATED" fails_with UNAUTHENTICATED cli --token-file "$work/wrong" meshes
check "right token (file): served" quietly cli --token-file "$work/token" meshes
# The queries below need the graph: wait until it is ready rather than race its build.
check "right token: graph ready" quietly cli --token-file "$work/token" --eps 0.02 graph --wait
check "right token (GEODESIC_TOKEN): served" quietly env GEODESIC_TOKEN=s3cret-token "$bin/geodesic" \
  --server "127.0.0.1:$port" --eps 0.02 distance --from v:1 --to v:2
check "health check needs no token" test "$(health)" = SERVING
check "Python client with the token: served" quietly py_client s3cret-token
check "Python client without it: refused" fails_with UNAUTHENTICATED py_client
stop_daemon

# Certificates: a CA, a server certificate for 127.0.0.1, a client
# certificate from the same CA, and one from a stranger's CA.
cd "$work" || exit 1
openssl_quiet() { openssl "$@" >/dev/null 2>&1; }
openssl_quiet req -x509 -newkey rsa:2048 -nodes -days 1 -subj /CN=test-ca -keyout ca.key -out ca.crt
openssl_quiet req -x509 -newkey rsa:2048 -nodes -days 1 -subj /CN=stranger -keyout other.key -out other.crt
openssl_quiet req -newkey rsa:2048 -nodes -subj /CN=127.0.0.1 -keyout server.key -out server.csr
printf 'subjectAltName=IP:127.0.0.1,DNS:localhost\n' > san.ext
openssl_quiet x509 -req -in server.csr -CA ca.crt -CAkey ca.key -CAcreateserial -days 1 \
  -extfile san.ext -out server.crt
openssl_quiet req -newkey rsa:2048 -nodes -subj /CN=client -keyout client.key -out client.csr
openssl_quiet x509 -req -in client.csr -CA ca.crt -CAkey ca.key -CAcreateserial -days 1 -out client.crt
cd - >/dev/null || exit 1
check "test certificates generated" test -s "$work/server.crt" -a -s "$work/client.crt"

# TLS.
start_daemon --tls-cert "$work/server.crt" --tls-key "$work/server.key"
check "TLS: client trusting the CA is served" quietly cli --tls-ca "$work/ca.crt" meshes
check "TLS: plaintext client is refused" fails_with UNAVAILABLE cli meshes
check "TLS: client trusting another CA is refused" fails_with UNAVAILABLE cli --tls-ca "$work/other.crt" meshes
stop_daemon

# Mutual TLS plus a token.
start_daemon --tls-cert "$work/server.crt" --tls-key "$work/server.key" \
  --tls-client-ca "$work/ca.crt" --auth-token-file "$work/token"
check "mTLS: client without a certificate is refused" \
  fails_with UNAVAILABLE cli --tls-ca "$work/ca.crt" --token-file "$work/token" meshes
check "mTLS: certificate from another CA is refused" fails_with UNAVAILABLE cli --tls-ca "$work/ca.crt" \
  --tls-cert "$work/other.crt" --tls-key "$work/other.key" --token-file "$work/token" meshes
check "mTLS: certificate without the token is UNAUTHENTICATED" fails_with UNAUTHENTICATED cli \
  --tls-ca "$work/ca.crt" --tls-cert "$work/client.crt" --tls-key "$work/client.key" meshes
mtls_cli() {
  cli --tls-ca "$work/ca.crt" --tls-cert "$work/client.crt" --tls-key "$work/client.key" \
    --token-file "$work/token" --eps 0.02 "$@"
}
check "mTLS: certificate and token are served" quietly mtls_cli graph --wait
check "mTLS: and answer queries" quietly mtls_cli distance --from v:1 --to v:2
check "mTLS: Python client with certificate and token is served" \
  quietly py_client s3cret-token "$work/ca.crt" "$work/client.crt" "$work/client.key"
stop_daemon

# Misconfiguration is refused at start, naming the flag.
timeout 60 "$bin/geodesicd" serve --listen 127.0.0.1:0 --tls-cert "$work/server.crt" 2>"$work/e1"
check "--tls-cert without --tls-key refused" grep -q "go together" "$work/e1"
timeout 60 "$bin/geodesicd" serve --listen 127.0.0.1:0 --tls-client-ca "$work/ca.crt" 2>"$work/e3"
check "--tls-client-ca without a server certificate refused" \
  grep -q "tls-client-ca needs --tls-cert" "$work/e3"
: > "$work/empty"
timeout 60 "$bin/geodesicd" serve --listen 127.0.0.1:0 --auth-token-file "$work/empty" 2>"$work/e2"
check "empty token file refused" grep -q "auth-token-file" "$work/e2"
exit $((failures > 0))
