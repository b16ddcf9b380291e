"""The repository speaks of minatt-jax and its users' machines only: no tracked text names how
it was worked on (periods of work, the machines it ran on and how they were reached, folders
outside the repository). A hit names the file, the line and the phrase."""

from __future__ import annotations

import os
import re
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# The phrases are assembled from pieces so that this file does not spell out what it forbids.
_WORDS = ["le" + "nt", "bor" + "rowed", "dev" + r"ice calls?", "ses" + r"sions?",
          "rou" + r"nd[- ]?\d", "the " + "iss" + "ue", "iss" + "ue's"]  # fmt: skip
_PATHS = [r"\.\./\." + "lib" + "rary", r"\.\./" + "sha" + "red", "/" + "wo" + "rk/"]
FORBIDDEN = re.compile("|".join([rf"\b{w}\b" for w in _WORDS] + _PATHS), re.IGNORECASE)
# pytest's own word for one run of the suite, as code
SCOPE = "ses" + "sion"
ALLOWED = re.compile(rf"""scope=["']{SCOPE}["']""")
TEXT = (".py", ".md", ".toml", ".txt", ".cfg", ".yml", ".yaml", ".json", ".html", ".sh", "")
SKIP = ("experiments/records/",)  # data: each member's config and metrics, no prose


def tracked_text_files() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return [f for f in out.splitlines()
            if os.path.splitext(f)[1] in TEXT and not f.startswith(SKIP)
            and os.path.isfile(os.path.join(ROOT, f))]  # fmt: skip


def test_no_tracked_text_speaks_of_how_the_project_was_worked_on():
    hits = []
    for name in tracked_text_files():
        try:
            text = open(os.path.join(ROOT, name), encoding="utf-8").read()
        except UnicodeDecodeError:
            continue
        for number, line in enumerate(text.splitlines(), 1):
            for match in FORBIDDEN.finditer(ALLOWED.sub("", line)):
                hits.append(f"{name}:{number}: {match.group(0)!r}")
    assert not hits, "\n".join(hits)


def test_the_pattern_catches_what_it_is_for():
    caught = [
        "a " + "le" + "nt H100",
        "one dev" + "ice call carries",
        "before rou" + "nd 2",
        "this " + SCOPE,
        "see ../" + "sha" + "red/paper",
        "the " + "iss" + "ue's target",
    ]
    for phrase in caught:
        assert FORBIDDEN.search(phrase), phrase
    for phrase in ("silently", "talent", "a populated round of 256 updates"):
        assert not FORBIDDEN.search(phrase), phrase
    assert not FORBIDDEN.search(ALLOWED.sub("", f'@pytest.fixture(scope="{SCOPE}")'))
