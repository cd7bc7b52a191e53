"""Independent case generator for judging ``microball analyze`` (numpy + scipy only).

Run: ``python bench/independent/generate.py --out DIR [--cases a,b] [--seeds N] [--jobs 2]``.
Writes ``DIR/<case>/seed<k>.csv`` (``time,stator_position,slider_position``; s, m, m) and
``DIR/<case>/seed<k>.truth.json`` for each case and seed; skips files that already exist
with the same generator version.

Its own model of the rig (it shares no code with microball_ros):
- stator: crank-slider, x = r cos(th) + sqrt(l^2 - r^2 sin^2 th) - l, crank angle
  th(t) = th0 + w t (+ a slow sinusoidal speed variation when the case asks);
- slider: a_slid = -f(v_slid - v_stat, state), the friction per unit mass, integrated with
  a fixed-step classical RK4 at 0.1 ms (the stator velocity at the half steps is analytic);
- camera: frame n at mid-exposure time n / fps, value = the average of the position over
  the exposure (motion blur), plus white Gaussian noise on each position; optional slow
  slider drift (added to the measured slider position), gaps (missing rows or empty cells),
  dropped frames, duplicated stamps (a frame carrying its predecessor's stamp) and uniform
  +-1 ms stamp jitter (positions stay those of the true mid-exposure time).
"""

import argparse
from concurrent.futures import ProcessPoolExecutor
import json
import math
import os
from pathlib import Path
import zlib

import numpy as np
from scipy.integrate import cumulative_trapezoid
from scipy.signal import butter, sosfiltfilt

VERSION = 2
H = 1e-4  # RK4 step, s
UM = 1e-6
MM = 1e-3

PAPER_LAW = ('langevin', {'A': 1.2, 'alpha': 110.0})
BASE = {
    'law': PAPER_LAW,
    'r': 1.2 * MM, 'rod': 40.0, 'freq': 2.95, 'speed_var': 0.0, 'speed_var_freq': 0.2,
    'fps': 30.0, 'exposure': 0.0, 'noise': 2 * UM, 'duration': 30.0,
    'drift': 0.0, 'gaps': 0, 'gap_len': 0.5, 'gap_empty': False, 'drop': 0.0, 'dup': 0.0,
    'jitter': 0.0, 'seeds': 10, 'group': 'coverage',
}


def _case(**kw):
    c = dict(BASE)
    for key in kw:
        if key not in c:
            raise KeyError(key)
    c.update(kw)
    return c


