#!/usr/bin/env python3
"""Independent renderer of a MEMS microball-bearing view (stator above, slider below).

Physics of one frame:
  * each plate is a fine reflectance image (cells of 1/Q px along x, 1/QY px along y,
    marks drawn with SSxSS sub-samples per cell, so edges are anti-aliased at 1/16 px);
  * plate rows are averaged over each pixel's height (no y motion);
  * along x the pixel-area integral is exact: with C(u) = integral of the plate along x
    (piecewise linear, exact for piecewise constant cells) a pixel k sees
    C(k+0.5-s) - C(k-0.5-s) for plate shift s; the exposure is NT (=512) mid-point
    samples of s(t); the sum over samples is one sparse convolution of C done by FFT;
  * occluders (image space), static dust (multiplicative, image space), illumination
    (flicker, drifting gradient), optics blur (Gaussian or pill-box), shot (Poisson)
    + read noise, quantisation.
Truth x = mark centre (centre of its symmetric shape, placed on a symmetric position of
the fine grid) + mean of the same NT samples of s(t) that were rendered.
"""
import json
import os
import shutil
import sys
import time

import cv2
import numpy as np
import scipy.fft as sfft
from scipy.ndimage import gaussian_filter

Q = 4      # fine cells per px along x
QY = 4     # fine rows per px along y
SS = 4     # sub-samples per fine cell (each axis) when drawing marks / occluders
NT = 512   # time samples per exposure
HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, 'out')


# ---------------------------------------------------------------- motion
class Motion:
    """periodic displacement as a sum of harmonics (complex coefficients c_k, k>=1)."""

    def __init__(self, f, coeffs):
        self.f = f
        self.c = np.asarray(coeffs, complex)

    def __call__(self, t):
        """Return the displacement at time(s) t (same shape as t)."""
        t = np.asarray(t, float)
        k = np.arange(1, len(self.c) + 1)
        ph = np.exp(1j * 2 * np.pi * self.f * np.multiply.outer(t, k))
        return (ph * self.c).real.sum(-1)


def crank_motion(f, r, lr, phase, K=16):
    n = 4096
    th = 2 * np.pi * np.arange(n) / n
    rod = lr * r   # connecting-rod length
    x = r * np.cos(th + phase) + np.sqrt(rod * rod - (r * np.sin(th + phase)) ** 2)
    X = np.fft.fft(x) / n
    c = 2 * X[1:K + 1]          # real part of sum c_k e^{ik th}
    return Motion(f, c)


def slider_from(stator, gain, tau, h3, psi3):
    k = np.arange(1, len(stator.c) + 1)
    H = gain / (1 + 1j * 2 * np.pi * stator.f * k * tau)
    c = stator.c * H
    c = c.copy()
    c[2] += h3 * abs(stator.c[0]) * np.exp(1j * psi3)
    return Motion(stator.f, c)


# ---------------------------------------------------------------- mark shapes
def profile(kind, p, du, dv):
    a = np.abs(du)
    b = np.abs(dv)
    if kind == 'rect':
        return ((a <= p['w'] / 2) & (b <= p['h'] / 2)).astype(float)
    if kind == 'disc':
        return (du * du + dv * dv <= p['r'] ** 2).astype(float)
    if kind == 'ring':
        r2 = du * du + dv * dv
        return ((r2 <= p['ro'] ** 2) & (r2 >= p['ri'] ** 2)).astype(float)
    if kind == 'cross':
        L, t = p['L'], p['t']
        return (((a <= L / 2) & (b <= t / 2)) | ((a <= t / 2) & (b <= L / 2))).astype(float)
    if kind == 'bars':
        w, h, g = p['w'], p['h'], p['gap']
        return ((a >= g / 2) & (a <= g / 2 + w) & (b <= h / 2)).astype(float)
    if kind == 'gauss':
        r2 = du * du + dv * dv
        s = p['sigma']
        return np.where(r2 <= (4 * s) ** 2, np.exp(-r2 / (2 * s * s)), 0.0)
    raise ValueError(kind)


def half_extent(kind, p):
    if kind == 'rect':
        return p['w'] / 2, p['h'] / 2
    if kind == 'disc':
        return p['r'], p['r']
    if kind == 'ring':
        return p['ro'], p['ro']
    if kind == 'cross':
        return p['L'] / 2, p['L'] / 2
    if kind == 'bars':
        return p['gap'] / 2 + p['w'], p['h'] / 2
    if kind == 'gauss':
        return 3 * p['sigma'], 3 * p['sigma']
    raise ValueError(kind)


