"""The studies' tests: their modules live in ``experiments/`` (scripts and shared helpers)."""

from __future__ import annotations

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