CASES = {
    # Langevin, memoryless: A and alpha coverage is judged.
    'paper': _case(),
    'paper-blur': _case(exposure=1 / 60),
    'paper-short': _case(duration=10.0),
    'paper-long': _case(duration=600.0),
    'paper-blur-full-frame': _case(exposure=1 / 30),
    'long-120fps': _case(duration=600.0, fps=120.0, noise=1 * UM),
    'fast-camera': _case(fps=120.0, freq=5.0, r=2 * MM, noise=1 * UM, rod=200.0),
    'slow-linear': _case(fps=15.0, freq=0.5, r=3 * MM, noise=5 * UM, duration=120.0),
    'saturated': _case(law=('langevin', {'A': 1.2, 'alpha': 2000.0}), r=2 * MM, freq=5.0,
                       fps=60.0, rod=200.0),
    'nyquist-30fps-5hz': _case(freq=5.0, r=1.0 * MM),
    'nyquist-15fps': _case(fps=15.0),
    'nyquist-60fps-10hz': _case(fps=60.0, freq=10.0, r=0.5 * MM, noise=1 * UM),
    'high-noise': _case(noise=10 * UM),
    'fast-10hz-120fps': _case(fps=120.0, freq=10.0, r=0.5 * MM, noise=0.5 * UM, rod=60.0),
    'drift': _case(drift=20 * UM),
    'gaps': _case(gaps=3),
    'gaps-empty-cells': _case(gaps=3, gap_empty=True),
    'dropped-frames': _case(drop=0.02),
    'duplicated-stamps': _case(dup=0.01),
    'jitter': _case(jitter=1e-3),
    'crank-vary': _case(speed_var=0.03),
    'short-rod': _case(rod=5.0),
    'messy': _case(exposure=1 / 60, noise=5 * UM, drift=10 * UM, drop=0.01, jitter=1e-3,
                   speed_var=0.01),
    # Regimes of issue 13 the set above missed (15-120 fps, 0.5-10 Hz, 0.5-10 um, alpha 20 to
    # 3000 s/m).
    'slow-15fps-1.5hz': _case(fps=15.0, freq=1.5, r=2.4 * MM),
    'one-hz': _case(freq=1.0, r=3.5 * MM),
    'low-noise': _case(noise=0.5 * UM),
    'alpha-3000': _case(law=('langevin', {'A': 1.2, 'alpha': 3000.0})),
    'alpha-20': _case(law=('langevin', {'A': 1.2, 'alpha': 20.0}), r=3 * MM, freq=2.0),
    'viscous-short': _case(law=('viscous', {'c': 44.0}), duration=10.0, group='law'),
    # Other memoryless laws: the verdict is judged, not A/alpha.
    'viscous': _case(law=('viscous', {'c': 44.0}), group='law'),
    'coulomb-viscous': _case(law=('coulomb_viscous', {'Fc': 0.1, 'c': 25.0, 'v_eps': 2e-4}),
                             group='law'),
    'stribeck': _case(law=('stribeck', {'Fc': 0.1, 'Fs': 0.2, 'vs': 1.5e-3, 'c': 20.0,
                                        'v_eps': 2e-4}), group='law'),
    # Friction with memory: the verdict should be 'memory'.
    'lag-10ms': _case(law=('langevin_lag', {'A': 1.2, 'alpha': 110.0, 'tau': 0.010}),
                      group='memory'),
    'lag-40ms': _case(law=('langevin_lag', {'A': 1.2, 'alpha': 110.0, 'tau': 0.040}),
                      group='memory'),
    'lugre': _case(law=('lugre', {'sigma0': 2e3, 'sigma1': 40.0, 'sigma2': 10.0, 'Fc': 0.15,
                                  'Fs': 0.25, 'vs': 2e-3}), group='memory'),
    'dahl': _case(law=('dahl', {'sigma': 2e3, 'Fc': 0.25}), group='memory'),
}

QUICK = ['paper', 'saturated', 'nyquist-15fps', 'gaps', 'viscous', 'lag-40ms', 'lugre']
MEMORY_LAWS = {'langevin_lag', 'lugre', 'dahl'}


def langevin(u, A, alpha):
    """Return the modified Langevin friction A (coth(alpha u) - 1/(alpha u)), a scalar."""
    x = alpha * u
    ax = abs(x)
    if ax < 1e-2:
        x2 = x * x
        return A * x * (1.0 / 3.0 - x2 / 45.0 + 2.0 * x2 * x2 / 945.0)
    if ax > 30.0:
        return A * (math.copysign(1.0, x) - 1.0 / x)
    return A * (1.0 / math.tanh(x) - 1.0 / x)


def static_friction(name, p):
    """Return f(u), friction per unit mass (m/s^2) of a memoryless law at relative speed u."""
    if name == 'langevin':
        A, alpha = p['A'], p['alpha']
        return lambda u: langevin(u, A, alpha)
    if name == 'viscous':
        c = p['c']
        return lambda u: c * u
    if name == 'coulomb_viscous':
        fc, c, ve = p['Fc'], p['c'], p['v_eps']
        return lambda u: fc * math.tanh(u / ve) + c * u
    if name == 'stribeck':
        fc, fs, vs, c, ve = p['Fc'], p['Fs'], p['vs'], p['c'], p['v_eps']
        return lambda u: (fc + (fs - fc) * math.exp(-(u / vs) ** 2)) * math.tanh(u / ve) + c * u
    raise KeyError(name)


