#!/usr/bin/python3
"""The Python client's modules keep a shape a reader can follow.

- No import cycle between the package's modules, counting every import in a
  module: at its top, inside functions, and under `if TYPE_CHECKING:` (a cycle
  hidden from the interpreter that way is still one for the reader).
- No module over MAX_MODULE_LINES lines.

The generated gRPC stubs (_proto/, git-ignored) are not the package's own code.

Usage: python_imports_test.py SOURCE_DIR
"""
import ast
import os
import sys

PACKAGE = "geodesic_client"
MAX_MODULE_LINES = 400
SKIPPED_PARTS = {"_proto", "__pycache__"}


def modules(package_dir):
    """{dotted module name: path} of the package's own modules."""
    found = {}
    for dirpath, dirnames, filenames in os.walk(package_dir):
        dirnames[:] = sorted(d for d in dirnames if d not in SKIPPED_PARTS)
        for name in sorted(filenames):
            if not name.endswith(".py"):
                continue
            rel = os.path.relpath(os.path.join(dirpath, name), os.path.dirname(package_dir))
            parts = rel[:-len(".py")].split(os.sep)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = os.path.join(dirpath, name)
    return found


def imported(module, path, known):
    """The package's modules that `module` imports, wherever the import statement is."""
    is_package = path.endswith("__init__.py")
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read(), filename=path)
    targets = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                # The package a relative import starts from.
                base = module.split(".")
                base = base[:len(base) - node.level + (1 if is_package else 0)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            # `from X import Y` imports X.Y when that is a module, else takes Y from X.
            names = [f"{stem}.{alias.name}" if f"{stem}.{alias.name}" in known else stem
                     for alias in node.names]
        else:
            continue
        # Only what a statement names: the parent packages Python imports on
        # the way are implicit, or every module would close a cycle with __init__.
        targets.update(name for name in names if name in known)
    targets.discard(module)
    return targets


def find_cycle(graph):
    """One import cycle as a list of modules (first == last), or None."""
    state = {}  # module -> 1 on the current path, 2 done

    def visit(node, path):
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state:
                cycle = visit(nxt, path)
                if cycle:
                    return cycle
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state:
            cycle = visit(start, [])
            if cycle:
                return cycle
    return None


def main():
    root = sys.argv[1]
    package_dir = os.path.join(root, "client", "python", PACKAGE)
    found = modules(package_dir)
    problems = []
    if len(found) < 2:
        problems.append(f"no modules found under {package_dir}")
    graph = {m: imported(m, p, found) for m, p in found.items()}
    # The package's __init__ imports its modules to re-export them, so a module
    # that imports the package itself (from . import X, X not a module) closes a cycle.
    cycle = find_cycle(graph)
    if cycle:
        problems.append("import cycle: " + " -> ".join(cycle))
    for module, path in sorted(found.items()):
        with open(path, encoding="utf-8") as f:
            lines = sum(1 for _ in f)
        if lines > MAX_MODULE_LINES:
            problems.append(f"{os.path.relpath(path, root)} is {lines} lines "
                            f"(at most {MAX_MODULE_LINES})")
    for problem in problems:
        print("FAIL", problem)
    edges = sum(len(t) for t in graph.values())
    print(f"{len(found)} modules, {edges} imports between them checked")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
