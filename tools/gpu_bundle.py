"""Packs the wheels a GPU machine without a package index lacks, for an offline install.

    python tools/gpu_bundle.py [--out .gpu_bundle] [--python 3.12] [--limit-mib 64]

For a GPU host that already has a CUDA jax, flax, optax, orbax-checkpoint, numpy, scipy and
matplotlib but reaches no package index. This writes to ``--out`` (git-ignored) the wheels of
what such a host lacks, at the versions installed here (the pinned set the tests ran), built for
``--python`` on x86-64 Linux, and minatt-jax's own wheel from this working tree. The list was
found by installing those wheels with ``--no-deps`` into a fresh environment holding only those
packages and training a smoke MB-MPO population: brax also wants jaxopt, mujoco its compiled
core, mujoco-mjx trimesh. On the GPU host:

    python3 -m pip install -q --no-deps --no-index .gpu_bundle/*.whl

Rebuild it after changing the code: the project's wheel is a copy of the tree as it was.
``--limit-mib`` fails the build when the bundle outgrows what a transfer allows.
"""

from __future__ import annotations

import argparse
import glob
import os
import subprocess
import sys
from importlib import metadata

# What a host with a CUDA jax stack (jax, flax, optax, orbax-checkpoint, numpy, scipy,
# matplotlib) lacks.
MISSING = ("brax", "mujoco", "mujoco-core", "mujoco-mjx", "gymnasium", "tensorboardX", "trimesh",
           "jaxopt")  # fmt: skip
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64")


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
    parser.add_argument("--python", default="3.12", help="the GPU host's Python version")
    parser.add_argument("--limit-mib", type=float, default=64.0,
                        help="fail when the wheels exceed this size (MiB)")  # fmt: skip
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
    print(f"{len(wheels)} wheels, {size / 2**20:.1f} MiB in {args.out}")
    if size > args.limit_mib * 2**20:
        fail(f"{size / 2**20:.1f} MiB is more than --limit-mib {args.limit_mib:g}")


if __name__ == "__main__":
    main()
