"""Start-up of the ``gonio`` command: whole-process time of ``gonio --help`` over that of
``python -c "import numpy"``, the same interpreter, interleaved and measured in the same run
(median of repeats), so the ratio says how much a command pays before doing anything."""

from __future__ import annotations

import statistics
import subprocess
import sys
import time
from pathlib import Path

_REPEATS = 15
_GONIO = Path(sys.executable).with_name("gonio")


def _run_s(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def bench_cli_start() -> dict[str, dict[str, float | str]]:
    helps, numpys = [], []
    for _ in range(2):  # warm the file cache
        _run_s([str(_GONIO), "--help"])
        _run_s([sys.executable, "-c", "import numpy"])
    for _ in range(_REPEATS):
        helps.append(_run_s([str(_GONIO), "--help"]))
        numpys.append(_run_s([sys.executable, "-c", "import numpy"]))
    h, n = statistics.median(helps), statistics.median(numpys)
    return {
        "cli_help_vs_numpy_import": {"value": h / n, "unit": "ratio"},
        "cli_help_s": {"value": h, "unit": "s"},
        "numpy_import_s": {"value": n, "unit": "s"},
    }
