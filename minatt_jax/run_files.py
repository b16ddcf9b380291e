"""The files of a run directory: ``config.json``, ``metrics.jsonl``, and how they are written.

Everything is written atomically (a uniquely named temporary file, fsync, rename), so a crash or a
second process never leaves half a file.
"""

from __future__ import annotations

import io
import json
import os
import tempfile
from typing import Any

import numpy as np

from minatt_jax.config import TrainConfig, resolve


class RunError(Exception):
    """A problem with the run directory (a user-facing error); the CLI exits with
    ``exit_status``."""

    exit_status = 2


class DivergedError(RunError):
    """Training went non-finite; the last good checkpoint is kept."""

    exit_status = 3


class StoppedError(RunError):
    """Training stopped by SIGINT or SIGTERM after checkpointing (exit 130 or 143)."""

    def __init__(self, message: str, exit_status: int) -> None:
        super().__init__(message)
        self.exit_status = exit_status


def file_mode() -> int:
    """The mode a plain ``open`` would give a new file (0o666 less the umask): temporary files
    are made 0600, and a result file renamed from one must not stay private to its writer."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def write_bytes_atomic(path: str, data: bytes) -> None:
    """Writes bytes through a uniquely named temporary file and a rename: never half a file,
    even with several processes writing the same path."""
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=directory, suffix=".tmp")
    try:
        os.fchmod(fd, file_mode())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_npz_atomic(path: str, arrays: dict[str, Any]) -> None:
    """Writes arrays as an ``.npz`` atomically (see ``write_bytes_atomic``)."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    write_bytes_atomic(path, buffer.getvalue())


def write_text_atomic(path: str, text: str) -> None:
    """Writes text atomically (see ``write_bytes_atomic``)."""
    write_bytes_atomic(path, text.encode())


def write_json_atomic(path: str, obj: Any) -> None:
    """Writes JSON atomically (see ``write_text_atomic``)."""
    write_text_atomic(path, json.dumps(obj, indent=2))


def read_metrics(run_dir: str) -> list[dict[str, Any]]:
    """The records of ``metrics.jsonl`` (an unfinished last line is ignored). RunError, naming
    the file and line, when it cannot be read or a finished line is not a JSON record."""
    path = os.path.join(run_dir, "metrics.jsonl")
    if not os.path.exists(path):
        return []
    try:
        with open(path) as f:
            lines = f.readlines()
    except (OSError, UnicodeDecodeError) as e:
        why = e.strerror if isinstance(e, OSError) else str(e)
        raise RunError(f"cannot read {path}: {why}") from None
    records = []
    for number, line in enumerate(lines, 1):
        if not line.endswith("\n"):
            continue
        try:
            record = json.loads(line)
        except ValueError as e:
            raise RunError(f"{path} line {number} is not a JSON record ({e})") from None
        if not isinstance(record, dict) or "step" not in record:
            raise RunError(f"{path} line {number} is not a metrics record (no step)")
        records.append(record)
    return records


RESULT_FILES = ("config.json", "metrics.jsonl")  # and meta_test/*.json
# What a run directory holds of its own: an output written by a command never lands on these.
RUN_OWN = (*RESULT_FILES, ".lock", "checkpoints", "checkpoints_ahead", "policy_snapshots",
           "meta_test", "tensorboard")  # fmt: skip


def check_not_run_file(run_dir: str, out: str, example: str = "policy.npz") -> None:
    """RunError when ``out`` is one of ``run_dir``'s own files or inside its own folders
    (``RUN_OWN``): an export or a report written there would leave the run unusable. Other
    names inside the run directory (``RUN/policy.npz``, ``RUN/report``) are allowed; the
    message suggests ``RUN/<example>``."""
    run = os.path.realpath(run_dir)
    target = os.path.realpath(out)
    relative = os.path.relpath(target, run)
    if relative == "." or relative.split(os.sep)[0] in RUN_OWN:
        raise RunError(
            f"{out} is the run's own {'directory' if relative == '.' else 'file'} "
            f"({relative}); write the output elsewhere, e.g. {os.path.join(run_dir, example)}"
        )


def copy_results(run_dir: str, target: str) -> None:
    """Copies what a run's tables are made of (``config.json``, ``metrics.jsonl`` and
    ``meta_test/*.json``), each atomically, to ``target``: a record small enough to keep in git
    where the run itself is not kept. Checkpoints and policy snapshots stay behind, so a record
    is tabulated, not resumed or analyzed."""
    tests = os.path.join(run_dir, "meta_test")
    names = [*RESULT_FILES, *(os.path.join("meta_test", f) for f in
                             sorted(os.listdir(tests) if os.path.isdir(tests) else [])
                             if f.endswith(".json"))]  # fmt: skip
    for name in names:
        with open(os.path.join(run_dir, name), "rb") as f:
            write_bytes_atomic(os.path.join(target, name), f.read())


def read_config_json(run_dir: str) -> dict[str, Any]:
    """A run directory's ``config.json`` as stored (no agent is looked up: ``inspect`` reads
    any run with it); RunError when there is none or it is not JSON."""
    check_run_dir(run_dir)
    path = os.path.join(run_dir, "config.json")
    try:
        with open(path) as f:
            stored = json.load(f)
    except (OSError, json.JSONDecodeError) as e:
        raise RunError(f"{path} is not readable JSON ({e})") from None
    if not isinstance(stored, dict) or "algo" not in stored:
        raise RunError(f"{path} is not a minatt-jax configuration")
    return stored


def check_run_dir(run_dir: str) -> None:
    """RunError unless ``run_dir`` is a directory holding a config.json."""
    if os.path.exists(run_dir) and not os.path.isdir(run_dir):
        raise RunError(f"{run_dir} is a file, not a run directory")
    if not os.path.isdir(run_dir):
        raise RunError(f"run directory {run_dir} does not exist")
    if not os.path.exists(os.path.join(run_dir, "config.json")):
        present = set(os.listdir(run_dir))
        if {"tensorboard", ".lock"} & present and not {"checkpoints", "metrics.jsonl"} & present:
            raise RunError(f"{run_dir} has no config.json and nothing trained: its run stopped "
                           "before it wrote its settings; run the original command again "
                           "(without --resume)")  # fmt: skip
        raise RunError(f"{run_dir} has no config.json: not a minatt-jax run directory")


def load_config(run_dir: str) -> TrainConfig:
    """The (resolved) configuration a run directory was made with (its agent looked up: a
    plugin's module as ``config.json`` records it)."""
    check_run_dir(run_dir)
    from minatt_jax.agents.registry import PluginError, UnknownAgentError

    path = os.path.join(run_dir, "config.json")
    try:
        with open(path) as f:
            return resolve(TrainConfig.from_dict(json.load(f)))
    except (UnknownAgentError, PluginError) as e:
        raise RunError(f"{run_dir}: {e}") from None
    except (json.JSONDecodeError, TypeError, KeyError, ValueError) as e:
        raise RunError(f"{path} is corrupt or from an incompatible version ({e})") from None
