"""Flake hunt: run the tests that start processes N times beside CPU hogs; count per test.

    make flake-hunt                      # 5 runs beside 2 hogs
    make flake-hunt RUNS=3 HOGS=0 ARGS="-k inference"

Each run is a whole pytest session of the ``processes`` tier (``-m processes``: node
executables, launch files, the CLI; test/conftest.py marks them), as CI runs it, while
``HOGS`` busy-loop processes (``yes > /dev/null``, at normal priority) compete for the
cores. Run it from a shell where `make test` works (install/ and, for the launch tests,
the launch stack sourced; the Makefile target does that). Prints, per test that did not
pass every time, its passes, failures, errors and skips over the runs, then the totals and
the wall time of each run; exit status 1 when any test failed or erred in any run.
The junit report and the whole pytest output of every run with a failure are kept in
``--keep`` (default ``results/flake_hunt``), so a failure seen once can be read in full.
"""

from __future__ import annotations

import argparse
import collections
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

OUTCOMES = ("passed", "failed", "error", "skipped")


def outcomes(junit: Path) -> tuple[dict, dict]:
    """``({test id: outcome}, {test id: failure message})`` of one junit XML report."""
    out, why = {}, {}
    for case in ET.parse(junit).getroot().iter("testcase"):
        tid = f"{case.get('classname')}::{case.get('name')}"
        kinds = {child.tag: child for child in case}
        out[tid] = ("failed" if "failure" in kinds else "error" if "error" in kinds
                    else "skipped" if "skipped" in kinds else "passed")
        bad = kinds.get("failure", kinds.get("error"))
        if bad is not None:
            why[tid] = [ln for ln in (bad.get("message") or "").splitlines() if ln.strip()][:3]
    return out, why


def hunt(runs: int, hogs: int, pytest_args: list, marker: str = "processes",
         keep: Path = Path("results/flake_hunt")) -> int:
    tally: dict = collections.defaultdict(collections.Counter)
    walls = []
    from aslip_ros.util import cpu_hogs
    with cpu_hogs(hogs), tempfile.TemporaryDirectory(prefix="aslip_flake_hunt_") as tmp:
        for k in range(runs):
            junit = Path(tmp) / f"run{k}.xml"
            log = Path(tmp) / f"run{k}.log"
            # -P: the repository root must not shadow the built package on sys.path.
            cmd = [sys.executable, "-P", "-m", "pytest", "test", "-m", marker, "-q",
                   "-p", "no:cacheprovider", f"--junitxml={junit}", *pytest_args]
            t0 = time.monotonic()
            with open(log, "wb") as out:
                rc = subprocess.call(cmd, stdout=out, stderr=subprocess.STDOUT)
            walls.append(time.monotonic() - t0)
            if not junit.exists():
                print(f"run {k + 1}: pytest exited {rc} without a report", flush=True)
                return 2
            res, why = outcomes(junit)
            for tid, outcome in res.items():
                tally[tid][outcome] += 1
            bad = [t for t, o in res.items() if o in ("failed", "error")]
            print(f"run {k + 1}/{runs}: {len(res)} tests, {len(bad)} failed or erred, "
                  f"{walls[-1]:.0f} s{' : ' + ', '.join(bad) if bad else ''}", flush=True)
            for tid in bad:
                print(f"  {tid}: " + " / ".join(why.get(tid, [])), flush=True)
            if bad:
                keep.mkdir(parents=True, exist_ok=True)
                stamp = time.strftime("%Y%m%d-%H%M%S")
                for src in (junit, log):
                    shutil.copy(src, keep / f"{stamp}-{src.name}")
                print(f"  kept: {keep / stamp}-run{k}.xml and .log", flush=True)
    flaky = {t: c for t, c in tally.items() if c["failed"] or c["error"]}
    skipped = sorted(t for t, c in tally.items() if c["skipped"] and t not in flaky)
    print(f"\n{len(tally)} tests x {runs} runs beside {hogs} CPU hogs; "
          f"{len(flaky)} failed or erred at least once")
    if skipped:
        print(f"skipped or xfailed at least once: {', '.join(skipped)}")
    if flaky:
        print("| test | " + " | ".join(OUTCOMES) + " |\n|---|" + "---|" * len(OUTCOMES))
        for tid, c in sorted(flaky.items()):
            print(f"| {tid} | " + " | ".join(str(c[o]) for o in OUTCOMES) + " |")
    total = collections.Counter()
    for c in tally.values():
        total.update(c)
    print("totals: " + ", ".join(f"{total[o]} {o}" for o in OUTCOMES)
          + f"; run wall times {', '.join(f'{w:.0f}' for w in walls)} s")
    return 1 if total["failed"] or total["error"] else 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5, help="pytest sessions (default 5)")
    ap.add_argument("--hogs", type=int, default=2, help="CPU-busy processes (default 2)")
    ap.add_argument("--marker", default="processes", help="the tier (default processes)")
    ap.add_argument("--keep", type=Path, default=Path("results/flake_hunt"),
                    help="where the reports of runs with a failure go")
    ap.add_argument("pytest_args", nargs=argparse.REMAINDER,
                    help="passed to pytest, e.g. -k inference")
    a = ap.parse_args(argv)
    if a.runs < 1 or a.hogs < 0:
        ap.error("--runs must be >= 1 and --hogs >= 0")
    return hunt(a.runs, a.hogs, [x for x in a.pytest_args if x != "--"], a.marker,
                a.keep)


if __name__ == "__main__":
    raise SystemExit(main())
