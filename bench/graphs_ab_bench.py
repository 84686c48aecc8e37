#!/usr/bin/env python3
"""Two builds' graphs of one mesh side by side, queried by the same code:
each mesh built by --before and by --after in alternating rounds, then
fields and pairs on each graph file by --after's own `geodesicd field` and
`query_bench --local-graph`, so that what differs is the graph, not the
search. CGAL's heat solve (after its factorisation) in the same run gives
the field's yardstick.

  bench/graphs_ab_bench.py --before OLD/geodesicd --after build/bin/geodesicd \\
      [--meshes armadillo,bunny] [--eps 1e-3] [--rounds 5] [--pairs 2000] [--own-code]

With --own-code each side's fields are its own binary's, on its own graph:
the whole change, code and graph, as a user of each release sees it (pairs
are then left out, as query_bench is --after's alone).

Checks, before any timing counts, that both graphs give the same field to
the last bit from every source timed (a graph's fans change which edges a
search relaxes, never a distance). Prints a Markdown table for
BENCHMARKS.md: per mesh and graph, the median build seconds, mean fan, a
new process's field solve (ms and ns per vertex, median over sources and
rounds), its ratio to CGAL's heat solve, and the p50 of random vertex pairs
and face-point pairs with the edges each relaxes, then after/before ratios.
"""
import json
import os
import random
import statistics
import subprocess
import sys
import tempfile

from ab_args import before_after_parser
from shared_data import SHARED
from truth_meshes import mesh_path

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "build", "bin")


def run_json(args):
    result = subprocess.run(args, capture_output=True, text=True)
    if result.returncode != 0:
        sys.exit(f"{' '.join(args)} failed:\n{result.stderr}")
    return json.loads(result.stdout)


def build(binary, mesh, eps, out):
    return run_json([binary, "build", mesh, "--eps", str(eps), "--quiet", "--json", "--out", out])


def field(binary, mesh, graph, vertex, out):
    return run_json([binary, "field", "--mesh", mesh, "--graph", graph, "--source", f"v:{vertex}",
                     "--out", out, "--json"])


def pairs(mesh, graph, count, face_points):
    args = [os.path.join(BIN, "query_bench"), "--local", mesh, "--local-graph", graph,
            "--concurrency", "1", "--count", str(count), "--duration", "600", "--json"]
    return run_json(args + (["--face-points"] if face_points else []))


def heat_solve_seconds(mesh, vertex, tmp):
    peer = os.path.join(BIN, "cgal_peer")
    if not os.path.exists(peer):
        return None
    return run_json([peer, mesh, str(vertex), os.path.join(tmp, "cgal")])["heat_solve_seconds"]


def main():
    parser = before_after_parser(__doc__, rounds=5)
    parser.add_argument("--pairs", type=int, default=2000, help="pairs a round, of each kind")
    parser.add_argument("--own-code", action="store_true",
                        help="each side's fields by its own binary; no pairs")
    parser.add_argument("--sources", type=int, default=5, help="field sources a round")
    args = parser.parse_args()
    rng = random.Random(7)
    queried_by = ("fields by each side's own binary on its own graph, no pairs" if args.own_code
                  else "fields and pairs by --after's code on each graph")
    print(f"ε = {args.eps}, {args.rounds} alternating rounds; {queried_by}, one query at a "
          "time\n")
    print("| mesh | graph | build s | mean fan | field ms (new process) | ns / vertex "
          "| field / CGAL heat solve | vertex pairs p50 ms (relaxed) "
          "| face-point pairs p50 ms (relaxed) |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.meshes.split(","):
            mesh = mesh_path(SHARED, name)
            graphs = {side: os.path.join(tmp, f"{name}-{side}.dgg") for side in ("before", "after")}
            binaries = {"before": args.before, "after": args.after}
            stats = {side: {"build": [], "fan": 0, "field": [], "nspv": [], "vp": [], "vr": [],
                            "fp": [], "fr": []} for side in graphs}
            vertices = None
            for r in range(args.rounds):
                order = ["before", "after"] if r % 2 == 0 else ["after", "before"]
                for side in order:
                    b = build(binaries[side], mesh, args.eps, graphs[side])
                    stats[side]["build"].append(b["build_seconds"])
                    stats[side]["fan"] = b["average_fan"]
                    vertices = b["vertices"]
                sources = [rng.randrange(vertices) for _ in range(args.sources)]
                for s in sources:
                    fields = {}
                    for side in order:
                        out = os.path.join(tmp, f"{side}.f64")
                        f = field(binaries[side] if args.own_code else args.after, mesh,
                                  graphs[side], s, out)
                        stats[side]["field"].append(f["solve_seconds"] * 1e3)
                        stats[side]["nspv"].append(f["ns_per_vertex"])
                        with open(out, "rb") as data:
                            fields[side] = data.read()
                    if not fields["before"] or fields["before"] != fields["after"]:
                        sys.exit(f"{name}: the two graphs' fields from vertex {s} differ")
                for side in [] if args.own_code else order:
                    for face, p, rel in ((False, "vp", "vr"), (True, "fp", "fr")):
                        q = pairs(mesh, graphs[side], args.pairs, face)
                        if q["failed"] or q["queries"] != args.pairs:
                            sys.exit(f"{name}: {q['failed']} of {q['queries']} pairs failed")
                        stats[side][p].append(q["p50_ms"])
                        stats[side][rel].append(q["edges_relaxed_per_query"])
            heat = heat_solve_seconds(mesh, 0, tmp)
            med = {side: {k: (statistics.median(v) if v else float("nan"))
                          if isinstance(v, list) else v
                          for k, v in st.items()} for side, st in stats.items()}
            def pairs_cell(p50, relaxed, p50_digits, relaxed_digits):
                if args.own_code:
                    return "-"
                return f"{p50:.{p50_digits}f} ({relaxed:.{relaxed_digits}f})"
            for side in ("before", "after"):
                m = med[side]
                ratio = f"{m['field'] / (heat * 1e3):.2f}x" if heat else "n/a"
                print(f"| {name} | {side} | {m['build']:.2f} | {m['fan']:.2f} | {m['field']:.2f} "
                      f"| {m['nspv']:.0f} | {ratio} | {pairs_cell(m['vp'], m['vr'], 3, 0)} "
                      f"| {pairs_cell(m['fp'], m['fr'], 3, 0)} |")
            b, a = med["before"], med["after"]
            print(f"| {name} | after / before | {a['build'] / b['build']:.2f} | "
                  f"{a['fan'] / b['fan']:.2f} | {a['field'] / b['field']:.2f} | "
                  f"{a['nspv'] / b['nspv']:.2f} | "
                  f"| {pairs_cell(a['vp'] / b['vp'], a['vr'] / b['vr'], 2, 2)} "
                  f"| {pairs_cell(a['fp'] / b['fp'], a['fr'] / b['fr'], 2, 2)} |")
            sys.stdout.flush()
            if heat:
                print(f"\n{name}: CGAL heat solve {heat * 1e3:.1f} ms (after factorisation)\n",
                      file=sys.stderr)


if __name__ == "__main__":
    main()
