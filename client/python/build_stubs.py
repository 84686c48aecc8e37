"""Generates geodesic_client's gRPC stubs from proto/geodesic/v1/geodesic.proto.

Used at install time by setup.py and by the CMake build (target
geodesic_python_stubs), so that both produce the same files. It runs Debian's
protoc and grpc_python_plugin (packages protobuf-compiler and
protobuf-compiler-grpc), or those named by $PROTOC and $GRPC_PYTHON_PLUGIN.

Usage: build_stubs.py PROTO_ROOT OUT_DIR [--protoc PATH] [--plugin PATH]
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

PROTO = os.path.join("geodesic", "v1", "geodesic.proto")
OUTPUTS = ("geodesic_pb2.py", "geodesic_pb2_grpc.py")


class StubError(RuntimeError):
    pass


def _tool(given, env, name, package):
    path = given or os.environ.get(env) or shutil.which(name)
    if not path:
        raise StubError(
            f"{name} not found on PATH: geodesic_client generates its gRPC stubs at install "
            f"time. Install Debian's {package} (apt-get install protobuf-compiler "
            f"protobuf-compiler-grpc) or set ${env} to the program.")
    return path


def generate(proto_root, out_dir, protoc=None, plugin=None):
    """Writes OUTPUTS and __init__.py into out_dir (a package beside geodesic_client)."""
    source = os.path.join(proto_root, PROTO)
    if not os.path.isfile(source):
        raise StubError(f"{source} not found: cannot generate the gRPC stubs")
    protoc = _tool(protoc, "PROTOC", "protoc", "protobuf-compiler")
    plugin = _tool(plugin, "GRPC_PYTHON_PLUGIN", "grpc_python_plugin", "protobuf-compiler-grpc")
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [protoc, f"--proto_path={proto_root}", f"--python_out={tmp}",
               f"--grpc_python_out={tmp}", f"--plugin=protoc-gen-grpc_python={plugin}", source]
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode != 0:
            raise StubError(f"{' '.join(cmd)} failed:\n{run.stderr}")
        os.makedirs(out_dir, exist_ok=True)
        for name in OUTPUTS:
            with open(os.path.join(tmp, "geodesic", "v1", name)) as f:
                text = f.read()
            # The stubs live inside geodesic_client rather than as a top-level
            # "geodesic" package, which could clash with a user's own module.
            text = re.sub(r"^from geodesic\.v1 import ", "from . import ", text, flags=re.M)
            with open(os.path.join(out_dir, name), "w") as f:
                f.write(text)
    with open(os.path.join(out_dir, "__init__.py"), "w") as f:
        proto = PROTO.replace(os.sep, "/")
        f.write(f'"""gRPC stubs generated from {proto} by build_stubs.py."""\n')


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("proto_root")
    parser.add_argument("out_dir")
    parser.add_argument("--protoc")
    parser.add_argument("--plugin")
    args = parser.parse_args()
    try:
        generate(args.proto_root, args.out_dir, args.protoc, args.plugin)
    except StubError as e:
        sys.exit(f"build_stubs: {e}")


if __name__ == "__main__":
    main()