# ---------------------------------------------------------------- plate
class Plate:
    """Render one plate (reflectance on a fine grid, with its mark) at any shift along x."""

    def __init__(self, W, r0, r1, M, base, mark, tex, rng, optics=None):
        self.W, self.r0, self.r1, self.M = W, r0, r1, M
        self.U0 = -0.5 - M
        self.ncell = (W + 2 * M) * Q
        nyf = (r1 - r0) * QY
        # fine cell centres
        uc = self.U0 + (np.arange(self.ncell) + 0.5) / Q
        vc = r0 - 0.5 + (np.arange(nyf) + 0.5) / QY
        P = np.full((nyf, self.ncell), float(base), np.float64)
        # texture that moves with the plate (multiplicative)
        if tex.get('std', 0) > 0:
            n = rng.standard_normal((nyf, self.ncell)).astype(np.float32)
            n = gaussian_filter(n, (tex['grain'] * QY / 2, tex['grain'] * Q / 2))
            n /= n.std()
            P *= 1 + tex['std'] * n
        if tex.get('scratches', 0):
            for _ in range(tex['scratches']):
                v = rng.uniform(r0 + 3, r1 - 3)
                L = rng.uniform(40, 400)
                u0 = rng.uniform(uc[0], uc[-1] - L)
                dep = rng.uniform(0.03, 0.08) * rng.choice([-1, 1])
                wv = rng.uniform(0.4, 1.2)
                rows = np.abs(vc - v) <= wv / 2
                cols = (uc >= u0) & (uc <= u0 + L)
                P[np.ix_(rows, cols)] *= (1 - dep)
        # the mark (after texture for bright marks = emitted light, before for etched)
        kind, p = mark['kind'], mark['p']
        hx, hy = half_extent(kind, p)
        hx += 2
        hy += 2
        if kind == 'gauss':
            hx = hy = 4 * p['sigma'] + 1
        ci = np.nonzero((uc >= mark['u'] - hx) & (uc <= mark['u'] + hx))[0]
        ri = np.nonzero((vc >= mark['v'] - hy) & (vc <= mark['v'] + hy))[0]
        off = (np.arange(SS) + 0.5) / SS - 0.5
        du = (uc[ci][None, :, None, None] + off[None, None, None, :] / Q) - mark['u']
        dv = (vc[ri][:, None, None, None] + off[None, None, :, None] / QY) - mark['v']
        cov = profile(kind, p, du + 0 * dv, dv + 0 * du).mean(axis=(2, 3))
        sub = P[np.ix_(ri, ci)]
        if mark['polarity'] == 'dark':
            sub *= 1 - mark['depth'] * cov
        else:
            sub += mark['amp'] * cov
        P[np.ix_(ri, ci)] = sub
        self.mark = mark
        # optics PSF applied to the (static) plate on the fine grid: it commutes with the
        # translation and the pixel integration, so this is the physical order
        if optics is not None:
            if optics.get('defocus'):
                P = cv2.filter2D(P, cv2.CV_64F, disc_kernel_fine(optics['defocus']),
                                 borderType=cv2.BORDER_REPLICATE)
            else:
                P = gaussian_filter(P, (optics['psf_sigma'] * QY, optics['psf_sigma'] * Q),
                                    mode='nearest', truncate=5)
        # average over pixel height
        Prow = P.reshape(r1 - r0, QY, self.ncell).mean(1)
        self.Prow = Prow
        Ce = np.zeros((r1 - r0, self.ncell + 1))
        Ce[:, 1:] = np.cumsum(Prow, axis=1) / Q
        # detrend (exact, linear)
        Ce -= Ce[:, -1:] * np.arange(self.ncell + 1)[None, :] / self.ncell
        self.trend = Prow.sum(1) / Q / self.ncell     # slope removed per px of u (per 1/Q cell *Q)
        self.Ce = Ce
        self.nfft = None

    def prepare(self, smin, smax):
        """Precompute the FFT of the plate integral C for shifts between smin and smax."""
        self.dmin = int(np.floor(smin * Q)) - 1
        Lk = int(np.floor(smax * Q)) + 2 - self.dmin + 1
        self.Lk = Lk
        self.nfft = sfft.next_fast_len(self.Ce.shape[1] + Lk, real=True)
        self.CF = sfft.rfft(self.Ce, n=self.nfft, axis=1, workers=1)
        self.Gb = (np.arange(self.W + 1) + self.M) * Q

    def render(self, s):
        """Mean over samples s of the pixel-integrated plate; returns (rows, W)."""
        s = np.asarray(s, float)
        sq = s * Q
        a = np.floor(sq).astype(int)
        f = sq - a
        w = np.zeros(self.Lk)
        np.add.at(w, a - self.dmin, (1 - f) / len(s))
        np.add.at(w, a + 1 - self.dmin, f / len(s))
        R = sfft.irfft(self.CF * sfft.rfft(w, n=self.nfft), n=self.nfft, axis=1, workers=1)
        Rb = R[:, self.Gb - self.dmin]
        img = np.diff(Rb, axis=1)
        # add back the removed linear trend of C: trend*(u) => pixel gets trend*Q*(1/Q)*...
        # exact: C_true(g) = Ce(g) + T*g/ncell*...
        #   -> difference over one pixel (Q cells) = T_total*Q/ncell
        img += (self.Ce_tot_per_px)[:, None]
        return img

    def finalize(self):
        """Store the per-pixel share of C's total, which the detrend removed."""
        # total of C over the plate, removed by the detrend; per pixel difference = tot*Q/ncell
        tot = self.Prow.sum(1) / Q
        self.Ce_tot_per_px = tot * Q / self.ncell


