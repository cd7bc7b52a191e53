#!/usr/bin/env python3
"""Run `microball track` (default options) on every case of out/ and score it against truth.csv.

Adapted from bench/tracking_videos_blind/evaluate.py for blind set 6 (truth columns stator_x /
slider_x, any video container or frame sequence, colour videos scored on grey, plain-plate target
max(0.03 px, 1.5 x CRB)).  Also scores a simple template-matching baseline (bn = frames it
reported with visible >= 0.5).  ``in2sig``: the share of the judged frames whose error is within
two of the standard errors the tracker reports.

usage: evaluate.py [case ...]     (prints the table, writes results.txt and out/<case>/track.csv)
"""
import csv
import json
import os
import subprocess
import sys
import time

import cv2
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, 'out')
MICROBALL = os.path.join(os.path.dirname(sys.executable), 'microball')
MARKS = ('stator', 'slider')


def load_truth(d):
    T = {m: [] for m in MARKS}
    V = {m: [] for m in MARKS}
    with open(os.path.join(d, 'truth.csv')) as fh:
        for r in csv.DictReader(fh):
            for m in MARKS:
                T[m].append(float(r[f'{m}_x']) if r[f'{m}_x'] else np.nan)
                V[m].append(float(r[f'{m}_visible']))
    return {m: np.array(T[m]) for m in MARKS}, {m: np.array(V[m]) for m in MARKS}


def frames_of(d, meta):
    """Frames as float32 grey images (colour converted with cv2's BGR2GRAY weights)."""
    def grey(fr):
        if fr.ndim == 3:
            fr = cv2.cvtColor(fr, cv2.COLOR_BGR2GRAY) if meta.get('color') else fr[..., 0]
        return fr.astype(np.float32)
    path = os.path.join(d, meta['video'])
    if os.path.isdir(path):
        for f in sorted(os.listdir(path)):
            yield grey(cv2.imread(os.path.join(path, f), cv2.IMREAD_UNCHANGED))
    else:
        cap = cv2.VideoCapture(path)
        while True:
            ok, fr = cap.read()
            if not ok:
                break
            yield grey(fr)
        cap.release()


def run_tracker(d, meta):
    video = os.path.join(d, meta['video'])
    out = os.path.join(d, 'track.csv')
    if os.path.exists(out):
        os.remove(out)
    cmd = ['nice', '-n', '10', MICROBALL, 'track', video,
           '--slider-roi', meta['rois']['slider'], '--stator-roi', meta['rois']['stator'],
           '--meters-per-pixel', repr(meta['meters_per_pixel']), '--fps', repr(float(meta['fps'])),
           '--exposure', repr(meta['exposure']), '--output', out]
    t = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True)
    dt = time.time() - t
    n = meta['frames']
    pos = {m: np.full(n, np.nan) for m in MARKS}
    sigma = {m: np.full(n, np.nan) for m in MARKS}
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ['(no stderr)'])[-1]
        return pos, sigma, f'exit {p.returncode}: {last}', dt
    mpp = meta['meters_per_pixel']
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        i = int(round((float(r['time']) - meta['exposure'] / 2) * meta['fps']))
        if not 0 <= i < n:
            continue
        for m in MARKS:
            v = r.get(f'{m}_position', '')
            if v not in ('', None) and v.lower() != 'nan':
                pos[m][i] = float(v) / mpp
                sigma[m][i] = float(r.get(f'{m}_sigma') or 'nan') / mpp
    note = '' if len(rows) == n else f'{len(rows)} rows for {n} frames'
    return pos, sigma, note, dt


def baseline(d, meta, T, V):
    """Track with cv2.matchTemplate (TM_CCOEFF_NORMED) as a reference.

    The template is cut around the known position in the clear frame with the least motion;
    parabolic sub-pixel peak; a position is reported when score > 0.5.
    """
    n = meta['frames']
    frames = list(frames_of(d, meta))
    pos = {m: np.full(n, np.nan) for m in MARKS}
    for m in MARKS:
        mk = meta['marks'][m]
        hx, hy = mk['half_w'], mk['half_h']
        t = T[m]
        speed = np.abs(np.gradient(np.nan_to_num(t)))
        speed[(V[m] < 1) | ~np.isfinite(t)] = np.inf
        speed[0] = speed[-1] = np.inf
        ref = int(np.argmin(speed))
        cx, cy = int(round(t[ref])), int(round(mk['y']))
        ax, ay = int(np.ceil(hx)) + 6, int(np.ceil(hy)) + 6
        tpl = frames[ref][cy - ay:cy + ay + 1, cx - ax:cx + ax + 1]
        X, Y, W, H = map(int, meta['rois'][m].split(','))
        for i, fr in enumerate(frames):
            R = cv2.matchTemplate(fr[Y:Y + H, X:X + W], tpl, cv2.TM_CCOEFF_NORMED)
            _, mx, _, (px, py) = cv2.minMaxLoc(R)
            if mx < 0.5:
                continue
            dx = 0.0
            if 0 < px < R.shape[1] - 1:
                a, b, c = R[py, px - 1], R[py, px], R[py, px + 1]
                den = a - 2 * b + c
                if den < 0:
                    dx = 0.5 * (a - c) / den
            pos[m][i] = X + px + ax + dx + (t[ref] - cx)
    return pos


