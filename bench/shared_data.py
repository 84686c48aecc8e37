"""Where the benchmarks find the shared meshes and exact truth: ../shared
beside the clone, or the directory GEODESIC_SHARED_DIR names (as the tests
read it)."""
import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.environ.get("GEODESIC_SHARED_DIR", os.path.join(os.path.dirname(ROOT), "shared"))
