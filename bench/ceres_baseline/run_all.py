#!/usr/bin/env python3
"""Run ceres_baseline on every .g2o file of a folder and print a table.

usage: run_all.py CERES_BASELINE_BINARY [DATASETS_DIR] [--repeat N]

Each file is solved N times (default 3); the table shows the run with the smallest solve
time (final chi2 and iterations are deterministic), the median solve time and the smallest
CPU time of the solve (a proxy for the unloaded wall time on a busy machine).
"""
import json
import pathlib
import statistics
import subprocess
import sys


def main() -> int:
    args = [a for a in sys.argv[1:]]
    repeat = 3
    if "--repeat" in args:
        k = args.index("--repeat")
        repeat = int(args[k + 1])
        del args[k:k + 2]
    if not args:
        print(__doc__, file=sys.stderr)
        return 2
    binary = args[0]
    folder = pathlib.Path(args[1] if len(args) > 1 else
                          pathlib.Path(__file__).resolve().parents[3] / "shared" / "datasets")
    files = sorted(folder.glob("*.g2o"))
    if not files:
        print(f"no .g2o files in {folder}", file=sys.stderr)
        return 1
    print(f"{'dataset':<16}{'poses':>7}{'edges':>7}{'iter':>6}{'setup s':>10}"
          f"{'solve s (min)':>15}{'median':>10}{'cpu s (min)':>13}{'initial chi2':>16}{'final chi2':>16}  termination")
    for f in files:
        runs = []
        for _ in range(repeat):
            out = subprocess.run([binary, str(f), "--json"], capture_output=True, text=True)
            if out.returncode != 0:
                print(f"{f.name}: exit {out.returncode}: {out.stderr.strip()}", file=sys.stderr)
                break
            runs.append(json.loads(out.stdout))
        if not runs:
            continue
        best = min(runs, key=lambda r: r["solve_s"])
        med = statistics.median(r["solve_s"] for r in runs)
        cpu = min(r.get("solve_cpu_s", float("nan")) for r in runs)
        print(f"{best['dataset']:<16}{best['poses']:>7}{best['edges']:>7}{best['iterations']:>6}"
              f"{best['setup_s']:>10.4f}{best['solve_s']:>15.4f}{med:>10.4f}{cpu:>13.4f}"
              f"{best['initial_chi2']:>16.6g}{best['final_chi2']:>16.9g}  {best['termination']}",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
