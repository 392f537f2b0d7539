"""Run every benchmark (``bench/*.py`` functions named ``bench_*``; ``_*.py`` are helpers) and
write results.json.

Each benchmark returns ``{"name": {"value": number, "unit": "..."}}``; ratios are measured
against a baseline taken in the same run, since the machines are shared and noisy.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    only = set(argv)
    results: dict[str, dict[str, float | str]] = {}
    failed = []
    for path in sorted(HERE.glob("*.py")):
        if path.name == "run.py" or path.name.startswith("_") or (only and path.stem not in only):
            continue
        spec = importlib.util.spec_from_file_location(f"bench_{path.stem}", path)
        module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        spec.loader.exec_module(module)  # type: ignore[union-attr]
        for name in sorted(n for n in dir(module) if n.startswith("bench_")):
            t0 = time.monotonic()
            try:
                figures = getattr(module, name)()
            except Exception:
                traceback.print_exc()
                failed.append(f"{path.stem}.{name}")
                continue
            for key, fig in figures.items():
                results[key] = {"value": float(fig["value"]), "unit": str(fig["unit"])}
                print(f"{key}: {fig['value']:.6g} {fig['unit']}", flush=True)
            print(f"  ({path.stem}.{name} took {time.monotonic() - t0:.1f} s)", file=sys.stderr)
    (HERE / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    print(json.dumps(results, indent=2))
    if failed:
        print(f"benchmarks failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
