"""The command line two-binary comparisons share (pairs_ab_bench.py,
build_ab_bench.py): the binaries before and after a change, the meshes, eps
and the number of alternating rounds."""
import argparse


def before_after_parser(doc, rounds):
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--before", required=True, help="geodesicd built before the change")
    parser.add_argument("--after", required=True, help="geodesicd built after the change")
    parser.add_argument("--meshes", default="armadillo,bunny",
                        help="comma-separated names in ../shared/meshes")
    parser.add_argument("--eps", type=float, default=1e-3)
    parser.add_argument("--rounds", type=int, default=rounds)
    return parser
