"""Judge ``microball analyze`` on the independent case set; print one Markdown table.

Run: ``python bench/independent/run.py [--quick] [--cases a,b] [--seeds N] [--work DIR]``.
Generates the cases that are missing (generate.py, a pool of 2 processes), then runs
``microball analyze CASE.csv --json OUT.json`` once per case and seed, exactly as a user
would, at most 2 at a time, adding ``--exposure E`` when the case has motion blur (the true
exposure; ``--no-exposure`` leaves it out). Asserts nothing; exits 0.
"""

import argparse
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
import json
import math
import os
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generate  # noqa: E402

DEFAULT_TOOL = os.environ.get('MICROBALL', '/work/main/.venv/bin/microball')


def analyze(tool, csv, exposure, timeout):
    """Run the CLI on one case; return (exit code, last stderr line, seconds, result or None)."""
    out = csv.with_suffix('.out.json')
    if out.exists():
        out.unlink()
    cmd = [tool, 'analyze', str(csv), '--json', str(out)]
    if exposure:
        cmd += ['--exposure', repr(exposure)]
    env = {k: v for k, v in os.environ.items() if k != 'PYTHONPATH'}
    for name in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
        env[name] = '1'
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    # A reinstall of the package (pip install -e) removes the script for a moment.
    deadline = time.monotonic() + 60.0
    while not os.path.exists(tool) and time.monotonic() < deadline:
        time.sleep(0.5)
    t0 = time.monotonic()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env,
                           cwd=csv.parent)
        code, err = p.returncode, p.stderr
    except subprocess.TimeoutExpired as e:
        code, err = 'timeout', (e.stderr or b'').decode(errors='replace')
    except FileNotFoundError as e:
        code, err = 'no-tool', str(e)
    dt = time.monotonic() - t0
    csv.with_suffix('.stderr.txt').write_text(err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    result = None
    if code == 0 and out.exists():
        try:
            result = json.loads(out.read_text())
        except ValueError:
            result = None
    return code, (lines[-1] if lines else ''), dt, result


def tool_version(tool):
    """Return the git commit of the checkout a venv's tool belongs to, or '?'."""
    repo = Path(tool).resolve().parent.parent.parent
    try:
        p = subprocess.run(['git', '-C', str(repo), 'log', '-1', '--format=%h %s'],
                           capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return '?'
    return p.stdout.strip()[:60] if p.returncode == 0 else '?'


def verdict(result):
    """Return the tool's memory verdict: memory_verdict if present, else from memoryless."""
    v = result.get('memory_verdict')
    if v is not None:
        return v
    m = result.get('memoryless')
    if m is None:
        return 'missing'
    return 'memoryless' if m else 'memory'


def covers(ci, value):
    """Return whether the interval ci = [lo, hi] contains value (null ends are unbounded)."""
    if not isinstance(ci, (list, tuple)) or len(ci) != 2:
        return False
    lo = -math.inf if ci[0] is None else float(ci[0])
    hi = math.inf if ci[1] is None else float(ci[1])
    return lo <= value <= hi


def samples(result, truth):
    """Return (used, total, source) from the result: top level, else window, else None."""
    if 'samples_used' in result:
        return result['samples_used'], result.get('samples_total'), ''
    w = result.get('window') or {}
    if 'samples_used' in w:
        return w['samples_used'], truth['rows'], 'w'
    return None, None, ''


INFORMATIONAL = {'gaps'}


def warning_codes(result):
    """Return the set of warning codes of a result."""
    return {w.get('code') for w in (result.get('warnings') or []) if isinstance(w, dict)}


def pct(k, n):
    """Format k of n as 'k/n (p%)'."""
    return f'{k}/{n} ({100 * k / n:.0f}%)' if n else 'n/a'


def summarise(case, runs):
    """Return one table row (dict of column -> text) and a list of failure lines."""
    truth0 = runs[0][1]
    n = len(runs)
    codes = Counter(str(r[2]) for r in runs)
    ok = [r for r in runs if r[5] is not None]
    verdicts = Counter(verdict(r[5]) for r in ok)
    exp = truth0['expected_verdict']
    right = verdicts.get(exp, 0)
    und = verdicts.get('undetermined', 0)
    wrong = len(ok) - right - und
    row = {'case': case, 'n': str(n),
           'exit codes': ' '.join(f'{k}:{v}' for k, v in sorted(codes.items())),
           'expect': exp, 'right/undet/wrong': f'{right}/{und}/{wrong}'}
    A, alpha = truth0['A'], truth0['alpha']
    if A is not None:
        ca = sum(covers((r[5].get('model') or {}).get('A_ci95'), A) for r in ok)
        cl = sum(covers((r[5].get('model') or {}).get('alpha_ci95'), alpha) for r in ok)
        errs = [abs((r[5].get('model') or {}).get('A', math.nan) - A) / A for r in ok
                if isinstance((r[5].get('model') or {}).get('A'), (int, float))]
        row['A cov'] = pct(ca, len(ok))
        row['alpha cov'] = pct(cl, len(ok))
        # The criterion: coverage where the tool gives no warning ('gaps' is
        # informational, so a run warned only with it counts as unwarned).
        quiet = [r for r in ok if not warning_codes(r[5]) - INFORMATIONAL]
        ca = sum(covers((r[5].get('model') or {}).get('A_ci95'), A) for r in quiet)
        cl = sum(covers((r[5].get('model') or {}).get('alpha_ci95'), alpha) for r in quiet)
        row['unwarned A/alpha cov'] = (f'{ca}/{len(quiet)}, {cl}/{len(quiet)}' if quiet
                                       else '-')
        row['med rel err A'] = f'{statistics.median(errs):.3f}' if errs else 'n/a'
    else:
        row['A cov'] = row['alpha cov'] = row['med rel err A'] = 'n/a'
        row['unwarned A/alpha cov'] = 'n/a'
    used = [samples(r[5], r[1]) for r in ok]
    used = [u for u in used if u[0] is not None]
    if used:
        tot = [u[1] for u in used if u[1] is not None]
        row['used/total'] = (f'{statistics.median([u[0] for u in used]):g}/'
                             f'{statistics.median(tot) if tot else "?":g}{used[0][2]}')
    else:
        row['used/total'] = 'n/a'
    warn = Counter()
    missing = Counter()
    for r in ok:
        codes_r = {w.get('code') for w in (r[5].get('warnings') or []) if isinstance(w, dict)}
        warn.update(codes_r)
        missing.update(c for c in r[1]['expected_warnings'] if c not in codes_r)
    row['warnings'] = ' '.join(f'{k}:{v}' for k, v in sorted(warn.items())) or '-'
    row['expected warnings missing'] = (
        ' '.join(f'{k}:{v}' for k, v in sorted(missing.items())) or '-')
    row['true dphi off pi'] = f'{truth0["derived"]["phase_offset_from_pi"]:+.3f}'
    row['median s'] = f'{statistics.median(r[4] for r in runs):.1f}'
    fails = [f'{case} seed {r[0]}: exit {r[2]}: {r[3]}' for r in runs if r[2] != 0]
    fails += [f'{case} seed {r[0]}: exit 0 but no readable JSON' for r in runs
              if r[2] == 0 and r[5] is None]
    return row, fails


def table(rows):
    """Return rows (list of dicts with the same keys) as a Markdown table."""
    keys = list(rows[0])
    out = ['| ' + ' | '.join(keys) + ' |', '|' + '---|' * len(keys)]
    out += ['| ' + ' | '.join(r[k] for k in keys) + ' |' for r in rows]
    return '\n'.join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--work', default=os.path.join(tempfile.gettempdir(),
                                                   'microball-independent'),
                    help='folder for the cases and the results (default: %(default)s)')
    ap.add_argument('--cases', help='comma-separated case names (default: all)')
    ap.add_argument('--seeds', type=int, help='seeds per case (default: per case, 10)')
    ap.add_argument('--quick', action='store_true',
                    help=f'cases {",".join(generate.QUICK)} with 3 seeds')
    ap.add_argument('--tool', default=DEFAULT_TOOL,
                    help='the microball executable (default: $MICROBALL or %(default)s)')
    ap.add_argument('--no-exposure', action='store_true',
                    help='never pass --exposure (default: pass the true exposure of blurred '
                         'cases)')
    ap.add_argument('--jobs', type=int, default=2, choices=(1, 2))
    ap.add_argument('--timeout', type=float, default=300.0, help='per analysis, s')
    ap.add_argument('--rescore', action='store_true',
                    help='run nothing: score the results already under --work')
    a = ap.parse_args(argv)
    jobs = generate.select(a.cases.split(',') if a.cases else None, a.seeds, a.quick)
    t0 = time.monotonic()
    if not a.rescore:
        generate.generate(a.work, jobs)
    tgen = time.monotonic() - t0
    print(f'generated/checked {len(jobs)} case files in {tgen:.0f} s under {a.work}',
          file=sys.stderr)

    def one(job):
        case, seed = job
        csv, tj = generate.paths(a.work, case, seed)
        truth = json.loads(tj.read_text())
        exposure = 0.0 if a.no_exposure else truth['camera']['exposure']
        if a.rescore:
            out = csv.with_suffix('.out.json')
            result = json.loads(out.read_text()) if out.exists() else None
            return case, (seed, truth, 0 if result else 'missing', '', 0.0, result)
        code, last, dt, result = analyze(a.tool, csv, exposure, a.timeout)
        print(f'{case} seed {seed}: exit {code} in {dt:.1f} s', file=sys.stderr)
        return case, (seed, truth, code, last, dt, result)

    order = sorted(jobs, key=lambda j: -generate.CASES[j[0]]['duration'])
    with ThreadPoolExecutor(max_workers=a.jobs) as pool:
        done = list(pool.map(one, order))
    by_case = {}
    for case, run in done:
        by_case.setdefault(case, []).append(run)
    rows, fails = [], []
    for case in dict.fromkeys(c for c, _ in jobs):
        runs = sorted(by_case[case], key=lambda r: r[0])
        row, f = summarise(case, runs)
        rows.append(row)
        fails += f
    ttot = time.monotonic() - t0
    text = [f'tool: {a.tool} ({tool_version(a.tool)}); '
            f'exposure passed: {"no" if a.no_exposure else "true value"}; '
            f'{len(jobs)} analyses; generation {tgen:.0f} s, total {ttot:.0f} s', '',
            table(rows)]
    if fails:
        text += ['', 'Non-zero exits:'] + [f'- {f}' for f in fails]
    report = '\n'.join(text)
    print(report)
    (Path(a.work) / 'table.md').write_text(report + '\n')


if __name__ == '__main__':
    main()
