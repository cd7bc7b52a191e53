"""Coverage of the analysis's 95 % intervals, and its verdicts, over many regimes.

Run: ``python bench/bench_coverage.py [--seeds N] [--regimes a,b,...]``. Prints a Markdown
table; asserts nothing. Each regime simulates records with core.bench (Langevin A = 1.2 m/s^2,
alpha = 110 s/m unless the regime changes the law) and runs core.pipeline.analyze_positions
with the true exposure. Per regime: how many runs gave no warning (besides 'gaps'), and among
those how often the 95 % interval of A and of alpha covered the truth (the target: at least
90 %); the verdicts; the worst samples_used / samples_total. A 'degenerate' run is scored on
its viscous limit c = A alpha / 3 (the true law's), in both columns.
"""

import os

for _name in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_name, '1')

import argparse  # noqa: E402
import collections  # noqa: E402
import sys  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from microball_ros.core import bench, friction, pipeline  # noqa: E402

LANGEVIN = friction.Langevin(1.2, 110.0)
# name: (scenario overrides, expected verdict)
REGIMES = {
    'paper 30 fps 2.95 Hz 2 um': ({}, 'memoryless'),
    'clean (no noise, no drift)': ({'noise_std': 0.0, 'drift_velocity': 0.0}, 'memoryless'),
    '15 fps 1.5 Hz': ({'frame_rate': 15.0, 'exposure': 1 / 30, 'frequency': 1.5,
                       'stator_amplitude': 2.4e-3}, 'memoryless'),
    '120 fps 10 Hz': ({'frame_rate': 120.0, 'exposure': 1 / 240, 'frequency': 10.0,
                       'stator_amplitude': 0.36e-3}, 'memoryless'),
    '30 fps 0.5 Hz': ({'frequency': 0.5, 'stator_amplitude': 7e-3}, 'memoryless'),
    '60 fps 6 Hz': ({'frame_rate': 60.0, 'exposure': 1 / 120, 'frequency': 6.0,
                     'stator_amplitude': 0.6e-3}, 'memoryless'),
    'noise 0.5 um': ({'noise_std': 0.5e-6}, 'memoryless'),
    'noise 10 um': ({'noise_std': 10e-6}, 'memoryless'),
    'drift 30 um/s': ({'drift_velocity': 30e-6}, 'memoryless'),
    'saturating 3 mm': ({'stator_amplitude': 3e-3}, 'memoryless'),
    'strongly saturated alpha 2000': ({'law': friction.Langevin(1.2, 2000.0)}, 'memoryless'),
    'near Nyquist 15 fps 4.9 Hz': ({'frame_rate': 15.0, 'exposure': 1 / 30, 'frequency': 4.9,
                                    'stator_amplitude': 0.72e-3}, 'memoryless'),
    'lag 10 ms': ({'law': friction.LaggedFriction(LANGEVIN, 0.010)}, 'memory'),
    'lag 40 ms': ({'law': friction.LaggedFriction(LANGEVIN, 0.040)}, 'memory'),
}


def run(name, seeds):
    """Return the row of one regime."""
    overrides, expected = REGIMES[name]
    scenario = bench.get_scenario('paper', **overrides)
    duration = max(20.0, 40.0 / scenario.frequency)
    clean_runs = covered = covered_alpha = 0
    verdicts = collections.Counter()
    codes = collections.Counter()
    worst_used = 1.0
    for seed in range(seeds):
        record = bench.simulate(bench.get_scenario('paper', **overrides, seed=seed), duration)
        result = pipeline.analyze_positions(
            record.time, record.stator_position, record.slider_position,
            options=pipeline.Options(exposure=scenario.exposure))
        verdicts[result.memory_verdict] += 1
        worst_used = min(worst_used, result.samples_used / result.samples_total)
        warned = {code for code, _ in result.warnings} - {'gaps'}
        codes.update(warned)
        if warned - {'degenerate'} or result.fit is None or expected == 'memory':
            continue
        clean_runs += 1
        law = scenario.law
        if result.viscous_limit is not None:
            _, (lo, hi) = result.viscous_limit
            truth = law.A * law.alpha / 3
            covered += lo <= truth <= hi
            covered_alpha += lo <= truth <= hi
            continue
        lo, hi = result.fit.ci95['A']
        covered += lo <= law.A <= hi
        lo, hi = result.fit.ci95['alpha']
        covered_alpha += lo <= law.alpha <= hi
    coverage = (f'{covered}/{clean_runs} A, {covered_alpha}/{clean_runs} alpha'
                if clean_runs else '-')
    verdict_text = ', '.join(f'{v} {n}' for v, n in sorted(verdicts.items()))
    code_text = ', '.join(f'{c} {n}' for c, n in sorted(codes.items())) or '-'
    return (f'| {name} | {expected} | {verdict_text} | {code_text} | {coverage} | '
            f'{worst_used:.3f} |')


def main():
    """Print the coverage table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=10)
    parser.add_argument('--regimes', help='comma-separated names (default: all)')
    args = parser.parse_args()
    names = args.regimes.split(',') if args.regimes else list(REGIMES)
    print('| regime | truth | verdicts | warnings (runs) | 95 % intervals covering the truth, '
          'runs without warning | worst used/total |')
    print('| --- | --- | --- | --- | --- | --- |')
    for name in names:
        print(run(name, args.seeds), flush=True)


if __name__ == '__main__':
    main()
