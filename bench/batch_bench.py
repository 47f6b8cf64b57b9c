#!/usr/bin/env python3
"""Batch benchmark: loopd-solve --solver lm against Ceres (run side by side, best of N) and
the GTSAM figures of ../shared/REFERENCE.md, on every g2o file of a datasets folder plus any
extra files given. Prints a markdown table; exits 1 if a target is missed.

  bench/batch_bench.py --build build [--repeat 3] [--datasets ../shared/datasets] [extra.g2o ...]
"""
import argparse, json, os, re, subprocess, sys, tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def reference_table(path):
    """dataset -> (best chi2, GTSAM LM seconds) from REFERENCE.md's first table."""
    ref = {}
    if not os.path.exists(path):
        return ref
    for line in open(path):
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if len(cells) < 7 or not re.match(r'^[\d.]+$', cells[3] or 'x'):
            continue
        gtsam = re.match(r'([\d.]+)', cells[4])
        ref[cells[0]] = (float(cells[3]), float(gtsam.group(1)) if gtsam else None)
    return ref


def report_misses(misses):
    """Print the missed targets, if any; returns the exit code (1 if any were missed, else 0)."""
    if misses:
        print('\nmissed targets:\n' + '\n'.join('- ' + m for m in misses))
    return 1 if misses else 0


def run_loopd(exe, path, repeat):
    best = None
    for _ in range(repeat):
        with tempfile.NamedTemporaryFile(suffix='.json') as tmp:
            subprocess.run([exe, path, '--solver', 'lm', '--quiet', '--stats', tmp.name],
                           check=True, stdout=subprocess.DEVNULL)
            stats = json.load(open(tmp.name))
        if best is None or stats['solve_s'] < best['solve_s']:
            best = stats
    return best


def run_ceres(exe, path, repeat):
    if not exe or not os.path.exists(exe):
        return None
    best = None
    for _ in range(repeat):
        out = subprocess.run([exe, path, '--json'], capture_output=True, text=True, timeout=600)
        if out.returncode != 0:
            return None
        stats = json.loads(out.stdout)
        if best is None or stats['solve_s'] < best['solve_s']:
            best = stats
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--build', default=os.path.join(ROOT, 'build'))
    ap.add_argument('--datasets', default=os.path.join(ROOT, '..', 'shared', 'datasets'))
    ap.add_argument('--reference', default=os.path.join(ROOT, '..', 'shared', 'REFERENCE.md'))
    ap.add_argument('--repeat', type=int, default=3)
    ap.add_argument('extra', nargs='*', help='more g2o files')
    args = ap.parse_args()

    solve = os.path.join(args.build, 'tools', 'loopd-solve')
    ceres = os.path.join(args.build, 'bench', 'ceres_baseline', 'ceres_baseline')
    ref = reference_table(args.reference)
    files = sorted(os.path.join(args.datasets, f) for f in os.listdir(args.datasets) if f.endswith('.g2o'))
    files += args.extra

    print('| dataset | poses | edges | iterations | final chi2 | best chi2 | reaches best | loopd s | Ceres s (→ chi2) | loopd/Ceres | GTSAM LM s (ref) | loopd/GTSAM |')
    print('|---|---|---|---|---|---|---|---|---|---|---|---|')
    failures = []
    for path in files:
        name = os.path.splitext(os.path.basename(path))[0]
        sys.stderr.write(f'{name}...\n')
        mine = run_loopd(solve, path, args.repeat)
        theirs = run_ceres(ceres, path, args.repeat)
        best, gtsam = ref.get(name, (None, None))
        ok = best is None or mine['final_chi2'] <= best * (1 + 1e-4)
        ceres_s = theirs['solve_s'] if theirs else None
        r_ceres = mine['solve_s'] / ceres_s if ceres_s else None
        r_gtsam = mine['solve_s'] / gtsam if gtsam else None
        if not ok:
            failures.append(f'{name}: chi2 {mine["final_chi2"]:.6f} above best {best}')
        if r_ceres is not None and r_ceres > 0.7:
            failures.append(f'{name}: {r_ceres:.2f} of Ceres time (target 0.70)')
        if r_gtsam is not None and r_gtsam > 0.5:
            failures.append(f'{name}: {r_gtsam:.2f} of GTSAM time (target 0.50)')
        fmt = lambda v, f='{:.4f}': '—' if v is None else f.format(v)
        ceres_cell = '—' if not theirs else f"{theirs['solve_s']:.4f} (→ {theirs['final_chi2']:.6g})"
        print(f"| {name} | {mine['poses']} | {mine['factors']} | {mine['iterations']} | "
              f"{mine['final_chi2']:.6f} | {fmt(best, '{}')} | {'yes' if ok else 'NO'} | "
              f"{mine['solve_s']:.4f} | {ceres_cell} | {fmt(r_ceres, '{:.2f}')} | {fmt(gtsam, '{}')} | "
              f"{fmt(r_gtsam, '{:.2f}')} |")
    return report_misses(failures)


if __name__ == '__main__':
    sys.exit(main())