# ---------------------------------------------------------------- occluder
def ellipse_alpha(X, Y, oc, yc):
    return (((X - oc['xc']) / oc['ax']) ** 2 + ((Y - yc) / oc['ay']) ** 2 <= 1).astype(float)


def occluder_y(oc, i):
    """Centre y of the occluder at frame i, or None when absent."""
    k = i - oc['start']
    if k < 0 or k > oc['n']:
        return None
    u = k / oc['n']
    if oc['mode'] == 'total':
        return oc['y0'] + (oc['y1'] - oc['y0']) * u
    return oc['y0'] + (oc['y1'] - oc['y0']) * (1 - abs(2 * u - 1))


def occluder_alpha_img(oc, yc, W, H):
    a = np.zeros((H, W))
    x0 = int(max(0, np.floor(oc['xc'] - oc['ax'] - 1)))
    x1 = int(min(W, np.ceil(oc['xc'] + oc['ax'] + 2)))
    y0 = int(max(0, np.floor(yc - oc['ay'] - 1)))
    y1 = int(min(H, np.ceil(yc + oc['ay'] + 2)))
    if x1 <= x0 or y1 <= y0:
        return a
    off = (np.arange(SS) + 0.5) / SS - 0.5
    X = np.arange(x0, x1)[None, :, None, None] + off[None, None, None, :]
    Y = np.arange(y0, y1)[:, None, None, None] + off[None, None, :, None]
    a[y0:y1, x0:x1] = ellipse_alpha(X, Y, oc, yc).mean(axis=(2, 3))
    return a


def visibility(mark, xc, oc, yc):
    if oc is None or yc is None:
        return 1.0
    kind, p = mark['kind'], mark['p']
    hx, hy = half_extent(kind, p)
    if kind == 'gauss':
        hx = hy = 4 * p['sigma']
    g = 1.0 / 16
    du = np.arange(-hx - 1, hx + 1 + 1e-9, g)
    dv = np.arange(-hy - 1, hy + 1 + 1e-9, g)
    DU, DV = np.meshgrid(du, dv)
    m = profile(kind, p, DU, DV)
    al = ellipse_alpha(DU + xc, DV + mark['v'], oc, yc)
    return float((m * (1 - al)).sum() / m.sum())


# ---------------------------------------------------------------- case rendering
def disc_kernel(R):
    n = int(np.ceil(R)) + 1
    off = (np.arange(8) + 0.5) / 8 - 0.5
    ys, xs = np.mgrid[-n:n + 1, -n:n + 1]
    X = xs[..., None, None] + off[None, None, None, :]
    Y = ys[..., None, None] + off[None, None, :, None]
    k = ((X * X + Y * Y) <= R * R).mean(axis=(2, 3))
    return k / k.sum()


