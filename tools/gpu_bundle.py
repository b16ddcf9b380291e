"""Packs the wheels a lent GPU machine lacks, so that a device call runs the project offline.

    python tools/gpu_bundle.py [--out .gpu_bundle] [--python 3.12]

The lent machine (``../.library/device``) has its own Python 3.12 with a CUDA jax, flax, optax,
orbax-checkpoint, numpy, scipy and matplotlib, reaches no package index, and takes what a call
carries. This writes to ``--out`` (git-ignored) the wheels of what its image lacks, at the
versions installed here (the pinned set the tests ran), built for ``--python`` on x86-64 Linux,
and minatt-jax's own wheel from this working tree. The list was found by installing those wheels
with ``--no-deps`` into a fresh environment holding only the image's packages and training a smoke
MB-MPO population: brax also wants jaxopt, mujoco its compiled core, mujoco-mjx trimesh. A device
call then carries the folder and installs it first, e.g.

    run(carry=[".gpu_bundle"], command="python3 -m pip install -q --no-deps --no-index
        .gpu_bundle/*.whl && PYTHONUNBUFFERED=1 python3 experiments/reading_study.py ...")

Rebuild it after changing the code: the project's wheel is a copy of the tree as it was.
"""

from __future__ import annotations

import argparse
import glob
import os
import subprocess
import sys
from importlib import metadata

# What the lent machine's image lacks (its package list: ../.library/device/KINDS.md).
MISSING = ("brax", "mujoco", "mujoco-core", "mujoco-mjx", "gymnasium", "tensorboardX", "trimesh",
           "jaxopt")  # fmt: skip
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64")
CARRY_LIMIT = 64 * 2**20  # what one device call carries, the working tree included


def fail(message: str) -> None:
    print(f"gpu_bundle.py: {message}", file=sys.stderr)
    raise SystemExit(2)


def pinned() -> list[str]:
    """``name==version`` of each missing package, at the version installed here."""
    out = []
    for name in MISSING:
        try:
            out.append(f"{name}=={metadata.version(name)}")
        except metadata.PackageNotFoundError:
            fail(f"{name} is not installed here: install the project first (pip install -e .)")
    return out


def download_command(requirements: list[str], out: str, python: str) -> list[str]:
    """pip's command that fetches ``requirements`` as wheels for ``python`` on x86-64 Linux."""
    platforms = [a for p in PLATFORMS for a in ("--platform", p)]
    return [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
            "--python-version", python, *platforms, "-d", out, *requirements]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=".gpu_bundle")
    parser.add_argument("--python", default="3.12", help="the lent machine's Python version")
    args = parser.parse_args()
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    requirements = pinned()
    os.makedirs(args.out, exist_ok=True)
    for old in glob.glob(os.path.join(args.out, "*.whl")):  # wheels of an earlier bundle only
        os.remove(old)
    build = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", args.out, root]
    for command in (download_command(requirements, args.out, args.python), build):
        if subprocess.run(command).returncode != 0:
            fail(f"failed: {' '.join(command)}")
    wheels = sorted(glob.glob(os.path.join(args.out, "*.whl")))
    size = sum(os.path.getsize(w) for w in wheels)
    for w in wheels:
        print(f"{os.path.getsize(w) / 2**20:6.1f} MiB  {os.path.basename(w)}")
    print(f"{len(wheels)} wheels, {size / 2**20:.1f} MiB in {args.out} (a device call carries "
          f"{CARRY_LIMIT // 2**20} MiB with the working tree)")  # fmt: skip
    if size > CARRY_LIMIT:
        fail(f"{size / 2**20:.1f} MiB is more than a device call carries")


if __name__ == "__main__":
    main()
