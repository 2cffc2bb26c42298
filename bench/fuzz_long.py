"""The fuzz properties of tests/test_fuzz_decoders.py and tests/test_fuzz_loaders.py with many
more examples each (issue 10): every decoder and loader fed garbage, a fresh random seed per
run unless --seed is given. Prints each property, its examples and time, and what it found: a
falsifying input with its traceback, or nothing.

    .venv/bin/python bench/fuzz_long.py                 # 20000 examples each (about an hour)
    .venv/bin/python bench/fuzz_long.py --examples 2000 -k stim300 -k wire

Exit status 1 if any property failed."""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--examples", type=int, default=20000, help="examples per property")
    ap.add_argument("-k", action="append", default=[], help="only properties naming this")
    ap.add_argument("--seed", type=int, default=None, help="hypothesis seed (default: random)")
    args = ap.parse_args()

    # read by tests/test_fuzz_decoders.py `fuzz()` at import: the long run's settings
    os.environ["IMUD_FUZZ_EXAMPLES"] = str(args.examples)
    sys.path.insert(0, str(REPO))
    from hypothesis import seed

    from tests import test_fuzz_decoders, test_fuzz_loaders

    props: list[tuple[str, Any]] = [
        (name, fn)
        for mod in (test_fuzz_decoders, test_fuzz_loaders)
        for name, fn in vars(mod).items()
        if name.startswith("test_") and callable(fn) and hasattr(fn, "hypothesis")
    ]
    if args.k:
        props = [(n, f) for n, f in props if any(k in n for k in args.k)]
    print(f"fuzzing {len(props)} properties, {args.examples} examples each, "
          f"seed {args.seed if args.seed is not None else 'random'}")  # fmt: skip
    failed: list[tuple[str, str]] = []
    t_all = time.perf_counter()
    for name, fn in props:
        run = seed(args.seed)(fn) if args.seed is not None else fn
        t0 = time.perf_counter()
        try:
            run()
            verdict = "ok"
        except Exception as e:  # a falsified property: hypothesis shrank it and re-raised
            verdict = f"FAILED {type(e).__name__}"
            failed.append((name, "".join(traceback.format_exception(e))))
        print(f"  {name:<72} {time.perf_counter() - t0:8.1f} s  {verdict}", flush=True)
    print(f"{len(props)} properties in {time.perf_counter() - t_all:.0f} s: "
          f"{len(failed)} failed")  # fmt: skip
    for name, tb in failed:
        print(f"\n=== {name}\n{tb}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
