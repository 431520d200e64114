"""Dump the firmware core's outputs over seeded random inputs, to compare two trees bit for bit.

The dump itself is ``robot_agent/buildtools/core_outputs.py`` (its docstring says what it covers)::

    PYTHONPATH=/path/to/before .venv/bin/python bench/firmware_outputs.py > before.txt
    .venv/bin/python bench/firmware_outputs.py > after.txt
    cmp before.txt after.txt    # identical, or the change is not a pure speed change

A ``PYTHONPATH`` (the tree to check) comes first, else this tree.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

from robot_agent.buildtools.core_outputs import main

if __name__ == "__main__":
    raise SystemExit(main())
