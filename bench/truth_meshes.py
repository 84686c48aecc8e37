"""The shared meshes that have exact truth, and where to find them."""
import os

# Every mesh of ../shared/meshes with exact fields in ../shared/truth,
# smallest first.
DEFAULT_MESHES = "eight,spot,blade_aniso,camelhead,fertility,bunny,armadillo,igea"


def mesh_path(shared, name):
    for ext in (".off", ".obj", ".ply"):
        p = os.path.join(shared, "meshes", name + ext)
        if os.path.exists(p):
            return p
    raise SystemExit(f"no mesh {name} in {shared}/meshes")
