"""Pickle core scenes (gzip) for a machine without Blender: the GPU benchmarks and the mask
digests read ``NAME.pkl.gz`` where a scene argument is expected.

    .venv/bin/python -m tools.pickle_scenes --output-dir gpu/scenes forest clusters "city:blocks=4"

A pickle is read by the same tree (or one whose scene classes keep their names and fields).
"""
from __future__ import annotations

import argparse
import gzip
import pickle
import re
import sys
from pathlib import Path


def pickle_name(spec: str) -> str:
    """A file name for scene argument ``spec`` (``city:blocks=4`` -> ``city_blocks_4.pkl.gz``)."""
    return re.sub(r"[^A-Za-z0-9]+", "_", spec).strip("_") + ".pkl.gz"


def load_pickled(path) -> object:
    with gzip.open(path, "rb") as fh:
        return pickle.load(fh)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--output-dir", required=True, type=Path)
    ap.add_argument("scenes", nargs="+")
    a = ap.parse_args(argv)
    from hybrid_shadow_addon.blender.load import load_scene

    a.output_dir.mkdir(parents=True, exist_ok=True)
    for spec in a.scenes:
        path = a.output_dir / pickle_name(spec)
        with gzip.open(path, "wb", compresslevel=6) as fh:
            pickle.dump(load_scene(spec), fh, protocol=4)
        print(f"{spec} -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
