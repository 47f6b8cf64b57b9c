#!/usr/bin/env python3
"""Multi-hypothesis benchmark (issue #6): N true loop closures of a dataset made ambiguous by
loopd-outliers --ambiguous (3 alternatives + null, mixed decoys by default; --decoys aliased is
the stress case where the data take long to decide), then run online
(loopd-solve --incremental) through mh with K = 1, 5, 10, 20, and through risam and mm (decoys
as ordinary loop closures); plain isam2 on the outlier-free file is the cost baseline.
Per run: how often the best hypothesis took the true alternative, chi2 over the true edges
against the outlier-free optimum, total online time, peak RSS and (mh) the clique numerics the
live hypotheses held at the sampled peak, shared cliques counted once (and once per hypothesis).

  bench/ambiguous_bench.py --build build [--datasets-only manhattan,city10000]
                           [--counts 50,200] [--ks 1,5,10,20] [--seeds 1] [--csv out.csv]
                           [--decoys mixed|target|measurement|aliased]
"""
import argparse, csv, json, os, subprocess, sys, tempfile

from batch_bench import ROOT


def run(cmd):
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def solve(exe, path, solver, work, tag, k=None):
    stats, est = os.path.join(work, tag + '.json'), os.path.join(work, tag + '.g2o')
    cmd = [exe, path, '--solver', solver, '--incremental', '--quiet', '--stats', stats, '--out', est]
    if k is not None:
        cmd += ['--max-hypotheses', str(k)]
    run(cmd)
    return json.load(open(stats)), est


def evaluate(eval_exe, ref, est, truth, stats_path, graph, work, tag):
    out = os.path.join(work, tag + '.eval.json')
    run([eval_exe, '--reference', ref, '--estimate', est, '--truth', truth, '--stats', stats_path,
         '--graph', graph, '--json', out])
    return json.load(open(out))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--build', default=os.path.join(ROOT, 'build'))
    ap.add_argument('--datasets', default=os.path.join(ROOT, '..', 'shared', 'datasets'))
    ap.add_argument('--datasets-only', default='manhattan,city10000')
    ap.add_argument('--counts', default='50,200')
    ap.add_argument('--ks', default='1,5,10,20')
    ap.add_argument('--others', default='risam,mm')
    ap.add_argument('--seeds', default='1')
    ap.add_argument('--csv', default='')
    ap.add_argument('--decoys', default='mixed')
    a = ap.parse_args()
    tools = os.path.join(a.build, 'tools')
    solve_exe, outliers, eval_exe = (os.path.join(tools, t) for t in ('loopd-solve', 'loopd-outliers', 'loopd-eval'))
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for ds in a.datasets_only.split(','):
            clean = os.path.join(a.datasets, ds + '.g2o')
            base, ref = solve(solve_exe, clean, 'isam2', work, ds + '_clean')
            optimum = base['final_chi2']
            print(f'{ds}: isam2 on the outlier-free file {base["solve_s"]:.2f} s, '
                  f'{base["peak_rss_mb"]:.0f} MB, chi2 {optimum:.6g}', file=sys.stderr)
            for n in map(int, a.counts.split(',')):
                for seed in map(int, a.seeds.split(',')):
                    tag = f'{ds}_a{n}_s{seed}'
                    graph, truth = os.path.join(work, tag + '.g2o'), os.path.join(work, tag + '.truth.json')
                    run([outliers, clean, '--ambiguous', str(n), '--null', '--decoys', a.decoys,
                         '--seed', str(seed), '--out', graph, '--truth', truth])
                    runs = [('mh', k) for k in map(int, a.ks.split(','))] + \
                           [(s, None) for s in a.others.split(',') if s]
                    for solver, k in runs:
                        rtag = f'{tag}_{solver}{k or ""}'
                        stats, est = solve(solve_exe, graph, solver, work, rtag, k)
                        e = evaluate(eval_exe, ref, est, truth, os.path.join(work, rtag + '.json'),
                                     graph, work, rtag)
                        row = dict(dataset=ds, decoys=a.decoys, ambiguous=n, seed=seed, solver=solver, K=k or '',
                                   chosen_accuracy=e['chosen_accuracy'],
                                   chosen_none=e['chosen_none'],
                                   chi2_true_vs_opt=e['inlier_chi2'] / optimum - 1.0,
                                   solve_s=stats['solve_s'], x_isam2=stats['solve_s'] / base['solve_s'],
                                   peak_rss_mb=stats['peak_rss_mb'], base_rss_mb=base['peak_rss_mb'],
                                   mean_live=stats.get('mean_live_hypotheses', ''),
                                   peak_clique_mb=stats.get('peak_clique_mb', ''),
                                   peak_clique_mb_unshared=stats.get('peak_clique_mb_unshared', ''),
                                   ate_m=e['ate_rmse'])
                        rows.append(row)
                        print(f"{ds} n={n} seed={seed} {solver}{k or ''}: chosen {row['chosen_accuracy']:.3f} "
                              f"chi2 {100 * row['chi2_true_vs_opt']:+.3f}% {row['solve_s']:.2f} s "
                              f"(x{row['x_isam2']:.2f}) {row['peak_rss_mb']:.0f} MB", file=sys.stderr)
    if a.csv:
        with open(a.csv, 'w', newline='') as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
            w.writeheader()
            w.writerows(rows)
    print('| dataset | decoys | ambiguous | solver | K | true chosen | chi2 true edges vs optimum | online s | x isam2 '
          '| peak RSS MB (isam2) | mean live | peak clique MB (unshared) |')
    print('|---|---|---|---|---|---|---|---|---|---|---|---|')
    for r in rows:
        live = f"{r['mean_live']:.2f}" if r['mean_live'] != '' else ''
        clique = (f"{r['peak_clique_mb']:.0f} ({r['peak_clique_mb_unshared']:.0f})"
                  if r['peak_clique_mb'] not in ('', 0) else '')
        print(f"| {r['dataset']} | {r['decoys']} | {r['ambiguous']} | {r['solver']} | {r['K']} | {r['chosen_accuracy']:.3f} | "
              f"{100 * r['chi2_true_vs_opt']:+.3f}% | {r['solve_s']:.2f} | {r['x_isam2']:.2f} | "
              f"{r['peak_rss_mb']:.0f} ({r['base_rss_mb']:.0f}) | {live} | {clique} |")


if __name__ == '__main__':
    main()
