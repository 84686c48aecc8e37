"""Build hook: the gRPC stubs are generated from proto/ when the package is built.

The metadata lives in pyproject.toml. In a clone the proto is read from the
repository's proto/ directory; an sdist carries its own copy.
"""
import os
import shutil
import sys

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import build_stubs  # noqa: E402


def proto_root():
    for root in (os.path.join(HERE, "proto"), os.path.join(HERE, "..", "..", "proto")):
        if os.path.isfile(os.path.join(root, build_stubs.PROTO)):
            return root
    sys.exit(f"geodesic_client: {build_stubs.PROTO} not found in {HERE}/proto or the "
             "repository's proto/: build from a full clone of geodesicd or from its sdist")


class BuildPyWithStubs(build_py):
    def run(self):
        super().run()
        package = (os.path.join(HERE, "geodesic_client") if getattr(self, "editable_mode", False)
                   else os.path.join(self.build_lib, "geodesic_client"))
        try:
            build_stubs.generate(proto_root(), os.path.join(package, "_proto"))
        except build_stubs.StubError as e:
            sys.exit(f"geodesic_client: {e}")


class SdistWithProto(sdist):
    def make_release_tree(self, base_dir, files):
        super().make_release_tree(base_dir, files)
        target = os.path.join(base_dir, "proto", build_stubs.PROTO)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        shutil.copyfile(os.path.join(proto_root(), build_stubs.PROTO), target)


setup(cmdclass={"build_py": BuildPyWithStubs, "sdist": SdistWithProto})
