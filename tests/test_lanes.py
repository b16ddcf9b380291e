"""tools/lanes.py: pieces queued over lanes, each single-threaded, failures reported."""

from __future__ import annotations

import json
import os
import subprocess
import sys

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "tools", "lanes.py")
# Each piece writes its value, its XLA flags and the cores it may run on, then exits with
# status 3 for the value "bad".
PIECE = ("import os, sys; v = sys.argv[1]; "
         "open(os.path.join(sys.argv[2], v), 'w').write(os.environ['XLA_FLAGS'] + '|' + "
         "str(sorted(os.sched_getaffinity(0)))); sys.exit(3 if v == 'bad' else 0)")  # fmt: skip


def lanes(tmp_path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, SCRIPT, "--logs", str(tmp_path / "logs"), *args],
                          capture_output=True, text=True, timeout=60)  # fmt: skip


def test_every_value_runs_once_single_threaded_and_pinned(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    r = lanes(tmp_path, "--lanes", "1", "--values", "a", "b", "c", "--",
              sys.executable, "-c", PIECE, "{}", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert sorted(os.listdir(out)) == ["a", "b", "c"]
    assert sorted(os.listdir(tmp_path / "logs")) == ["a.log", "b.log", "c.log"]
    flags, cores = (out / "a").read_text().split("|")
    assert "intra_op_parallelism_threads=1" in flags
    if os.path.exists("/usr/bin/taskset"):
        assert cores == "[0]"  # lane 0 on core 0
    assert "3 of 3 pieces ended well" in r.stdout


def test_a_failed_piece_is_named_and_the_others_still_run(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    r = lanes(tmp_path, "--lanes", "1", "--values", "bad", "good", "--",
              sys.executable, "-c", PIECE, "{}", str(out))  # fmt: skip
    assert r.returncode == 1
    assert sorted(os.listdir(out)) == ["bad", "good"]
    assert "failed: bad" in r.stdout


def test_a_value_of_several_words_becomes_several_arguments(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    piece = ("import json, sys; open(sys.argv[-1] + '/' + sys.argv[1], 'w')"
             ".write(json.dumps(sys.argv[1:-1]))")  # fmt: skip
    r = lanes(tmp_path, "--lanes", "1", "--values", "a --sizes 20 1", "b", "--",
              sys.executable, "-c", piece, "{}", str(out))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "a").read_text()) == ["a", "--sizes", "20", "1"]
    assert json.loads((out / "b").read_text()) == ["b"]
    assert sorted(os.listdir(tmp_path / "logs")) == ["a_sizes_20_1.log", "b.log"]


def test_bad_input_exits_2_with_one_line(tmp_path):
    for args in (["--values", "0", "--", "echo", "no placeholder"],
                 ["--values", "0", "echo", "{}"],
                 ["--lanes", "999", "--values", "0", "--", "echo", "{}"],
                 ["--values", "0", "0", "--", "echo", "{}"],
                 ["--values", "a b", "a_b", "--", "echo", "{}"],
                 ["--values", 'a "b', "--", "echo", "{}"]):  # fmt: skip
        r = lanes(tmp_path, *args)
        assert r.returncode == 2, args
        assert r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