def disc_kernel_fine(R):
    # pill-box of radius R px sampled on the fine grid (Q per px in x, QY per px in y)
    nx = int(np.ceil(R * Q)) + 1
    ny = int(np.ceil(R * QY)) + 1
    off = (np.arange(4) + 0.5) / 4 - 0.5
    ys, xs = np.mgrid[-ny:ny + 1, -nx:nx + 1]
    X = (xs[..., None, None] + off[None, None, None, :]) / Q
    Y = (ys[..., None, None] + off[None, None, :, None]) / QY
    k = ((X * X + Y * Y) <= R * R).mean(axis=(2, 3))
    return k / k.sum()


def blur(img, c):
    if c.get('defocus'):
        return cv2.filter2D(img, cv2.CV_64F, disc_kernel(c['defocus']),
                            borderType=cv2.BORDER_REFLECT)
    return gaussian_filter(img, c['psf_sigma'], mode='reflect', truncate=5)


def render_case(c, outdir, noiseless=False, check=False):
    rng = np.random.default_rng(c['seed'])
    W, H = c['size']
    fps, nfr = c['fps'], c['frames']
    texp = c['exp_frac'] / fps
    st = crank_motion(c['f'], c['r'], c['lr'], rng.uniform(0, 2 * np.pi))
    sl = slider_from(st, c['sl_gain'], c['sl_tau'], c['sl_h3'], rng.uniform(0, 2 * np.pi))
    t0 = rng.uniform(0, 1 / c['f'])
    tj = (np.arange(NT) + 0.5) / NT * texp
    times = t0 + np.arange(nfr)[:, None] / fps + tj[None, :]
    S = {'stator': st(times), 'slider': sl(times)}
    if c.get('static'):   # True: both plates still; or a list of the plates that do not move
        st_ = c['static'] if isinstance(c['static'], (list, tuple)) else list(S)
        S = {k: (np.zeros_like(v) if k in st_ else v) for k, v in S.items()}
    gap = c.get('gap', 20)
    rows = {'stator': (0, H // 2 - gap // 2), 'slider': (H // 2 + gap // 2, H)}
    plates, truth, rois = {}, {}, {}
    blur_ext = 3 * c.get('psf_sigma', 1.0) + (c.get('defocus') or 0)
    for name in ('stator', 'slider'):
        m = dict(c['marks'][name])
        r0, r1 = rows[name]
        s = S[name]
        M = int(np.ceil(np.abs(s).max())) + 3
        # symmetric position on the fine grid: multiple of 1/(2Q) px
        m['u'] = round((W / 2 - (s.max() + s.min()) / 2 + rng.uniform(-8, 8)) * 2 * Q) / (2 * Q)
        m['v'] = round(((r0 + r1) / 2 + rng.uniform(-10, 10)) * 2 * QY) / (2 * QY)
        tex = c.get('tex', {})
        tex = tex.get(name, tex) if isinstance(tex, dict) and name in tex else tex
        pl = Plate(W, r0, r1, M, c['base'][name], m, tex, rng, optics=c)
        pl.finalize()
        pl.prepare(s.min(), s.max())
        plates[name] = pl
        truth[name] = m['u'] + s.mean(1)
        hx, hy = half_extent(m['kind'], m['p'])
        xlo = m['u'] + s.min() - hx - blur_ext - 25
        xhi = m['u'] + s.max() + hx + blur_ext + 25
        ylo = m['v'] - hy - blur_ext - 25
        yhi = m['v'] + hy + blur_ext + 25
        X0, X1 = int(np.floor(xlo)), int(np.ceil(xhi))
        Y0, Y1 = int(np.floor(ylo)), int(np.ceil(yhi))
        assert X0 >= 0 and X1 <= W, (name, X0, X1)
        assert Y0 >= r0 and Y1 <= r1, (name, Y0, Y1, r0, r1)
        rois[name] = (X0, Y0, X1 - X0, Y1 - Y0)
    # static dust on the window
    dust = np.ones((H, W))
    if c.get('dust'):
        yy, xx = np.mgrid[0:H, 0:W]
        for _ in range(c['dust']):
            # put half of them inside the ROIs
            if rng.random() < 0.6:
                nm = rng.choice(['stator', 'slider'])
                X0, Y0, w_, h_ = rois[nm]
                x = rng.uniform(X0, X0 + w_)
                y = rng.uniform(Y0, Y0 + h_)
            else:
                x = rng.uniform(0, W)
                y = rng.uniform(0, H)
            R = rng.uniform(2, 10)
            d = rng.uniform(0.03, 0.10)
            dust *= 1 - d * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * R * R))
    oc = c.get('occ')
    if oc is not None:
        oc = dict(oc)
        X0, Y0, w_, h_ = rois[oc['mark']]
        mk = plates[oc['mark']].mark
        hx, hy = half_extent(mk['kind'], mk['p'])
        oc['xc'] = X0 + w_ / 2
        oc['ax'] = 3 * w_
        if oc['mode'] == 'total':
            oc['y0'] = mk['v'] - hy - oc['ay'] - 6
            oc['y1'] = mk['v'] + hy + oc['ay'] + 6
        else:
            oc['y0'] = mk['v'] - hy - oc['ay'] - 6
            oc['y1'] = mk['v'] - hy + oc.get('reach', 0.0) * 2 * hy - oc['ay']
    flick = np.ones(nfr)
    if c.get('flicker'):
        flick = 1 + rng.uniform(-c['flicker'], c['flicker'], nfr)
    yy, xx = np.mgrid[0:H, 0:W]
    bits = c.get('bits', 8)
    maxv = 2 ** bits - 1
    gain_e = c.get('gain_e', 20.0)
    read = c.get('read', 1.0)
    frames_dir = None
    if bits == 16 or c.get('png'):
        frames_dir = os.path.join(outdir, 'frames')
        os.makedirs(frames_dir, exist_ok=True)
        vw = None
    else:
        vw = cv2.VideoWriter(os.path.join(outdir, 'video.mkv'), cv2.VideoWriter_fourcc(*'FFV1'),
                             fps, (W, H), isColor=False)
        assert vw.isOpened()
    vis = {'stator': np.ones(nfr), 'slider': np.ones(nfr)}
    written = []
    crb_s = {'stator': [], 'slider': []}
    chk = {'stator': [], 'slider': []}
    for i in range(nfr):
        img = np.full((H, W), float(c.get('slot', 50)))
        for name, pl in plates.items():
            img[pl.r0:pl.r1] = pl.render(S[name][i])
        if oc is not None:
            yc = occluder_y(oc, i)
            if yc is not None:
                a = occluder_alpha_img(oc, yc, W, H)
                a = blur(a, c)   # out-of-focus occluder edge (image space)
                img = img * (1 - a) + a * oc['level']
                vis[oc['mark']][i] = visibility(plates[oc['mark']].mark, truth[oc['mark']][i],
                                                oc, yc)
        img *= dust
        g = flick[i]
        if c.get('gradient'):
            tt = i / fps
            gx = c['gradient'] * np.sin(2 * np.pi * tt / 6.0 + 0.3)
            gy = 0.5 * c['gradient'] * np.cos(2 * np.pi * tt / 9.0)
            img *= 1 + gx * (xx - W / 2) / W + gy * (yy - H / 2) / H
        img *= g
        if check:
            for name, pl in plates.items():
                X0, Y0, w_, h_ = rois[name]
                sub = img[Y0:Y0 + h_, X0:X0 + w_]
                base = c['base'][name] * g
                con = (base - sub) if pl.mark['polarity'] == 'dark' else (sub - base)
                xs = np.arange(X0, X0 + w_)
                chk[name].append((con.sum(0) * xs).sum() / con.sum() - truth[name][i])
        if i % 12 == 0 and not noiseless:
            # rough Cramer-Rao bound for a translation of the plate rows inside the ROI
            var = np.clip(img, 0, None) / gain_e + read ** 2 + 1 / 12
            for name, pl in plates.items():
                d = 0.02
                full = np.full((H, W), float(c.get('slot', 50)))
                full[pl.r0:pl.r1] = pl.render(S[name][i] + d) - pl.render(S[name][i] - d)
                full[:pl.r0] = 0
                full[pl.r1:] = 0
                D = full * dust * g / (2 * d)
                X0, Y0, w_, h_ = rois[name]
                fi = (D[Y0:Y0 + h_, X0:X0 + w_] ** 2 / var[Y0:Y0 + h_, X0:X0 + w_]).sum()
                crb_s[name].append(1 / np.sqrt(fi))
        if noiseless:
            out = img
        else:
            e = rng.poisson(np.clip(img, 0, None) * gain_e) / gain_e
            out = e + rng.normal(0, read, img.shape)
            out = np.clip(np.round(out), 0, maxv)
        if frames_dir:
            cv2.imwrite(os.path.join(frames_dir, f'frame_{i:05d}.png'),
                        out.astype(np.uint16 if bits == 16 else np.uint8))
        else:
            o8 = out.astype(np.uint8)
            vw.write(o8)
            written.append(o8)
    if vw is not None:
        vw.release()
        cap = cv2.VideoCapture(os.path.join(outdir, 'video.mkv'))
        ok_all = True
        for i in range(nfr):
            ok, fr = cap.read()
            if not ok or not np.array_equal(fr[..., 0] if fr.ndim == 3 else fr, written[i]):
                ok_all = False
                break
        cap.release()
        if not ok_all:
            print('  FFV1 readback not bit-exact -> PNG folder')
            os.remove(os.path.join(outdir, 'video.mkv'))
            frames_dir = os.path.join(outdir, 'frames')
            os.makedirs(frames_dir, exist_ok=True)
            for i, o8 in enumerate(written):
                cv2.imwrite(os.path.join(frames_dir, f'frame_{i:05d}.png'), o8)
    # truth
    with open(os.path.join(outdir, 'truth.csv'), 'w') as fh:
        fh.write('frame,time,slider_x_px,stator_x_px,slider_visible,stator_visible\n')
        for i in range(nfr):
            sx = '' if vis['slider'][i] == 0 else f"{truth['slider'][i]:.6f}"
            tx = '' if vis['stator'][i] == 0 else f"{truth['stator'][i]:.6f}"
            fh.write(f'{i},{i / fps + texp / 2:.6f},{sx},{tx},'
                     f"{vis['slider'][i]:.4f},{vis['stator'][i]:.4f}\n")
    vmax = {k: np.abs(np.diff(v.mean(1))).max() for k, v in S.items()}
    blur_px = {k: float(np.abs(v[:, -1] - v[:, 0]).max()) for k, v in S.items()}
    meta = {
        'fps': fps, 'exposure': texp, 'meters_per_pixel': c['mpp'],
        'rois': {k: ','.join(map(str, rois[k])) for k in ('slider', 'stator')},
        'category': c['category'], 'description': c.get('desc', ''),
        'size': [W, H], 'frames': nfr,
        'video': 'frames' if frames_dir else 'video.mkv',
        'crb_px': {k: (float(np.median(v)) if v else None) for k, v in crb_s.items()},
        'max_step_px': vmax, 'max_blur_px': blur_px,
        'stator_pp_px': float(np.ptp(S['stator'].mean(1))),
        'slider_pp_px': float(np.ptp(S['slider'].mean(1))),
        'marks': {k: {kk: vv for kk, vv in plates[k].mark.items()} for k in plates},
    }
    with open(os.path.join(outdir, 'case.json'), 'w') as fh:
        json.dump(meta, fh, indent=1, default=float)
    return meta, chk