def score(est, t, v, sigma=None):
    """Error statistics; with ``sigma`` (px per frame), the share within two of them."""
    rep = np.isfinite(est)
    good = rep & (v >= 0.5) & np.isfinite(t)
    anyv = rep & (v > 0) & np.isfinite(t)
    e = est - t
    s = {}
    s['n'] = int(good.sum())
    s['rms'] = float(np.sqrt(np.mean(e[good] ** 2))) if good.any() else np.nan
    s['bias'] = float(np.mean(e[good])) if good.any() else np.nan
    s['max'] = float(np.max(np.abs(e[anyv]))) if anyv.any() else np.nan
    s['gross'] = int((np.abs(e[anyv]) > 2).sum())
    clear = v == 1
    s['clear'] = int(clear.sum())
    s['lost'] = int((clear & ~rep).sum())
    s['covered'] = int((rep & (v == 0)).sum())
    s['in2'] = (float(np.mean(np.abs(e[good]) <= 2 * sigma[good]))
                if sigma is not None and good.any() else np.nan)
    return s


def main():
    names = sys.argv[1:] or sorted(os.listdir(OUT))
    hdr = (f"{'case':33s} {'mark':6s} {'cat':8s} {'n':>4s} {'RMS':>7s} {'bias':>8s} "
           f"{'max':>7s} {'lost':>5s} {'covd':>4s} {'>2px':>4s} | "
           f"{'bn':>4s} {'bRMS':>7s} {'bbias':>8s} {'bmax':>7s} | "
           f"{'CRB':>6s} {'RMS/CRB':>7s} {'in2sig':>6s} {'target':>6s}  verdict")
    lines = [hdr, '-' * len(hdr)]
    print(hdr)
    print('-' * len(hdr), flush=True)
    fails = []
    for nm in names:
        d = os.path.join(OUT, nm)
        if not os.path.exists(os.path.join(d, 'case.json')):
            continue
        meta = json.load(open(os.path.join(d, 'case.json')))
        T, V = load_truth(d)
        pos, sigma, note, dt = run_tracker(d, meta)
        bpos = baseline(d, meta, T, V)
        for m in MARKS:
            s = score(pos[m], T[m], V[m], sigma[m])
            b = score(bpos[m], T[m], V[m])
            crb = meta.get('crb_px', {}).get(m)
            target = max(0.03, 1.5 * crb) if meta['category'] == 'plain' else 0.1
            why = []
            if note.startswith('exit'):
                why.append('tracker failed')
            else:
                if not s['rms'] <= target:
                    why.append(f'RMS>{target:.3g}'
                               + (' (CRB %.3f>target)' % crb if crb and crb > target else ''))
                if not s['max'] <= 2:
                    why.append('err>2px')
                if s['lost'] > 0.01 * s['clear']:
                    why.append('lost>1%')
                if s['covered'] > 0:
                    why.append('covered>0')
            verdict = 'PASS' if not why else 'FAIL: ' + ', '.join(why)
            if why:
                fails.append((nm, m, verdict))
            ln = (f"{nm:33s} {m:6s} {meta['category']:8s} {s['n']:4d} {s['rms']:7.4f} "
                  f"{s['bias']:+8.4f} {s['max']:7.3f} {s['lost']:5d} {s['covered']:4d} "
                  f"{s['gross']:4d} | {b['n']:4d} {b['rms']:7.4f} {b['bias']:+8.4f} "
                  f"{b['max']:7.3f} | "
                  f"{(crb or float('nan')):6.4f} {s['rms'] / (crb or float('nan')):7.2f} "
                  f"{100 * s['in2']:5.0f}% {target:6.3f}  {verdict}")
            print(ln, flush=True)
            lines.append(ln)
        extra = f"  ({nm}: tracker {dt:.1f}s{'; ' + note if note else ''})"
        print(extra, flush=True)
        lines.append(extra)
    with open(os.path.join(HERE, 'results.txt'), 'w') as fh:
        fh.write('\n'.join(lines) + '\n')
    print(f'\n{len(fails)} mark(s) miss a target')


if __name__ == '__main__':
    main()
