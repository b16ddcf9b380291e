"""Ctrl-C and SIGTERM at any moment: every command ends with exit 130 / 143 and one line, no
traceback, no crash (SIGSEGV) while XLA compiles, and the run directory it read stays intact.

Each case starts the console command in a subprocess and sends the signal after a delay that
lands in its imports, its compilation or its work (the delays are moments, not guarantees: the
assertions hold whichever phase the signal meets)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from conftest import digest, untrained_run

from minatt_jax import run_files
from minatt_jax.config import PRESETS, resolve, with_overrides

CONFIG = resolve(with_overrides(PRESETS["smoke"], total_steps=300))
STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A run directory (config, a checkpoint at step 300, a policy snapshot) made without
    training."""
    run = str(tmp_path_factory.mktemp("signals") / "run")
    untrained_run(run, CONFIG, 300)
    return run


# (command, signal, seconds after start): imports take about 3 s, compilation follows.
CASES = [
    (["rollout", "--env", "hopper", "--steps", "200000"], signal.SIGINT, 0.3),
    (["rollout", "--env", "hopper", "--steps", "200000"], signal.SIGTERM, 8.0),
    (["evaluate", "{RUN}", "--episodes", "400"], signal.SIGTERM, 6.0),
    (["meta-test", "{RUN}", "--variant", "mass", "--out", "{TMP}/mt"], signal.SIGINT, 7.0),
    (["analyze", "{RUN}", "--out", "{TMP}/report"], signal.SIGTERM, 9.0),
    (
        ["train", "--preset", "smoke", "--steps", "30000", "--out", "{TMP}/train"],
        signal.SIGINT,
        5.0,
    ),
]


@pytest.mark.parametrize("argv, signum, delay", CASES,
                         ids=[f"{a[0]}-{s.name}-{d:g}s" for a, s, d in CASES])  # fmt: skip
def test_a_signal_ends_a_command_with_one_line(run_dir, tmp_path, argv, signum, delay):
    argv = [a.format(RUN=run_dir, TMP=str(tmp_path)) for a in argv]
    before = digest(run_dir)
    proc = subprocess.Popen([sys.executable, "-m", "minatt_jax.cli", *argv],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    time.sleep(delay)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=300)
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == STATUS[signum], (proc.returncode, err)
    if argv[0] == "train" and len(lines) == 2:  # training acknowledges, then stops at a chunk
        assert lines[0].startswith(f"minatt-jax: {signum.name} received: stopping after"), err
        lines = lines[1:]
    assert len(lines) == 1 and lines[0].startswith("minatt-jax: "), err
    assert "Traceback" not in err
    assert digest(run_dir) == before
    train_dir = os.path.join(str(tmp_path), "train")
    if argv[0] == "train" and os.path.exists(os.path.join(train_dir, "config.json")):
        run_files.load_config(train_dir)  # what a stop leaves is readable
        run_files.read_metrics(train_dir)