# ---------------------------------------------------------------- the cases
def D(**kw):
    base = dict(size=(640, 480), fps=30, frames=240, exp_frac=0.5, mpp=1.0e-6,
                f=2.0, r=60, lr=3.0, sl_gain=0.75, sl_tau=0.03, sl_h3=0.04,
                base={'stator': 170, 'slider': 150}, psf_sigma=0.8, gain_e=20.0, read=1.0,
                category='plain')
    base.update(kw)
    return base


def dark(kind, depth, **p):
    return {'kind': kind, 'p': p, 'polarity': 'dark', 'depth': depth}


def bright(kind, amp, **p):
    return {'kind': kind, 'p': p, 'polarity': 'bright', 'amp': amp}


CASES = {
    'p01_square_basic': D(
        seed=101,
        marks={'stator': dark('rect', 0.5, w=10, h=10), 'slider': dark('rect', 0.5, w=10, h=10)},
        desc='10x10 px dark squares 50%, 640x480, 30 fps, exposure 1/2 period, 2 Hz, '
             'stator pp 120 px, l/r 3'),
    'p02_disc_fullexp': D(
        seed=102, f=3.0, r=90, exp_frac=1.0,
        marks={'stator': dark('disc', 0.4, r=8), 'slider': dark('disc', 0.4, r=8)},
        desc='hard-edged discs r=8 40%, exposure = whole frame period, 3 Hz, stator pp 180 px '
             '(blur up to ~57 px)'),
    'p03_bigrect_hd60': D(
        seed=103, size=(1280, 720), fps=60, exp_frac=0.1, f=4.0, r=50, lr=2.5, sl_tau=0.02,
        marks={'stator': dark('rect', 0.35, w=30, h=70), 'slider': dark('rect', 0.35, w=30, h=70)},
        desc='30x70 px rectangles 35%, 1280x720, 60 fps, exposure 1/10 period, 4 Hz, l/r 2.5'),
    'p04_ring_hd_big': D(
        seed=104, size=(1280, 720), fps=25, f=1.0, r=230, lr=3.5, sl_gain=0.6, sl_tau=0.06,
        sl_h3=0.06,
        marks={'stator': dark('ring', 0.6, ro=10, ri=6), 'slider': dark('ring', 0.6, ro=10, ri=6)},
        desc='rings (r 6-10) 60%, 1280x720, 25 fps, 1 Hz, stator pp 460 px, slider lag 0.06 s'),
    'p05_cross_flicker': D(
        seed=105, flicker=0.15, f=3.0, r=40,
        marks={'stator': dark('cross', 0.45, L=20, t=4),
               'slider': dark('cross', 0.45, L=20, t=4)},
        desc='crosses 20x4 45%, illumination flicker +-15 % per frame, 3 Hz'),
    'p06_bars_gradient_15fps': D(
        seed=106, fps=15, frames=120, exp_frac=0.3, f=1.5, r=70, gradient=0.3,
        marks={'stator': dark('bars', 0.5, w=4, h=24, gap=12),
               'slider': dark('bars', 0.5, w=4, h=24, gap=12)},
        desc='pair of 4x24 bars (12 px apart) 50%, 15 fps 120 frames, '
             'slowly drifting illumination gradient +-30 % across view'),
    'p07_lowcontrast16': D(
        seed=107, bits=16, base={'stator': 30000, 'slider': 28000}, gain_e=0.3, read=20.0,
        slot=8000,
        marks={'stator': dark('rect', 0.05, w=12, h=12), 'slider': dark('disc', 0.05, r=7)},
        desc='16-bit PNG, 5 % contrast: 12x12 square (stator), disc r=7 (slider)'),
    'p08_defocus': D(
        seed=108, defocus=3.0, f=2.0, r=90, lr=4.0,
        marks={'stator': dark('rect', 0.5, w=14, h=10), 'slider': dark('disc', 0.5, r=8)},
        desc='defocus: pill-box PSF radius 3 px; 14x10 rect / disc, l/r 4, pp 180 px'),
    'p09_occl_dark_total': D(
        seed=109,
        marks={'stator': dark('rect', 0.5, w=10, h=10), 'slider': dark('rect', 0.5, w=10, h=10)},
        occ={'mark': 'stator', 'mode': 'total', 'start': 100, 'n': 12, 'ay': 16, 'level': 25},
        desc='10x10 squares; a dark band (debris shadow) sweeps over the stator mark, '
             'frames 100-112, totally covering it for some frames'),
    't10_texture_coarse': D(
        seed=110, category='textured', tex={'std': 0.10, 'grain': 5},
        marks={'stator': dark('rect', 0.5, w=10, h=10), 'slider': dark('rect', 0.5, w=10, h=10)},
        desc='moving multiplicative texture std 10 %, grain 5 px; 10x10 squares 50%'),
    't11_speckle_fast': D(
        seed=111, category='textured', tex={'std': 0.08, 'grain': 1}, f=2.5, r=80, exp_frac=0.8,
        marks={'stator': dark('disc', 0.3, r=8), 'slider': dark('disc', 0.3, r=8)},
        desc='fine speckle std 8 %, grain 1 px; discs 30%; 2.5 Hz pp 160 px, '
             'exposure 0.8 period'),
    't12_scratch_dust_lowdepth': D(
        seed=112, category='textured', tex={'std': 0.05, 'grain': 3, 'scratches': 40}, dust=25,
        marks={'stator': dark('cross', 0.25, L=20, t=4),
               'slider': dark('cross', 0.25, L=20, t=4)},
        desc='texture 5 % grain 3 px + faint scratches along x + static dust on the window; '
             'crosses only 25% deep'),
    'b13_led_spot': D(
        seed=113, category='bright', base={'stator': 20, 'slider': 25}, slot=10, f=3.0, r=50,
        marks={'stator': bright('gauss', 200, sigma=2.5),
               'slider': bright('gauss', 180, sigma=2.5)},
        desc='bright Gaussian spots (sigma 2.5 px, IR-LED-like) on dark plates, 3 Hz'),
    'b14_brightrect_occl': D(
        seed=114, category='bright', base={'stator': 90, 'slider': 80},
        tex={'std': 0.04, 'grain': 2},
        size=(1280, 720), fps=30, f=1.5, r=150, lr=3.0,
        marks={'stator': bright('rect', 110, w=12, h=20),
               'slider': bright('rect', 110, w=12, h=20)},
        occ={'mark': 'slider', 'mode': 'partial', 'start': 150, 'n': 10, 'ay': 14,
             'level': 235, 'reach': 0.5},
        desc='bright 12x20 rectangles on textured (4 %) grey plates, 1280x720, pp 300 px; '
             'a bright blob covers ~half of the slider mark, frames 150-160'),
    't15_slider_stuck': D(
        seed=115, category='textured', tex={'std': 0.06, 'grain': 3}, f=2.0, r=70,
        static=['slider'],
        marks={'stator': dark('disc', 0.5, r=8), 'slider': dark('disc', 0.5, r=8)},
        desc='texture 6 % grain 3 px; discs 50%; the slider is stuck (does not move at all) '
             'while the stator oscillates (pp 140 px)'),
}


