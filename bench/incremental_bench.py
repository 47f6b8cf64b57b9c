#!/usr/bin/env python3
"""Incremental benchmark: loopd-solve --solver isam2 --incremental (one update per pose, the
full estimate after each, a final optimize) on the datasets, against the GTSAM iSAM2 figures
of ../shared/REFERENCE.md; then scaling tables on synthetic Manhattan worlds (loopd-synth):
the city world (the robot keeps exploring new streets and closes loops around where it is)
and the square world (it revisits places anywhere on a map of ~N cells: the worst case).

  bench/incremental_bench.py --build build [--sizes 1000,10000,100000] [--worlds city,square]
                             [--only manhattan,...] (--only none: scaling tables alone)
"""
import argparse, json, os, re, subprocess, sys, tempfile

from batch_bench import ROOT, reference_table, report_misses

TARGETS = ['manhattan', 'city10000', 'sphere2500', 'torus3D', 'parking-garage']


def gtsam_isam2(path):
    """dataset -> (total s, max step ms) from REFERENCE.md's iSAM2 column."""
    out = {}
    for line in open(path):
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if len(cells) >= 7:
            m = re.match(r'([\d.]+) \(([\d.]+) / ([\d.]+)\)', cells[6])
            if m:
                out[cells[0]] = (float(m.group(1)), float(m.group(3)))
    return out


def solve(exe, path, solver='isam2'):
    with tempfile.NamedTemporaryFile(suffix='.json') as tmp:
        subprocess.run([exe, path, '--solver', solver, '--incremental', '--quiet', '--stats', tmp.name],
                       check=True, stdout=subprocess.DEVNULL)
        return json.load(open(tmp.name))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--build', default=os.path.join(ROOT, 'build'))
    ap.add_argument('--datasets', default=os.path.join(ROOT, '..', 'shared', 'datasets'))
    ap.add_argument('--reference', default=os.path.join(ROOT, '..', 'shared', 'REFERENCE.md'))
    ap.add_argument('--sizes', default='1000,10000,100000')
    ap.add_argument('--only', default='', help='comma-separated dataset names ("none": skip them)')
    ap.add_argument('--worlds', default='city,square', help='synthetic worlds for the scaling tables')
    args = ap.parse_args()
    exe = os.path.join(args.build, 'tools', 'loopd-solve')
    best = reference_table(args.reference)
    gtsam = gtsam_isam2(args.reference)
    names = [] if args.only == 'none' else args.only.split(',') if args.only else sorted(
        os.path.splitext(f)[0] for f in os.listdir(args.datasets) if f.endswith('.g2o'))

    print('| dataset | poses | total s | GTSAM total s (ref) | ratio | mean / p99 / max update ms | GTSAM max ms (ref) | final chi2 | within 0.1% of best | peak RSS MB |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    misses = []
    for name in names:
        sys.stderr.write(f'{name}...\n')
        st = solve(exe, os.path.join(args.datasets, name + '.g2o'))
        b = best.get(name, (None, None))[0]
        g = gtsam.get(name)
        ok = b is None or st['final_chi2'] <= b * 1.001
        ratio = st['solve_s'] / g[0] if g else None
        if not ok:
            misses.append(f'{name}: chi2 {st["final_chi2"]:.6f} vs best {b}')
        if name in TARGETS and ratio is not None and ratio > 0.5:
            misses.append(f'{name}: {ratio:.2f} of GTSAM iSAM2 time (target 0.5)')
        if name in TARGETS and g and st['update_ms_max'] > g[1]:
            misses.append(f'{name}: worst update {st["update_ms_max"]:.1f} ms > GTSAM {g[1]} ms')
        print(f"| {name} | {st['poses']} | {st['solve_s']:.3f} | {g[0] if g else '—'} | "
              f"{'—' if ratio is None else f'{ratio:.2f}'} | {st['update_ms_mean']:.2f} / "
              f"{st['update_ms_p99']:.2f} / {st['update_ms_max']:.1f} | {g[1] if g else '—'} | "
              f"{st['final_chi2']:.6f} | {'yes' if ok else 'NO'} | {st['peak_rss_mb']:.0f} |")

    synth = os.path.join(args.build, 'bench', 'loopd-synth')
    for world in [w for w in args.worlds.split(',') if w] if args.sizes and os.path.exists(synth) else []:
        print(f'\n{world} world: `loopd-synth --world {world} --poses N`; load average (1 min) at the start of each run\n')
        print('| poses | loop closures | online total s | exploration updates: mean / max ms '
              '| loop-closure updates: mean / p99 / max ms | final chi2 | peak RSS MB | load |')
        print('|---|---|---|---|---|---|---|---|')
        for n in [int(x) for x in args.sizes.split(',') if x]:
            with tempfile.TemporaryDirectory() as d:
                path = os.path.join(d, f'{world}{n}.g2o')
                log = subprocess.run([synth, '--world', world, '--poses', str(n), '--out', path],
                                     check=True, capture_output=True, text=True).stderr
                closures = re.search(r'\((\d+) loop closures\)', log).group(1)
                sys.stderr.write(f'synthetic {world} {n}...\n')
                load = os.getloadavg()[0]
                st = solve(exe, path)
            print(f"| {n} | {closures} | {st['solve_s']:.2f} | "
                  f"{st['exploration_update_ms_mean']:.3f} / "
                  f"{st['exploration_update_ms_max']:.1f} | "
                  f"{st['closure_update_ms_mean']:.3f} / {st['closure_update_ms_p99']:.2f} / "
                  f"{st['closure_update_ms_max']:.1f} | {st['final_chi2']:.4f} | {st['peak_rss_mb']:.0f} | "
                  f"{load:.1f} |")
            sys.stdout.flush()
    return report_misses(misses)


if __name__ == '__main__':
    sys.exit(main())