def static_friction_array(name, p, u):
    """Return the memoryless friction per unit mass of static_friction on an array u."""
    if name == 'langevin':
        x = p['alpha'] * u
        small = np.abs(x) < 1e-2
        xs = np.where(small, 1.0, x)
        x2 = x * x
        series = x * (1.0 / 3.0 - x2 / 45.0 + 2.0 * x2 * x2 / 945.0)
        return p['A'] * np.where(small, series, 1.0 / np.tanh(xs) - 1.0 / xs)
    if name == 'viscous':
        return p['c'] * u
    if name == 'coulomb_viscous':
        return p['Fc'] * np.tanh(u / p['v_eps']) + p['c'] * u
    if name == 'stribeck':
        g = p['Fc'] + (p['Fs'] - p['Fc']) * np.exp(-(u / p['vs']) ** 2)
        return g * np.tanh(u / p['v_eps']) + p['c'] * u
    raise KeyError(name)


def stator_motion(t, c, th0):
    """Return crank-slider stator position and velocity (m, m/s) at times t (array)."""
    r, rl, w = c['r'], c['rod'] * c['r'], 2 * math.pi * c['freq']
    dv, wv = c['speed_var'], 2 * math.pi * c['speed_var_freq']
    th = th0 + w * t
    thdot = np.full_like(t, w)
    if dv:
        th = th + w * dv / wv * np.sin(wv * t)
        thdot = w * (1 + dv * np.cos(wv * t))
    s, co = np.sin(th), np.cos(th)
    root = np.sqrt(rl * rl - r * r * s * s)
    x = r * co + root - rl
    dxdth = -r * s - r * r * s * co / root
    return x, dxdth * thdot


def integrate(c, vstat_half, n_steps):
    """RK4 of the slider at step H; vstat_half[j] is the stator velocity at j H / 2.

    Returns slider position, velocity and acceleration at the n_steps + 1 grid points.
    """
    name, p = c['law']
    xs = np.empty(n_steps + 1)
    vs = np.empty(n_steps + 1)
    acc = np.empty(n_steps + 1)
    sv = vstat_half.tolist()
    x, v, h = 0.0, sv[0], H
    if name not in MEMORY_LAWS:
        f = static_friction(name, p)
        xl, vl = [0.0] * (n_steps + 1), [0.0] * (n_steps + 1)
        for k in range(n_steps):
            xl[k], vl[k] = x, v
            s0, s1, s2 = sv[2 * k], sv[2 * k + 1], sv[2 * k + 2]
            k1 = -f(v - s0)
            v2 = v + 0.5 * h * k1
            k2 = -f(v2 - s1)
            v3 = v + 0.5 * h * k2
            k3 = -f(v3 - s1)
            v4 = v + h * k3
            k4 = -f(v4 - s2)
            x += h / 6 * (v + 2 * v2 + 2 * v3 + v4)
            v += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xl[n_steps], vl[n_steps] = x, v
        xs[:], vs[:] = xl, vl
        acc[:] = -static_friction_array(name, p, vs - np.asarray(sv[::2]))
        return xs, vs, acc
    # Laws with an internal state z: returns (dz/dt, friction per unit mass).
    if name == 'langevin_lag':
        A, alpha, tau = p['A'], p['alpha'], p['tau']

        def rhs(u, z):
            return (langevin(u, A, alpha) - z) / tau, z
    elif name == 'lugre':
        s0_, s1_, s2_ = p['sigma0'], p['sigma1'], p['sigma2']
        fc, fs, vsb = p['Fc'], p['Fs'], p['vs']

        def rhs(u, z):
            g = fc + (fs - fc) * math.exp(-(u / vsb) ** 2)
            zd = u - s0_ * abs(u) * z / g
            return zd, s0_ * z + s1_ * zd + s2_ * u
    elif name == 'dahl':
        sig, fc = p['sigma'], p['Fc']

        def rhs(u, z):
            return sig * (u - abs(u) * z / fc), z
    else:
        raise KeyError(name)
    z = 0.0
    xl, vl, al = [0.0] * (n_steps + 1), [0.0] * (n_steps + 1), [0.0] * (n_steps + 1)
    for k in range(n_steps):
        s0, s1, s2 = sv[2 * k], sv[2 * k + 1], sv[2 * k + 2]
        zd1, f1 = rhs(v - s0, z)
        xl[k], vl[k], al[k] = x, v, -f1
        v2, z2 = v - 0.5 * h * f1, z + 0.5 * h * zd1
        zd2, f2 = rhs(v2 - s1, z2)
        v3, z3 = v - 0.5 * h * f2, z + 0.5 * h * zd2
        zd3, f3 = rhs(v3 - s1, z3)
        v4, z4 = v - h * f3, z + h * zd3
        zd4, f4 = rhs(v4 - s2, z4)
        x += h / 6 * (v + 2 * v2 + 2 * v3 + v4)
        v -= h / 6 * (f1 + 2 * f2 + 2 * f3 + f4)
        z += h / 6 * (zd1 + 2 * zd2 + 2 * zd3 + zd4)
    xl[n_steps], vl[n_steps] = x, v
    al[n_steps] = -rhs(v - sv[2 * n_steps], z)[1]
    xs[:], vs[:], acc[:] = xl, vl, al
    return xs, vs, acc