def selftest():
    """Check noiseless renders (static, moving, ...): contrast centroid vs truth."""
    ok = True
    for nm, extra in [('static', dict(static=True)),
                      ('moving', {}),
                      ('defocus', dict(defocus=3.0, flicker=0.15)),
                      ('bright', dict(base={'stator': 20, 'slider': 25}))]:
        mk = {'stator': dark('disc', 0.4, r=8), 'slider': dark('rect', 0.5, w=10, h=10)}
        if nm == 'bright':
            mk = {'stator': bright('gauss', 200, sigma=2.5),
                  'slider': bright('ring', 100, ro=10, ri=6)}
        if nm == 'defocus':
            mk = {'stator': dark('bars', 0.5, w=4, h=24, gap=12),
                  'slider': dark('cross', 0.45, L=20, t=4)}
        c = D(seed=7, f=2.5, r=80, exp_frac=1.0, **extra, marks=mk, frames=24)
        c2 = dict(c)
        d = os.path.join(HERE, 'selftest_' + nm)
        os.makedirs(d, exist_ok=True)
        meta, chk = render_case(c2, d, noiseless=True, check=True)
        for k, v in chk.items():
            v = np.array(v)
            print(f'selftest {nm:7s} {k:7s}: centroid-truth max |err| = '
                  f'{np.abs(v).max():.5f} px  mean {v.mean():+.5f}')
            ok &= np.abs(v).max() < 0.01
        shutil.rmtree(d)
    # truth is the exposure mean of the centre: compare with a fine analytic average
    c = D(seed=7, f=2.5, r=80, exp_frac=1.0, marks={})
    rng = np.random.default_rng(c['seed'])
    st = crank_motion(c['f'], c['r'], c['lr'], rng.uniform(0, 2 * np.pi))
    texp = 1 / 30
    for t0 in (0.0, 0.013, 0.1):
        tj = (np.arange(NT) + 0.5) / NT * texp
        tf = np.linspace(0, texp, 200001)
        m1 = st(t0 + tj).mean()
        m2 = np.trapezoid(st(t0 + tf), tf) / texp
        print(f'selftest exposure mean: {NT}-sample {m1:.6f} vs fine integral {m2:.6f} '
              f'(diff {m1 - m2:.2e})')
    return ok


if __name__ == '__main__':
    args = sys.argv[1:]
    if args and args[0] == 'selftest':
        print('OK' if selftest() else 'FAIL')
        sys.exit(0)
    names = args or list(CASES)
    for n in names:
        t = time.time()
        d = os.path.join(OUT, n)
        if os.path.exists(d):
            shutil.rmtree(d)
        os.makedirs(d)
        meta, _ = render_case(CASES[n], d)
        print(f"{n}: {time.time() - t:.0f}s rois={meta['rois']} crb={meta['crb_px']} "
              f"step={meta['max_step_px']} blur={meta['max_blur_px']}", flush=True)
