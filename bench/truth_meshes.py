"""The shared meshes that have exact truth, where to find them, and how to
read their fields."""
import array
import os
import sys

# Every mesh of ../shared/meshes with exact fields in ../shared/truth,
# smallest first.
DEFAULT_MESHES = "eight,spot,blade_aniso,camelhead,fertility,bunny,armadillo,igea"


def mesh_path(shared, name):
    for ext in (".off", ".obj", ".ply"):
        p = os.path.join(shared, "meshes", name + ext)
        if os.path.exists(p):
            return p
    raise SystemExit(f"no mesh {name} in {shared}/meshes")


def read_f64(path):
    """A raw little-endian float64 field (../shared/truth's format)."""
    values = array.array("d")
    with open(path, "rb") as f:
        values.frombytes(f.read())
    if sys.byteorder != "little":
        values.byteswap()
    return values