def _sample(tg, xg, vg, t, exposure):
    """Sample a fine-grid position at times t: cubic Hermite, or its mean over the exposure."""
    if exposure <= 0:
        k = np.clip(((t - tg[0]) / H).astype(int), 0, len(tg) - 2)
        s = (t - tg[k]) / H
        h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
        h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
        return h00 * xg[k] + h10 * H * vg[k] + h01 * xg[k + 1] + h11 * H * vg[k + 1]
    cum = cumulative_trapezoid(xg, tg, initial=0.0)
    lo = np.interp(t - exposure / 2, tg, cum)
    hi = np.interp(t + exposure / 2, tg, cum)
    return (hi - lo) / exposure


def _fundamental(t, y, f):
    return np.mean(y * np.exp(-2j * math.pi * f * t))


def seed_rng(case, seed):
    """Return the case's random generator for one seed (stable across runs and machines)."""
    return np.random.default_rng([zlib.crc32(case.encode()), seed])


def simulate(case, seed):
    """Simulate one case and seed: return (rows as an (n, 3) object array, truth dict)."""
    c = CASES[case]
    rng = seed_rng(case, seed)
    th0 = rng.uniform(0, 2 * math.pi)
    fps, duration, exposure = c['fps'], c['duration'], c['exposure']
    warm = max(3.0, 3.0 / c['freq'])
    n_frames = int(round(duration * fps))
    t_end = (n_frames - 1) / fps + exposure / 2 + 0.01
    n_steps = int(math.ceil((t_end + warm) / H))
    th_half = -warm + 0.5 * H * np.arange(2 * n_steps + 1)
    xstat_half, vstat_half = stator_motion(th_half, c, th0)
    xs, vs, acc = integrate(c, vstat_half, n_steps)
    tg = th_half[::2]
    xstat, vstat = xstat_half[::2], vstat_half[::2]
    # Re-centre the slider on its record mean (it starts wherever; only motion matters).
    t = np.arange(n_frames) / fps
    stator = _sample(tg, xstat, vstat, t, exposure)
    slider = _sample(tg, xs, vs, t, exposure)
    offset = slider.mean()
    slider = slider - offset
    # Truth on the fine grid over the record.
    # Fundamentals over the largest whole number of stator periods inside the record.
    f0 = c['freq']
    rec = (tg >= 0) & (tg < math.floor(t[-1] * f0) / f0)
    urel = vs[rec] - vstat[rec]
    a1 = _fundamental(tg[rec], acc[rec], f0)
    u1 = _fundamental(tg[rec], urel, f0)
    dphi = abs(math.remainder(np.angle(a1) - np.angle(u1), 2 * math.pi))
    s1 = _fundamental(tg[rec], xs[rec], f0)
    st1 = _fundamental(tg[rec], xstat[rec], f0)
    # Camera artefacts.
    noise = c['noise']
    stator = stator + rng.normal(0, noise, n_frames)
    slider = slider + rng.normal(0, noise, n_frames)
    if c['drift']:
        w = np.cumsum(rng.normal(0, 1, n_frames))
        sos = butter(2, min(0.05, 0.2 * fps / 2), fs=fps, output='sos')
        d = sosfiltfilt(sos, w)
        d -= d.mean()
        d *= c['drift'] / max(np.std(d), 1e-300)
        slider = slider + d
    stamps = t.copy()
    if c['jitter']:
        stamps = stamps + rng.uniform(-c['jitter'], c['jitter'], n_frames)
    keep = np.ones(n_frames, bool)
    empty = np.zeros(n_frames, bool)
    gap_spans = []
    if c['gaps']:
        n_gap = int(round(c['gap_len'] * fps))
        # Non-overlapping gaps, away from the record's ends.
        slots = np.sort(rng.choice(np.arange(1, 2 * c['gaps'], 2), c['gaps'], replace=False))
        for slot in slots:
            centre = int(n_frames * (slot + rng.uniform(-0.3, 0.3)) / (2 * c['gaps']))
            a, b = max(1, centre - n_gap // 2), min(n_frames - 1, centre + n_gap - n_gap // 2)
            gap_spans.append([float(t[a]), float(t[b - 1])])
            if c['gap_empty']:
                empty[a:b] = True
            else:
                keep[a:b] = False
    dup = np.zeros(n_frames, bool)
    if c['dup']:
        dup[1:] = rng.random(n_frames - 1) < c['dup']
        dup[1:] &= ~dup[:-1]
        stamps[dup] = stamps[np.flatnonzero(dup) - 1]
    if c['drop']:
        keep[1:-1] &= rng.random(n_frames - 2) >= c['drop']
    rows = []
    for i in np.flatnonzero(keep):
        if empty[i]:
            rows.append((stamps[i], None, None))
        else:
            rows.append((stamps[i], stator[i], slider[i]))
    name, p = c['law']
    memory = name in MEMORY_LAWS
    upeak = float(np.max(np.abs(urel)))
    regimes = []
    half = fps / 2
    if any(k * c['freq'] >= 0.8 * half for k in (2, 3)):
        regimes.append('near-nyquist')
    if 'alpha' in p:
        if p['alpha'] * upeak >= 5:
            regimes.append('saturated')
        elif p['alpha'] * upeak <= 1:
            regimes.append('linear')
    if c['exposure']:
        regimes.append('blur')
    if noise >= 5 * UM:
        regimes.append('high-noise')
    for key, label in (('drift', 'drift'), ('gaps', 'gaps'), ('drop', 'dropped-frames'),
                       ('dup', 'duplicated-stamps'), ('jitter', 'jitter'),
                       ('speed_var', 'crank-vary')):
        if c[key]:
            regimes.append(label)
    if c['gap_empty']:
        regimes.append('empty-cells')
    if duration <= 15:
        regimes.append('short')
    if duration >= 300:
        regimes.append('long')
    if memory:
        regimes.append('memory')
    expected_warnings = [w for w in ('near-nyquist', 'saturated', 'gaps') if w in regimes]
    truth = {
        'generator': 'bench/independent/generate.py', 'version': VERSION,
        'case': case, 'seed': seed, 'group': c['group'],
        'law': {'name': name, 'params': p}, 'memory': memory,
        'expected_verdict': 'memory' if memory else 'memoryless',
        'A': p.get('A') if name == 'langevin' else None,
        'alpha': p.get('alpha') if name == 'langevin' else None,
        'underlying_A': p.get('A'), 'underlying_alpha': p.get('alpha'),
        'regimes': regimes, 'expected_warnings': expected_warnings,
        'stator': {'crank_radius': c['r'], 'rod_length': c['rod'] * c['r'],
                   'frequency': c['freq'], 'crank_phase0': th0,
                   'speed_variation': c['speed_var'],
                   'speed_variation_frequency': c['speed_var_freq']},
        'camera': {'fps': fps, 'exposure': exposure, 'noise': noise,
                   'jitter': c['jitter'], 'drop_probability': c['drop'],
                   'duplicate_probability': c['dup'], 'drift_rms': c['drift'],
                   'gap_spans': gap_spans, 'gaps_as_empty_cells': c['gap_empty']},
        'duration': duration, 'frames': n_frames, 'rows': len(rows),
        'rows_with_positions': int(sum(r[1] is not None for r in rows)),
        'duplicated_stamps': int(dup[keep].sum()),
        'rk4_step': H, 'warmup': warm,
        'derived': {
            'relative_velocity_peak': upeak,
            'alpha_times_peak': p['alpha'] * upeak if 'alpha' in p else None,
            'true_phase_difference': dphi,
            'phase_offset_from_pi': math.pi - dphi,
            'slider_fundamental_amplitude': 2 * abs(s1),
            'stator_fundamental_amplitude': 2 * abs(st1),
            'slider_stator_phase': abs(math.remainder(np.angle(st1) - np.angle(s1),
                                                      2 * math.pi)),
            'acceleration_peak': float(np.max(np.abs(acc[rec]))),
        },
    }
    return rows, truth


def paths(out, case, seed):
    """Return the (csv, truth json) paths of one case and seed under out."""
    d = Path(out) / case
    return d / f'seed{seed}.csv', d / f'seed{seed}.truth.json'


def write(out, case, seed, force=False):
    """Simulate and write one case and seed unless it already exists; return the csv path."""
    csv, tj = paths(out, case, seed)
    if not force and csv.exists() and tj.exists():
        try:
            if json.loads(tj.read_text()).get('version') == VERSION:
                return csv
        except (OSError, ValueError):
            pass
    rows, truth = simulate(case, seed)
    csv.parent.mkdir(parents=True, exist_ok=True)
    lines = ['time,stator_position,slider_position']
    for t, a, b in rows:
        if a is None:
            lines.append(f'{t:.6f},,')
        else:
            lines.append(f'{t:.6f},{a:.9e},{b:.9e}')
    tmp = csv.with_suffix('.tmp')
    tmp.write_text('\n'.join(lines) + '\n')
    os.replace(tmp, csv)
    tj.write_text(json.dumps(truth, indent=1) + '\n')
    return csv


def select(cases=None, seeds=None, quick=False):
    """Return [(case, seed)] for a selection: named cases (default all, or QUICK)."""
    names = cases or (QUICK if quick else list(CASES))
    for n in names:
        if n not in CASES:
            raise SystemExit(f'unknown case {n!r}; known: {", ".join(CASES)}')
    return [(n, s) for n in names
            for s in range(seeds if seeds is not None else (3 if quick else CASES[n]['seeds']))]


def generate(out, jobs, force=False):
    """Write every (case, seed) of jobs with a pool of at most 2 processes."""
    jobs = sorted(jobs, key=lambda j: -CASES[j[0]]['duration'])
    with ProcessPoolExecutor(max_workers=2) as pool:
        futures = [pool.submit(write, out, c, s, force) for c, s in jobs]
        for f in futures:
            f.result()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', required=True, help='output folder')
    ap.add_argument('--cases', help='comma-separated case names (default: all)')
    ap.add_argument('--seeds', type=int, help='seeds per case (default: per case, 10)')
    ap.add_argument('--quick', action='store_true', help=f'cases {",".join(QUICK)}, 3 seeds')
    ap.add_argument('--force', action='store_true', help='rewrite existing files')
    ap.add_argument('--list', action='store_true', help='list the cases and exit')
    a = ap.parse_args(argv)
    if a.list:
        for n, c in CASES.items():
            print(f'{n:22s} {c["group"]:8s} {c["law"][0]:16s} {c["freq"]:5.2f} Hz '
                  f'{c["r"] * 1e3:.1f} mm {c["fps"]:5.0f} fps {c["duration"]:5.0f} s')
        return
    jobs = select(a.cases.split(',') if a.cases else None, a.seeds, a.quick)
    generate(a.out, jobs, a.force)
    print(f'wrote {len(jobs)} cases under {a.out}')


if __name__ == '__main__':
    main()
