#!/usr/bin/env python3
"""Render blind test set 6 for the microball camera tracker (stator + slider marks moving along x).

usage: generate.py [case ...]      render the named cases (all when none) into out/<case>/
       generate.py --list          list the cases
       generate.py --selftest      renderer vs the analytic pixel integral of a (smeared) square

Physics (see README.md): each plate is a reflectance map on a fine grid (SX x SY cells per pixel,
marks rasterised with 4x4 samples per cell).  A frame is the exposure-time mean of the plate
shifted (sub-pixel-exactly) to NSUB sub-exposure positions, blurred by a Gaussian PSF and
integrated over pixel areas -- all done as one convolution along x in the Fourier domain.
Lighting, window dirt, occluders and glints are then applied at pixel level, followed by an
optional defocus kernel, shot + read noise, quantisation and hot pixels.

Pixel convention: pixel (row r, column p) covers x in [p-0.5, p+0.5), y in [r-0.5, r+0.5), i.e. the
centre of pixel column p is x = p (as in OpenCV).  Truth x is in these pixel coordinates.
"""
import csv
import json
import os
import sys
import time

import cv2
import numpy as np
import scipy.fft as sfft
from scipy.ndimage import gaussian_filter1d
from scipy.signal import lfilter

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, 'out')
SX, SY = 8, 4          # fine cells per pixel along x and y
SS = 4                 # sub-samples per fine cell (per axis) when rasterising marks
NSUB = 512             # sub-exposure time samples per frame
TAYLOR = 10            # terms of the sub-cell shift expansion (see Plate.kernel)
DT_SIM = 2e-5          # time step of the slider simulation (s)
CRB_FRAMES = 16        # frames used for the Cramer-Rao bound


# ----------------------------------------------------------------------------------------------
# motion
# ----------------------------------------------------------------------------------------------
def crank(t, st):
    """Crank-slider displacement about the centre of travel (px).

    r cos(wt) + sqrt(l^2 - r^2 sin^2(wt)) - l, with the rod length l = l_over_r * r.
    """
    r = st['p2p'] / 2.0
    rod = st['l_over_r'] * r
    th = 2 * np.pi * st['hz'] * t + st.get('phase', 0.0)
    return r * np.cos(th) + np.sqrt(rod * rod - (r * np.sin(th)) ** 2) - rod


def slider_motion(st, sl, t_end):
    """Slider displacement about its centre (px) on a dense time grid; returns (t_grid, x_grid)."""
    tg = np.arange(-1.0, t_end + 2 * DT_SIM, DT_SIM)
    if sl['mode'] == 'stuck':
        return tg, np.zeros_like(tg)
    th = 2 * np.pi * st['hz'] * tg + st.get('phase', 0.0)
    drive = (sl['gain'] * crank(tg, st)
             + sl.get('h3', 0.0) * st['p2p'] / 2 * np.cos(3 * th + sl.get('phi3', 0.0)))
    a = np.exp(-DT_SIM / sl['tau'])                       # first-order lag, starting at rest
    y, _ = lfilter([1 - a], [1, -a], drive, zi=[a * drive[0]])
    if sl['mode'] == 'follow':
        return tg, y
    # stick-slip: stuck until the lagged drive is `brk` px away, then slips towards it (time
    # constant tau_slip) until within `rel` px, then sticks again.
    brk, rel, k = sl['brk'], sl['rel'], DT_SIM / sl['tau_slip']
    out = np.empty_like(y)
    p, slipping = y[0], False
    for n, yn in enumerate(y.tolist()):
        d = yn - p
        if not slipping and abs(d) > brk:
            slipping = True
        if slipping:
            p += d * k
            if abs(yn - p) < rel:
                slipping = False
        out[n] = p
    return tg, out


# ----------------------------------------------------------------------------------------------
# marks (plate-local coordinates a along x, b along y, px, centre at 0,0)
# ----------------------------------------------------------------------------------------------
def rotate(a, b, deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return c * a + s * b, -s * a + c * b


QR_BITS = ['11101', '10110', '11010', '00111', '10100']   # no symmetry: centroid is not the centre


def mark_value(mk, a, b):
    """Mark value (coverage or emission profile, 0..1) at local coordinates."""
    k, p = mk['kind'], mk['p']
    a, b = rotate(a, b, mk.get('rot', 0.0))
    if k in ('square', 'rect', 'polished'):
        return ((np.abs(a) <= p['w'] / 2) & (np.abs(b) <= p['h'] / 2)).astype(np.float32)
    if k in ('disc', 'retro'):
        return (a * a + b * b <= p['r'] ** 2).astype(np.float32)
    if k == 'ring':
        r2 = a * a + b * b
        return ((r2 <= p['ro'] ** 2) & (r2 >= p['ri'] ** 2)).astype(np.float32)
    if k == 'cross':
        h, t = p['L'] / 2, p['t'] / 2
        return (((np.abs(a) <= h) & (np.abs(b) <= t))
                | ((np.abs(a) <= t) & (np.abs(b) <= h))).astype(np.float32)
    if k == 'bars':
        return ((np.abs(a) >= p['gap'] / 2) & (np.abs(a) <= p['gap'] / 2 + p['w'])
                & (np.abs(b) <= p['h'] / 2)).astype(np.float32)
    if k == 'triangle':     # isosceles, apex pointing to +x, base at a = -w/2
        w, h = p['w'], p['h']
        return ((a >= -w / 2) & (a <= w / 2)
                & (np.abs(b) <= h / 2 * (w / 2 - a) / w)).astype(np.float32)
    if k == 'L':            # vertical bar on the left, foot along the bottom (+y is down)
        s, t = p['s'] / 2, p['t']
        inside = (np.abs(a) <= s) & (np.abs(b) <= s)
        return (inside & ((a <= -s + t) | (b >= s - t))).astype(np.float32)
    if k == 'qr':
        c = p['cell']
        i = np.floor(b / c + 2.5).astype(int)
        j = np.floor(a / c + 2.5).astype(int)
        ok = (i >= 0) & (i < 5) & (j >= 0) & (j < 5)
        bits = np.array([[int(ch) for ch in row] for row in QR_BITS])
        return (ok & (bits[np.clip(i, 0, 4), np.clip(j, 0, 4)] == 1)).astype(np.float32)
    if k == 'led':          # emission: flat-topped (super-Gaussian) spot
        r = np.sqrt(a * a + b * b)
        return np.exp(-0.5 * (r / p['sigma']) ** p.get('order', 2)).astype(np.float32)
    raise ValueError(k)


def mark_half_extent(mk):
    k, p = mk['kind'], mk['p']
    if k in ('square', 'rect', 'polished'):
        hx, hy = p['w'] / 2, p['h'] / 2
    elif k in ('disc', 'retro'):
        hx = hy = p['r']
    elif k == 'ring':
        hx = hy = p['ro']
    elif k == 'cross':
        hx = hy = p['L'] / 2
    elif k == 'bars':
        hx, hy = p['gap'] / 2 + p['w'], p['h'] / 2
    elif k == 'triangle':
        hx, hy = p['w'] / 2, p['h'] / 2
    elif k == 'L':
        hx = hy = p['s'] / 2
    elif k == 'qr':
        hx = hy = 2.5 * p['cell']
    elif k == 'led':
        hx = hy = 4.0 * p['sigma']
    rot = np.radians(abs(mk.get('rot', 0.0)))
    return (hx * np.cos(rot) + hy * np.sin(rot), hx * np.sin(rot) + hy * np.cos(rot))


SYMMETRIC = {'square', 'rect', 'polished', 'disc', 'retro', 'ring', 'cross', 'bars', 'led'}


# ----------------------------------------------------------------------------------------------
# plate textures (multiplicative, on the fine grid, moving with the plate)
# ----------------------------------------------------------------------------------------------
def gauss_noise(shape, sx, sy, rng):
    """White noise low-passed with a Gaussian of sigma (sx, sy) cells, unit std."""
    n = rng.standard_normal(shape, dtype=np.float32)
    F = sfft.rfft2(n, workers=1)
    ky = sfft.fftfreq(shape[0]).astype(np.float32)[:, None]
    kx = sfft.rfftfreq(shape[1]).astype(np.float32)[None, :]
    F *= np.exp(-2 * np.pi ** 2 * ((kx * sx) ** 2 + (ky * sy) ** 2))
    out = sfft.irfft2(F, s=shape, workers=1)
    return out / out.std()


def seg_distance(U, Y, p0, p1):
    d = np.subtract(p1, p0)
    t = np.clip(((U - p0[0]) * d[0] + (Y - p0[1]) * d[1]) / (d @ d), 0, 1)
    return np.hypot(U - p0[0] - t * d[0], Y - p0[1] - t * d[1])


def box_index(uf, yf, u0, u1, y0, y1):
    i0, i1 = np.searchsorted(uf, [u0, u1])
    j0, j1 = np.searchsorted(yf, [y0, y1])
    return slice(j0, j1), slice(i0, i1)


def smooth_disc(r, radius, soft):
    """1 inside, 0 beyond radius+soft, smooth (cubic) in between; exactly 0 outside."""
    t = np.clip((radius + soft - r) / (2 * soft), 0, 1)
    return t * t * (3 - 2 * t)


def make_texture(specs, uf, yf, ym, rng):
    tex = np.ones((len(yf), len(uf)), np.float32)
    for sp in specs:
        k = sp['kind']
        if k == 'grain':          # isotropic grain, sigma = size/2 px
            tex += sp['amp'] * gauss_noise(
                tex.shape, sp['size'] / 2 * SX, sp['size'] / 2 * SY, rng)
        elif k == 'brushed':      # streaks along x (long correlation in x, short in y)
            tex += sp['amp'] * gauss_noise(
                tex.shape, sp['len'] / 2 * SX, sp['width'] / 2 * SY, rng)
        elif k == 'speckle':      # fully developed speckle intensity, contrast amp
            re = gauss_noise(tex.shape, sp['size'] / 2 * SX, sp['size'] / 2 * SY, rng)
            im = gauss_noise(tex.shape, sp['size'] / 2 * SX, sp['size'] / 2 * SY, rng)
            inten = re * re + im * im
            tex += sp['amp'] * (inten / inten.mean() - 1)
        elif k == 'scratches':    # straight scratches along and across x, depth varies along them
            for n, along in ((sp['n_along'], True), (sp['n_across'], False)):
                for _ in range(n):
                    c = (rng.uniform(uf[0], uf[-1]), rng.uniform(yf[0], yf[-1]))
                    L = rng.uniform(*(sp['len_along'] if along else sp['len_across']))
                    ang = np.radians(rng.normal(0, 1.0) if along else 90 + rng.normal(0, 12))
                    h = 0.5 * L * np.array([np.cos(ang), np.sin(ang)])
                    p0, p1 = np.array(c) - h, np.array(c) + h
                    w = rng.uniform(*sp['width'])
                    dep = rng.uniform(*sp['depth']) * (1 if rng.random() < 0.75 else -0.6)
                    sl = box_index(uf, yf, min(p0[0], p1[0]) - 4 * w, max(p0[0], p1[0]) + 4 * w,
                                   min(p0[1], p1[1]) - 4 * w, max(p0[1], p1[1]) + 4 * w)
                    U, Y = np.meshgrid(uf[sl[1]], yf[sl[0]])
                    if U.size == 0:
                        continue
                    along_t = (((U - p0[0]) * (p1[0] - p0[0]) + (Y - p0[1]) * (p1[1] - p0[1]))
                               / (L * L))
                    mod = 0.6 + 0.4 * np.cos(
                        2 * np.pi * (rng.uniform(1, 4) * along_t + rng.random()))
                    tex[sl] *= 1 - dep * mod * np.exp(-0.5 * (seg_distance(U, Y, p0, p1) / w) ** 2)
        elif k == 'grid':         # etched grid lines (period in px), Gaussian line profile
            P, w, dep = sp['period'], sp['width'], sp['depth']
            du = (uf - sp.get('phase', 0.0) + P / 2) % P - P / 2
            dy = (yf - sp.get('phase_y', 0.0) + P / 2) % P - P / 2
            lu = np.exp(-0.5 * (du / w) ** 2)[None, :]
            ly = np.exp(-0.5 * (dy / w) ** 2)[:, None]
            tex *= 1 - dep * np.maximum(lu, ly)
        elif k == 'particles':    # dark/bright particles lying on the plate (move with it)
            for du, dy, rad, dep in sp['items']:
                sl = box_index(uf, yf, du - rad - 2, du + rad + 2,
                               ym + dy - rad - 2, ym + dy + rad + 2)
                U, Y = np.meshgrid(uf[sl[1]], yf[sl[0]])
                tex[sl] *= 1 - dep * smooth_disc(np.hypot(U - du, Y - ym - dy), rad, 0.7)
        else:
            raise ValueError(k)
    return tex


# ----------------------------------------------------------------------------------------------
# one plate on the fine grid, and its exposure / pixel / PSF rendering
# ----------------------------------------------------------------------------------------------
class Plate:
    """Plate band in image rows r0..r1-1; plate coordinate u = x - s (s = plate displacement, px).

    Layer A = texture * plate coverage * (1 - mark coverage), layer B = mark (coverage or
    emission).  Both are y-blurred / y-pixel-integrated once; x handling (motion, pixel box, PSF)
    per frame.
    """

    def __init__(self, spec, W, H, s_min, s_max, psf_sigma, rng, grey=(1.0,)):
        mk = spec['mark']
        self.r0 = max(0, int(np.floor(spec['edges'][0])) - 6)
        self.r1 = min(H, int(np.ceil(spec['edges'][1])) + 7)
        self.W = W
        self.ym = spec['ym']
        pad = 24
        self.u_lo = -int(np.ceil(s_max)) - pad - 0.5
        self.Nf = sfft.next_fast_len(int((W - np.floor(s_min) + pad - 0.5 - self.u_lo) * SX),
                                     real=True)
        self.j0 = int(round((-0.5 - self.u_lo) * SX))             # fine cell of x = -0.5
        assert W * SX <= self.Nf
        uf = self.u_lo + (np.arange(self.Nf) + 0.5) / SX
        yf = self.r0 - 0.5 + (np.arange((self.r1 - self.r0) * SY) + 0.5) / SY
        yt, yb = spec['edges']
        cy = np.clip(np.minimum(yf + 0.5 / SY, yb) - np.maximum(yf - 0.5 / SY, yt), 0, None) * SY

        # mark raster (SSxSS samples per fine cell, symmetric about the mark centre)
        hx, hy = mark_half_extent(mk)
        sl = box_index(uf, yf, -hx - 1.5, hx + 1.5, self.ym - hy - 1.5, self.ym + hy + 1.5)
        off = (np.arange(SS) + 0.5) / SS - 0.5
        ua = (uf[sl[1]][:, None] + off[None, :] / SX).ravel()
        yb_ = (yf[sl[0]][:, None] + off[None, :] / SY).ravel()
        A_, B_ = np.meshgrid(ua, yb_ - self.ym)
        cov_val = mark_value(mk, A_, B_).reshape(
            len(yb_) // SS, SS, len(ua) // SS, SS).mean((1, 3))
        val = cov_val
        if mk['kind'] == 'retro':       # glass-bead texture, made point-symmetric about the centre
            n = rng.standard_normal(val.shape).astype(np.float32)
            n = gaussian_filter1d(gaussian_filter1d(n, 0.4 * SX, axis=1), 0.4 * SY, axis=0)
            n = 0.5 * (n + n[::-1, ::-1])
            val = val * (1 + mk['p']['beads'] * n / n.std())
        self.emissive = mk['kind'] == 'led'
        cov = np.zeros((len(yf), len(uf)), np.float32)
        B = np.zeros_like(cov)
        B[sl] = val
        if not self.emissive:
            cov[sl] = cov_val
        # contrast-area centroid of the mark (truth offset; 0 for symmetric marks)
        w = val if self.emissive else cov_val
        self.u_c = float((w.sum(0) * uf[sl[1]]).sum() / w.sum())
        tex = make_texture(spec.get('texture', []), uf, yf, self.ym, rng)
        # with a textured plate the contrast (plate level - mark level) varies over the mark's
        # area: how far its weighted centroid is from the shape's (a measure of the truth's
        # ambiguity)
        # grey level the tracker sees
        Pm = float(np.dot(np.resize(np.atleast_1d(spec['P']), len(grey)), grey))
        Mm = float(np.dot(np.resize(np.atleast_1d(spec['M']), len(grey)), grey))
        wc = np.abs(Pm * tex[sl] - Mm) * cov_val if not self.emissive else val
        self.tex_shift = float((wc.sum(0) * uf[sl[1]]).sum() / wc.sum()) - self.u_c
        A = cy[:, None] * tex * (1 - cov)
        # the plate without texture
        A0 = cy[:, None] * (1 - cov) if spec.get('texture') else None
        del tex, cov
        # y: PSF then pixel box; x: pixel box done per frame, PSF in the spectra
        sig = psf_sigma * SY
        Hp = self.r1 - self.r0

        nrows = (self.r1 - self.r0) * SY
        # zero padding below
        ny = sfft.next_fast_len(nrows + int(np.ceil(8 * sig)) + 1, real=True)
        fy = sfft.rfftfreq(ny)
        Gy = (np.exp(-2 * np.pi ** 2 * (fy * sig) ** 2)
              * np.sinc(fy) ** 2).astype(np.float32)[:, None]

        def yreduce(F):
            """Fine rows (cell averages) -> pixel rows: Gaussian PSF and pixel box, exactly.

            The cell values stand for a piecewise-constant map; averaging cell-centre values of
            (map * PSF) over a pixel needs one more cell-width box, hence sinc^2 (box of the map's
            cells x box of the averaging cells) in the transfer function.
            """
            F = sfft.irfft(sfft.rfft(F, n=ny, axis=0, workers=1) * Gy, n=ny, axis=0,
                           workers=1)[:nrows]
            return F.reshape(Hp, SY, -1).mean(1)

        k = sfft.rfftfreq(self.Nf).astype(np.float32)
        G = np.exp(-2 * np.pi ** 2 * (k * psf_sigma * SX) ** 2) * np.sinc(k) ** 2  # as in yreduce
        self.D = (-2j * np.pi * k * SX).astype(np.complex64)     # d/ds of a shift (per px)
        self.D[-1] = 0 if self.Nf % 2 == 0 else self.D[-1]
        self.SA = (sfft.rfft(yreduce(A), axis=1, workers=1) * G).astype(np.complex64)
        self.SB = (sfft.rfft(yreduce(B), axis=1, workers=1) * G).astype(np.complex64)
        self.SA0 = (self.SA if A0 is None
                    else (sfft.rfft(yreduce(A0), axis=1, workers=1) * G).astype(np.complex64))
        self.cov_y = yreduce(cy[:, None].astype(np.float32))[:, 0]   # plate coverage per pixel row
        self.Hp = Hp

    def kernel(self, shifts):
        """Spectrum of the exposure kernel: mean over the sub-exposure shifts of an exact shift.

        Each shift = whole cells n + fraction phi (|phi| <= 1/2 cell); exp(-2 pi i f phi) is
        expanded in a Taylor series (TAYLOR terms, error < 1e-5 where the PSF passes anything), so
        every sample is shifted sub-pixel-exactly while the sum over samples stays a few
        histograms.
        """
        pos = np.asarray(shifts, dtype=np.float64) * SX
        n = np.round(pos)
        phi = pos - n
        idx = (n.astype(np.int64) - self.j0) % self.Nf   # output column 0 <-> x = -0.5 (circular)
        f = sfft.rfftfreq(self.Nf)
        K = np.zeros(len(f), np.complex128)
        coef = np.ones(len(f), np.complex128)
        for m in range(TAYLOR + 1):
            if m:
                coef = coef * (-2j * np.pi * f) / m
            K += coef * sfft.rfft(np.bincount(idx, phi ** m, self.Nf))
        return (K / len(pos)).astype(np.complex64)

    def render(self, FK, coefs, deriv=False):
        """Pixel images (Hp, W) of a*A + b*B (+ a0*A0) for each (a, b[, a0]) in coefs.

        FK is the exposure kernel; A0 is layer A without the plate texture; deriv: derivative
        w.r.t. the plate shift instead.
        """
        out = []
        for cf in coefs:
            a, b, a0 = (tuple(cf) + (0,))[:3]
            S = ((a * self.SA if a else 0) + (b * self.SB if b else 0)
                 + (a0 * self.SA0 if a0 else 0))
            S = S * FK
            if deriv:
                S = S * self.D
            c = sfft.irfft(S, n=self.Nf, axis=1, workers=1)[:, :self.W * SX]
            out.append(c.reshape(self.Hp, self.W, SX).mean(-1))
        return out


# ----------------------------------------------------------------------------------------------
# pixel-level scene layers: lighting, glints, window dirt, occluders
# ----------------------------------------------------------------------------------------------
def smoothstep(t):
    t = np.clip(t, 0, 1)
    return t * t * (3 - 2 * t)


def polyline_distance(X, Y, pts):
    d = np.full(X.shape, np.inf)
    for p0, p1 in zip(pts[:-1], pts[1:], strict=True):
        d = np.minimum(d, seg_distance(X, Y, p0, p1))
    return d


class Scene:
    """Pixel-level scene layers of one case: lighting, glints and window dirt / occluders."""

    def __init__(self, c, W, H, n, fps, E):
        self.c, self.W, self.H, self.n, self.fps, self.E = c, W, H, n, fps, E
        self.y, self.x = np.mgrid[0:H, 0:W].astype(np.float64)
        L = c.get('light', {})
        self.vig = np.ones((H, W))
        if 'vignette' in L:                       # (1 + k r^2)^-2, corner level given
            k = L['vignette'] ** -0.5 - 1
            r2 = ((self.x - W / 2) ** 2 + (self.y - H / 2) ** 2) / ((W / 2) ** 2 + (H / 2) ** 2)
            self.vig = (1 + k * r2) ** -2
        self._static_cache = None

    def flicker(self, i):
        """Per-frame gain: exposure mean of 1 + d cos(2 pi f t + phi).

        The flicker is mains ripple at twice the line frequency.
        """
        fl = self.c.get('light', {}).get('flicker')
        if not fl:
            return 1.0
        f, d, ph = fl['hz'], fl['depth'], fl.get('phase', 0.3)
        t0 = i / self.fps
        w = 2 * np.pi * f
        return 1 + d * (np.sin(w * (t0 + self.E) + ph) - np.sin(w * t0 + ph)) / (w * self.E)

    def lighting(self, i, v):
        """Illumination (H, W) for frame i, scene shifted by v px in x.

        Lamp light, including flicker.
        """
        L = self.c.get('light', {})
        x, y, W, H = self.x - v, self.y, self.W, self.H
        lum = self.vig * self.flicker(i)
        if 'gradient' in L:                       # slowly drifting linear gradient
            g = L['gradient']
            a = g['amp'] * (1 + 0.5 * np.sin(2 * np.pi * i / (1.3 * self.n)))
            th = g['angle'] + g['turn'] * i / self.n
            lum = lum * (1 + a * ((x - W / 2) * np.cos(th) + (y - H / 2) * np.sin(th)) / W)
        if 'shadow' in L:                         # soft shadow band sweeping across (e.g. a cable)
            s = L['shadow']
            f = np.clip((i - s['f0']) / (s['f1'] - s['f0']), 0, 1)
            xc = s['x0'] + f * (s['x1'] - s['x0'])
            cb, sb = np.cos(np.radians(s['tilt'])), np.sin(np.radians(s['tilt']))
            d = np.abs((x - xc) * cb + (y - s['yc']) * sb)
            lum = lum * (1 - s['depth'] * smoothstep((s['width'] / 2 + s['pen'] - d)
                                                     / (2 * s['pen'])))
        return lum

    def glint(self, i, v):
        """Return the static additive reflection (window / fixture), lit by the lamp (flickers)."""
        out = 0.0
        for g in self.c.get('light', {}).get('glints', []):
            dx, dy = self.x - v - g['x'], self.y - g['y']
            a, b = rotate(dx, dy, g.get('angle', 0.0))
            out = out + g['amp'] * np.exp(-0.5 * ((a / g['sx']) ** 2 + (b / g['sy']) ** 2))
        return out * self.flicker(i) if np.ndim(out) else None

    def dirt(self, i, v):
        """Occluder opacity (H, W) in [0,1] and the radiance of the occluder; None when clean."""
        D = self.c.get('dirt', {})
        if not D:
            return None, None
        x, y = self.x - v, self.y
        if self._static_cache is None or v != 0:
            sop, srad = np.zeros((self.H, self.W)), np.zeros((self.H, self.W))
            for d in D.get('dust', []):           # out-of-focus dust on the window: soft disc
                o = d['opacity'] * smooth_disc(np.hypot(x - d['x'], y - d['y']), d['r'], d['soft'])
                sop = 1 - (1 - sop) * (1 - o)
            for fb in D.get('fibres', []):        # lint fibre, nearly in focus: thin dark curve
                t = np.linspace(0, 1, 60)[:, None]
                P0, P1, P2 = map(np.array, (fb['p0'], fb['p1'], fb['p2']))
                pts = (1 - t) ** 2 * P0 + 2 * (1 - t) * t * P1 + t ** 2 * P2
                lo, hi = pts.min(0) - 3 * fb['w'] - 2, pts.max(0) + 3 * fb['w'] + 2
                bx = (slice(max(0, int(lo[1])), int(hi[1]) + 1),
                      slice(max(0, int(lo[0])), int(hi[0]) + 1))
                dist = polyline_distance(x[bx], y[bx], pts)
                o = np.zeros_like(sop)
                o[bx] = fb['opacity'] * np.clip(1 - (dist / fb['w']) ** 2, 0, 1) ** 2
                srad = np.where(o > 0, fb['rad'], srad)
                sop = 1 - (1 - sop) * (1 - o)
            self._static_cache = (sop, srad)
        sop, srad = self._static_cache
        op, rad = sop.copy(), srad.copy()
        for pr in D.get('probes', []):            # opaque tool moving in and out (tapered blade)
            fr = np.interp(i, pr['frames'], pr['depth'])      # tip y position per frame
            if fr > -50:
                xc = pr['x'] + pr.get('drift', 0.0) * i
                half = pr['tip_r'] + pr['taper'] * np.clip(fr - y, 0, None)
                inside = np.where(y <= fr, np.abs(x - xc) - half,
                                  np.hypot(x - xc, y - fr) - pr['tip_r'])   # signed distance
                o = smoothstep((0.8 - inside) / 1.6)
                shade = pr['rad'] * (1 + 0.8 * np.exp(
                    -0.5 * ((x - xc - 0.3 * half) / (0.25 * half + 1)) ** 2))
                rad = np.where(o > 0, shade, rad)
                op = np.maximum(op, o)
        return op, rad


# ----------------------------------------------------------------------------------------------
# sensor and output
# ----------------------------------------------------------------------------------------------
def defocus_kernel(radius):
    """Pillbox of the given radius integrated over pixel areas (16x16 samples per pixel)."""
    R = int(np.ceil(radius)) + 1
    o = (np.arange(16) + 0.5) / 16 - 0.5
    ax = (np.arange(-R, R + 1)[:, None] + o[None, :]).ravel()
    X, Y = np.meshgrid(ax, ax)
    k = (X * X + Y * Y <= radius * radius).reshape(2 * R + 1, 16, 2 * R + 1, 16).mean((1, 3))
    return (k / k.sum()).astype(np.float32)


class Sensor:
    """Sensor model: shot + read noise, quantisation, black level and hot / warm pixels."""

    def __init__(self, c, rng):
        s = c['sensor']
        self.bits, self.fwe, self.read = s['bits'], s['fwe'], s['read']
        self.dn_max = 2 ** self.bits - 1
        self.black = s.get('black', 0)
        self.gain = (self.dn_max - self.black) / self.fwe          # DN per electron
        self.rng = rng
        self.hot = None

    def place_hot(self, shape, hp, rng, rois):
        """Hot (stuck high) and warm (offset) pixels anywhere, plus some placed inside the ROIs."""
        H, W = shape[-2:]
        idx = []
        for k, (n_any, n_roi) in enumerate([(hp.get('hot', 0), hp.get('hot_roi', 0)),
                                            (hp.get('warm', 0), hp.get('warm_roi', 0))]):
            pts = [(rng.integers(H), rng.integers(W)) for _ in range(n_any)]
            for j in range(n_roi):
                X, Y, w, h = rois[j % len(rois)]
                pts.append((Y + rng.integers(h), X + rng.integers(w)))
            for (r, q) in pts:
                level = (rng.uniform(0.7, 1.0) if k == 0 else rng.uniform(0.05, 0.2)) * self.dn_max
                idx.append((r, q, k, level))
        self.hot = idx

    def expose(self, radiance):
        """Relative radiance (1.0 = full scale) -> quantised DN (float array).

        Also returns the noiseless DN.
        """
        mu = np.clip(radiance, 0, None) * self.fwe
        e = self.rng.poisson(mu).astype(np.float64) + self.rng.normal(0, self.read, radiance.shape)
        dn = np.clip(np.round(self.black + self.gain * e), 0, self.dn_max)
        if self.hot:
            for r, q, k, level in self.hot:
                dn[..., r, q] = np.minimum(self.dn_max, max(dn[..., r, q].max(), level) if k == 0
                                           else dn[..., r, q] + round(level))
        return dn, np.clip(self.black + self.gain * mu, 0, self.dn_max)

    def variance(self, radiance):
        """Return the expected DN variance for a relative radiance (shot + read + quantisation)."""
        return self.gain ** 2 * (np.clip(radiance, 0, None) * self.fwe + self.read ** 2) + 1 / 12


class Writer:
    """Video file (FFV1 / MPEG-4 part 2 / MJPEG) or a numbered PNG / TIFF sequence."""

    def __init__(self, d, fmt, W, H, fps, color):
        self.fmt, self.color, self.d = fmt, color, d
        if fmt in ('ffv1', 'mp4v', 'mjpg'):
            name, cc = {'ffv1': ('video.mkv', 'FFV1'), 'mp4v': ('video.mp4', 'mp4v'),
                        'mjpg': ('video.avi', 'MJPG')}[fmt]
            self.rel = name
            self.vw = cv2.VideoWriter(os.path.join(d, name), cv2.VideoWriter_fourcc(*cc), fps,
                                      (W, H), isColor=color)
            if not self.vw.isOpened():
                raise RuntimeError(f'cannot open a {cc} writer')
        else:
            self.rel = 'frames'
            os.makedirs(os.path.join(d, 'frames'), exist_ok=True)
            self.ext = 'tif' if fmt == 'tiff16' else 'png'
            self.i = 0

    def write(self, img):
        """Append one frame."""
        if self.fmt in ('ffv1', 'mp4v', 'mjpg'):
            self.vw.write(img)
        else:
            cv2.imwrite(os.path.join(self.d, 'frames', f'{self.i:06d}.{self.ext}'), img)
            self.i += 1

    def close(self):
        """Finish the video file (nothing to do for image sequences)."""
        if self.fmt in ('ffv1', 'mp4v', 'mjpg'):
            self.vw.release()

    def read_back(self):
        """Yield the frames as stored (decoded from the file or read from the sequence)."""
        if self.fmt in ('ffv1', 'mp4v', 'mjpg'):
            cap = cv2.VideoCapture(os.path.join(self.d, self.rel))
            while True:
                ok, f = cap.read()
                if not ok:
                    break
                yield f if self.color else f[..., 0]
            cap.release()
        else:
            fd = os.path.join(self.d, 'frames')
            for f in sorted(os.listdir(fd)):
                yield cv2.imread(os.path.join(fd, f), cv2.IMREAD_UNCHANGED)


# ----------------------------------------------------------------------------------------------
# cases
# ----------------------------------------------------------------------------------------------
def mark(kind, polarity='dark', rot=0.0, **p):
    return {'kind': kind, 'p': p, 'rot': rot, 'polarity': polarity}


def case(**kw):
    c = {'size': (640, 480), 'fps': 30, 'exp': 0.4, 'frames': 240, 'fmt': 'ffv1', 'psf': 0.8,
         'mpp': 2.0e-6, 'category': 'plain',
         'sensor': {'bits': 8, 'fwe': 6000, 'read': 8.0, 'black': 6},
         'stator_motion': {'p2p': 200, 'hz': 1.0, 'l_over_r': 3.0, 'phase': 0.4},
         'slider_motion': {'mode': 'follow', 'gain': 0.7, 'tau': 0.025, 'h3': 0.03, 'phi3': 0.5},
         'bg': (0.12, 0.08, 0.15), 'margin': (20, 20), 'roi_h': (3.0, 3.0)}
    c.update(kw)
    return c


def plate(mk, P, M, edges, ym, texture=(), **kw):
    d = {'mark': mk, 'P': P, 'M': M, 'edges': edges, 'ym': ym, 'texture': list(texture)}
    d.update(kw)
    return d


G = lambda size, amp: {'kind': 'grain', 'size': size, 'amp': amp}   # noqa: E731

CASES = {
    # --- plain plates ---------------------------------------------------------------------------
    'p01_square_ffv1': case(
        seed=101, stator=plate(mark('square', w=16, h=16), 0.55, 0.12, (40, 200), 120.0),
        slider=plate(mark('square', w=16, h=16), 0.50, 0.10, (250, 430), 340.0),
        light={'vignette': 0.85}, hot={'hot': 3}, roi_h=(3.0, 2.5), margin=(15, 25), mpp=2.0e-6,
        note='baseline: dark squares, follow (gain 0.7, tau 25 ms, 3 % 3rd harmonic)'),
    'p02_rect_rot3_vignette_25fps': case(
        seed=102, size=(720, 480), fps=25, exp=0.3, frames=200, psf=1.0,
        stator_motion={'p2p': 160, 'hz': 0.8, 'l_over_r': 4.0, 'phase': 1.0},
        slider_motion={'mode': 'follow', 'gain': 0.6, 'tau': 0.040, 'h3': 0.04, 'phi3': 1.2},
        stator=plate(mark('rect', rot=3.0, w=30, h=14), 0.60, 0.15, (50, 210), 130.5),
        slider=plate(mark('rect', rot=-4.0, w=24, h=12), 0.58, 0.18, (260, 440), 350.0),
        light={'vignette': 0.55}, roi_h=(4.0, 4.0), margin=(30, 12), mpp=1.5e-6,
        note='rectangles rotated +3 / -4 deg, strong vignetting'),
    'p03_disc_fullexp_15fps': case(
        seed=103, fps=15, exp=1.0, frames=150, psf=0.7,
        stator_motion={'p2p': 220, 'hz': 1.5, 'l_over_r': 2.2, 'phase': 0.2},
        slider_motion={'mode': 'follow', 'gain': 0.8, 'tau': 0.015, 'h3': 0.02, 'phi3': 2.0},
        stator=plate(mark('disc', r=10), 0.55, 0.10, (40, 200), 120.0),
        slider=plate(mark('disc', r=10), 0.52, 0.12, (250, 430), 340.0),
        roi_h=(2.5, 3.0), margin=(25, 25), mpp=3.0e-6,
        note='exposure = whole frame period: up to ~75 px smear'),
    'p04_ring_cross_hd60_gradient': case(
        seed=104, size=(1280, 720), fps=60, exp=0.25, frames=240, psf=1.1,
        stator_motion={'p2p': 400, 'hz': 0.5, 'l_over_r': 5.0, 'phase': 2.0},
        slider_motion={'mode': 'follow', 'gain': 0.5, 'tau': 0.060, 'h3': 0.05, 'phi3': 0.1},
        stator=plate(mark('ring', ro=14, ri=8), 0.55, 0.10, (80, 300), 190.0),
        slider=plate(mark('cross', L=26, t=6), 0.55, 0.10, (380, 620), 500.0),
        light={'gradient': {'amp': 0.25, 'angle': 0.3, 'turn': 1.5}}, roi_h=(3.0, 3.5),
        margin=(35, 20), mpp=1.0e-6, note='ring and cross, drifting lighting gradient, HD'),
    'p05_bars_flicker_120fps': case(
        seed=105, fps=120, exp=0.8, frames=300, psf=0.8,
        stator_motion={'p2p': 60, 'hz': 4.0, 'l_over_r': 3.0, 'phase': 0.0},
        slider_motion={'mode': 'follow', 'gain': 0.65, 'tau': 0.010, 'h3': 0.03, 'phi3': 0.0},
        stator=plate(mark('bars', w=4, gap=8, h=20), 0.55, 0.12, (40, 200), 120.0),
        slider=plate(mark('square', w=14, h=14), 0.55, 0.12, (250, 430), 340.0),
        light={'flicker': {'hz': 100, 'depth': 0.25}},
        sensor={'bits': 8, 'fwe': 5000, 'read': 8, 'black': 6},
        roi_h=(2.5, 3.0), margin=(15, 15), mpp=4.0e-6,
        note='pair of bars; 100 Hz mains ripple beating with 120 fps'),
    'p06_lowlight_png10': case(
        seed=106, fmt='png16', align='left', exp=0.3, frames=200, psf=0.9,
        stator_motion={'p2p': 120, 'hz': 1.0, 'l_over_r': 3.5, 'phase': 0.5},
        stator=plate(mark('disc', r=10), 0.40, 0.40 * 0.93, (40, 200), 120.0),
        slider=plate(mark('square', w=18, h=18), 0.36, 0.36 * 0.94, (250, 430), 340.0),
        sensor={'bits': 10, 'fwe': 2500, 'read': 5.0, 'black': 16},
        roi_h=(3.0, 3.0), margin=(15, 15), mpp=2.5e-6,
        note='low light (plate ~1000 e-), contrast 7 % / 6 %; 16-bit PNG, 10-bit data '
             'left-aligned (x64)'),
    'p07_bigmarks_defocus_hd': case(
        seed=107, size=(1280, 720), fps=30, exp=0.2, frames=180, psf=0.6, defocus=2.5,
        stator_motion={'p2p': 300, 'hz': 0.7, 'l_over_r': 2.5, 'phase': 1.5},
        slider_motion={'mode': 'follow', 'gain': 0.7, 'tau': 0.030, 'h3': 0.03, 'phi3': 0.7},
        stator=plate(mark('square', w=56, h=56), 0.55, 0.12, (60, 330), 195.0),
        slider=plate(mark('disc', r=24), 0.55, 0.12, (390, 680), 535.0),
        roi_h=(2.2, 2.2), margin=(20, 20), mpp=1.0e-6,
        note='marks > 40 px; defocus (pillbox r 2.5 px on pixels) + Gaussian 0.6'),
    'p08_asym_triangle_L': case(
        seed=108, exp=0.3, frames=200,
        stator_motion={'p2p': 180, 'hz': 1.0, 'l_over_r': 3.0, 'phase': 0.8},
        stator=plate(mark('triangle', w=22, h=20), 0.55, 0.12, (40, 200), 120.0),
        slider=plate(mark('L', s=20, t=6), 0.55, 0.12, (250, 430), 340.0),
        roi_h=(3.5, 3.5), margin=(20, 20), mpp=2.0e-6,
        note='asymmetric marks: triangle (apex +x) and L; truth = area centroid'),
    'p09_qr_vibration_60fps': case(
        seed=109, size=(720, 480), fps=60, exp=0.5, frames=240, psf=0.9,
        stator_motion={'p2p': 100, 'hz': 2.0, 'l_over_r': 3.0, 'phase': 0.1},
        stator=plate(mark('qr', cell=4), 0.55, 0.10, (40, 200), 120.0),
        slider=plate(mark('disc', r=7), 0.55, 0.12, (250, 430), 340.0),
        vibration=0.3, roi_h=(3.0, 4.0), margin=(20, 20), mpp=2.0e-6,
        note='QR-like 5x5 block (4 px cells); camera vibration <= 0.3 px per frame'),
    'p10_occlusion_probe_fibre': case(
        seed=110, exp=0.5, frames=240,
        stator_motion={'p2p': 200, 'hz': 1.0, 'l_over_r': 3.0, 'phase': 0.4},
        stator=plate(mark('square', w=18, h=18), 0.55, 0.12, (40, 200), 120.0),
        slider=plate(mark('disc', r=9), 0.55, 0.12, (250, 430), 340.0),
        dirt={'probes': [{'x': 330, 'tip_r': 6, 'taper': 1.0, 'rad': 0.10,
                          'frames': [70, 95, 120, 150, 175], 'depth': [-60, 150, 150, 150, -60]}],
              'fibres': [{'p0': (300, 250), 'p1': (330, 330), 'p2': (305, 430), 'w': 1.3,
                          'opacity': 0.85, 'rad': 0.05}]},
        roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='tool tip occludes the stator mark partly/totally (frames 94-155); lint fibre over '
             'the slider path'),
    'p11_mpeg4_lossy': case(
        seed=111, fmt='mp4v', exp=0.3, frames=240, psf=0.9,
        stator=plate(mark('disc', r=9), 0.55, 0.12, (40, 200), 120.0),
        slider=plate(mark('square', w=16, h=16), 0.55, 0.12, (250, 430), 340.0),
        hot={'hot': 4, 'warm': 6}, roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='lossy MPEG-4 part 2 (.mp4, OpenCV has no H.264 encoder here); '
             'truth = rendered scene'),
    'p12_shadow_hotpixels': case(
        seed=112, size=(720, 480), fps=25, exp=0.5, frames=200, psf=0.8,
        stator_motion={'p2p': 150, 'hz': 0.9, 'l_over_r': 2.5, 'phase': 1.1},
        stator=plate(mark('cross', L=22, t=6), 0.58, 0.12, (40, 200), 120.0),
        slider=plate(mark('ring', ro=10, ri=5), 0.58, 0.12, (250, 430), 340.0),
        light={'shadow': {'f0': 40, 'f1': 160, 'x0': 150, 'x1': 600, 'yc': 200, 'tilt': 20,
                          'width': 40, 'pen': 8, 'depth': 0.45}},
        hot={'hot': 5, 'hot_roi': 4, 'warm': 10, 'warm_roi': 6}, roi_h=(3.0, 3.0), margin=(20, 20),
        mpp=2.0e-6, note='a soft shadow sweeps over both ROIs; hot/warm pixels inside the ROIs'),
    'p25_mjpeg_stickslip': case(
        seed=125, fmt='mjpg', exp=0.5, frames=240, psf=0.9,
        slider_motion={'mode': 'stickslip', 'gain': 0.7, 'tau': 0.02, 'h3': 0.0, 'brk': 8.0,
                       'rel': 0.4, 'tau_slip': 0.003},
        stator=plate(mark('square', w=18, h=18), 0.55, 0.12, (40, 200), 120.0),
        slider=plate(mark('disc', r=9), 0.55, 0.12, (250, 430), 340.0),
        roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='MJPEG .avi (lossy); slider stick-slips (breaks away at 8 px, slips with tau 3 ms)'),
    # --- textured plates ------------------------------------------------------------------------
    't13_texture_multigrain': case(
        seed=113, category='textured', exp=0.4,
        stator=plate(mark('square', w=16, h=16), 0.55, 0.12, (40, 200), 120.0,
                     texture=[G(1.0, 0.06), G(4.0, 0.05), G(16.0, 0.08)]),
        slider=plate(mark('disc', r=8), 0.55, 0.12, (250, 430), 340.0,
                     texture=[G(1.5, 0.04), G(6.0, 0.10)]),
        roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='multiplicative grain 1/4/16 px (6/5/8 %) and 1.5/6 px (4/10 %)'),
    't14_speckle_60fps': case(
        seed=114, category='textured', fps=60, exp=0.3, frames=240,
        stator_motion={'p2p': 160, 'hz': 2.0, 'l_over_r': 3.0, 'phase': 0.4},
        stator=plate(mark('disc', r=10), 0.55, 0.12, (40, 200), 120.0,
                     texture=[{'kind': 'speckle', 'size': 1.5, 'amp': 0.12}]),
        slider=plate(mark('ring', ro=12, ri=7), 0.55, 0.12, (250, 430), 340.0,
                     texture=[{'kind': 'speckle', 'size': 2.5, 'amp': 0.10}]),
        roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6, note='speckle 12 % / 10 %'),
    't15_scratches_windowdust': case(
        seed=115, category='textured', size=(720, 480), exp=0.5,
        stator=plate(mark('rect', w=22, h=14), 0.58, 0.14, (40, 200), 120.0,
                     texture=[G(2.0, 0.03), {'kind': 'scratches', 'n_along': 25, 'n_across': 90,
                                            'len_along': (80, 400), 'len_across': (10, 60),
                                            'width': (0.4, 0.9), 'depth': (0.04, 0.12)}]),
        slider=plate(mark('rect', w=14, h=22), 0.58, 0.14, (250, 430), 340.0,
                     texture=[G(2.0, 0.03), {'kind': 'scratches', 'n_along': 25, 'n_across': 90,
                                            'len_along': (80, 400), 'len_across': (10, 60),
                                            'width': (0.4, 0.9), 'depth': (0.04, 0.12)}]),
        dirt={'dust': [{'x': 330, 'y': 124, 'r': 7, 'soft': 4, 'opacity': 0.45},
                       {'x': 420, 'y': 330, 'r': 5, 'soft': 3, 'opacity': 0.35}]},
        roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='scratches along and across x; static window dust on both mark paths'),
    't16_brushed_particle_hd': case(
        seed=116, category='textured', size=(1280, 720), fps=30, exp=0.3, frames=200, psf=1.0,
        stator_motion={'p2p': 350, 'hz': 0.6, 'l_over_r': 3.0, 'phase': 0.9},
        stator=plate(mark('square', w=20, h=20), 0.60, 0.15, (80, 300), 190.0,
                     texture=[{'kind': 'brushed', 'len': 60, 'width': 0.6, 'amp': 0.07},
                              G(1.0, 0.02),
                              {'kind': 'particles',
                               'items': [(19.0, -7.0, 2.5, 0.7), (-40, 12, 1.5, 0.5)]}]),
        slider=plate(mark('cross', L=24, t=6), 0.60, 0.15, (380, 620), 500.0,
                     texture=[{'kind': 'brushed', 'len': 40, 'width': 0.5, 'amp': 0.06},
                              G(1.0, 0.02),
                              {'kind': 'particles', 'items': [(-17.0, 9.0, 2.0, 0.6)]}]),
        roi_h=(3.0, 3.0), margin=(25, 25), mpp=1.0e-6,
        note='brushed metal (streaks along x) + particles on the plate next to the marks'),
    't17_grid_lines_25fps': case(
        seed=117, category='textured', fps=25, exp=0.3, frames=200,
        stator_motion={'p2p': 140, 'hz': 0.9, 'l_over_r': 3.0, 'phase': 0.3},
        stator=plate(mark('disc', r=12), 0.55, 0.10, (40, 200), 120.0,
                     texture=[{'kind': 'grid', 'period': 24, 'width': 0.6, 'depth': 0.10,
                               'phase': 5.0, 'phase_y': 3.0}, G(1.5, 0.02)]),
        slider=plate(mark('square', w=18, h=18), 0.55, 0.10, (250, 430), 340.0,
                     texture=[{'kind': 'grid', 'period': 20, 'width': 0.5, 'depth': 0.08,
                               'phase': 7.0, 'phase_y': 2.0}, G(1.5, 0.02)]),
        roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='etched grid lines moving with the plates (period 24 / 20 px, 10 / 8 %)'),
    't18_lowcontrast_tiff10_stickslip': case(
        seed=118, category='textured', fmt='tiff16', align='right', exp=0.25, frames=240, psf=0.8,
        slider_motion={'mode': 'stickslip', 'gain': 0.6, 'tau': 0.03, 'h3': 0.02, 'brk': 6.0,
                       'rel': 0.3, 'tau_slip': 0.002},
        stator=plate(mark('square', w=26, h=26), 0.40, 0.40 * 0.92, (40, 200), 120.0,
                     texture=[G(1.0, 0.02)]),
        slider=plate(mark('disc', r=13), 0.40, 0.40 * 0.93, (250, 430), 340.0,
                     texture=[G(1.0, 0.02)]),
        sensor={'bits': 10, 'fwe': 10000, 'read': 12.0, 'black': 16},
        roi_h=(2.5, 2.5), margin=(20, 20), mpp=2.0e-6,
        note='16-bit TIFF, 10-bit data right-aligned; contrast 8 / 7 %; fine texture 2 %; '
             'stick-slip'),
    't19_rgb_colour': case(
        seed=119, category='textured', color=True, exp=0.4,
        stator=plate(mark('disc', r=9), (0.60, 0.18, 0.12), (0.10, 0.20, 0.55), (40, 200), 120.0,
                     texture=[G(1.5, 0.04), G(8.0, 0.03)]),
        slider=plate(mark('square', w=16, h=16), (0.55, 0.45, 0.15), (0.08, 0.35, 0.10),
                     (250, 430), 340.0,
                     texture=[G(1.5, 0.04)]),
        bg=(0.10, 0.08, 0.12), roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='colour: blue dot on red anodised plate, green square on ochre plate; FFV1 BGR'),
    't20_bayer_raw': case(
        seed=120, category='textured', bayer=True, exp=0.4, frames=200,
        stator=plate(mark('disc', r=9), (0.55, 0.50, 0.42), (0.12, 0.12, 0.14), (40, 200), 120.0,
                     texture=[G(2.0, 0.03)]),
        slider=plate(mark('square', w=16, h=16), (0.52, 0.50, 0.45), (0.10, 0.11, 0.12),
                     (250, 430), 340.0,
                     texture=[G(2.0, 0.03)]),
        roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='raw Bayer RGGB mosaic written as mono (no demosaicing), '
             'raw channel gains 0.8/1/0.7'),
    't26_texture_vibration_120fps': case(
        seed=126, category='textured', fps=120, exp=0.5, frames=300,
        stator_motion={'p2p': 80, 'hz': 3.0, 'l_over_r': 2.0, 'phase': 0.0},
        slider_motion={'mode': 'follow', 'gain': 0.55, 'tau': 0.012, 'h3': 0.04, 'phi3': 1.0},
        stator=plate(mark('ring', ro=11, ri=6), 0.55, 0.12, (40, 200), 120.0,
                     texture=[G(3.0, 0.10), G(1.0, 0.04)]),
        slider=plate(mark('bars', w=4, gap=6, h=18), 0.55, 0.12, (250, 430), 340.0,
                     texture=[G(3.0, 0.10), G(1.0, 0.04)]),
        vibration=0.3, hot={'hot': 3, 'hot_roi': 2, 'warm': 8}, roi_h=(3.0, 3.0), margin=(15, 15),
        mpp=3.0e-6, note='10 % coarse texture, camera vibration <= 0.3 px, hot pixels'),
    # --- bright marks ---------------------------------------------------------------------------
    'b21_ir_led_saturated_glint': case(
        seed=121, category='bright', fps=60, exp=0.05, frames=240, psf=0.9,
        stator_motion={'p2p': 250, 'hz': 2.0, 'l_over_r': 3.0, 'phase': 0.6},
        stator=plate(mark('led', 'bright', sigma=3.0, order=3), 0.08, 3.0, (40, 200), 120.0,
                     texture=[G(2.0, 0.05)]),
        slider=plate(mark('led', 'bright', sigma=2.5, order=2), 0.08, 2.0, (250, 430), 340.0,
                     texture=[G(2.0, 0.05)]),
        light={'glints': [{'x': 300, 'y': 106, 'sx': 9, 'sy': 3, 'amp': 0.5, 'angle': 10}]},
        roi_h=(3.0, 3.0), margin=(20, 20), mpp=2.0e-6,
        note='IR LED spots with clipped cores (stator peak 3x full scale), short exposure, '
             'glint near the path'),
    'b22_retro_flicker_vignette': case(
        seed=122, category='bright', size=(720, 480), fps=30, exp=0.5, frames=240,
        stator=plate(mark('retro', 'bright', r=8, beads=0.15), 0.18, 0.95, (40, 200), 120.0,
                     texture=[G(3.0, 0.04)]),
        slider=plate(mark('retro', 'bright', r=7, beads=0.15), 0.18, 0.90, (250, 430), 340.0,
                     texture=[G(3.0, 0.04)]),
        light={'flicker': {'hz': 100, 'depth': 0.15}, 'vignette': 0.6}, roi_h=(3.0, 3.0),
        margin=(20, 20), mpp=2.0e-6,
        note='retro-reflective dots (glass-bead texture), 100 Hz flicker at 30 fps, vignetting'),
    'b23_polished_stuck_glint': case(
        seed=123, category='bright', fps=25, exp=0.4, frames=200,
        slider_motion={'mode': 'stuck'},
        stator=plate(mark('polished', 'bright', w=14, h=14), 0.40, 2.0, (40, 200), 120.0,
                     texture=[{'kind': 'brushed', 'len': 30, 'width': 0.6, 'amp': 0.05}]),
        slider=plate(mark('polished', 'bright', w=12, h=12), 0.40, 1.6, (250, 430), 340.0,
                     texture=[{'kind': 'brushed', 'len': 30, 'width': 0.6, 'amp': 0.05}]),
        light={'glints': [{'x': 260, 'y': 135, 'sx': 5, 'sy': 4, 'amp': 0.9},
                          {'x': 330, 'y': 325, 'sx': 12, 'sy': 2.5, 'amp': 0.5, 'angle': -5}]},
        roi_h=(4.0, 4.0), margin=(20, 20), mpp=2.0e-6,
        note='specular polished squares (saturated) on brushed plate; stuck slider; '
             'static glints'),
    'b24_bright_occlusion_png16_hd': case(
        seed=124, category='bright', size=(1280, 720), fmt='png16', align='right', fps=60,
        exp=0.3, frames=240, psf=1.0,
        stator_motion={'p2p': 300, 'hz': 0.8, 'l_over_r': 4.0, 'phase': 0.2},
        slider_motion={'mode': 'follow', 'gain': 0.5, 'tau': 0.05, 'h3': 0.03, 'phi3': 0.3},
        stator=plate(mark('rect', 'bright', w=28, h=12), 0.25, 0.90, (80, 300), 190.0,
                     texture=[G(2.0, 0.04)]),
        slider=plate(mark('rect', 'bright', w=28, h=12), 0.25, 0.90, (380, 620), 500.0,
                     texture=[G(2.0, 0.04)]),
        sensor={'bits': 12, 'fwe': 10000, 'read': 10.0, 'black': 64},
        dirt={'probes': [{'x': 640, 'tip_r': 45, 'taper': 0.15, 'rad': 0.08,
                          'frames': [90, 115, 150, 175], 'depth': [-60, 560, 560, -60]}],
              'fibres': [{'p0': (560, 80), 'p1': (600, 190), 'p2': (575, 300), 'w': 1.5,
                          'opacity': 0.8, 'rad': 0.04}]},
        roi_h=(4.0, 4.0), margin=(30, 30), mpp=1.0e-6,
        note='bright tape rectangles; a wide tool hides the slider (frames 112-130) and passes '
             'over the stator; fibre; 16-bit PNG, 12-bit data right-aligned'),
}


# ----------------------------------------------------------------------------------------------
# rendering of one case
# ----------------------------------------------------------------------------------------------
def sub_times(i, fps, E, nsub=NSUB):
    return i / fps + E * (np.arange(nsub) + 0.5) / nsub


def render_case(name):
    c = CASES[name]
    t_start = time.time()
    rng = np.random.default_rng(c['seed'])
    W, H = c['size']
    fps, n = c['fps'], c['frames']
    E = c['exp'] / fps
    color = c.get('color', False) or c.get('bayer', False)
    C = 3 if color else 1
    d = os.path.join(OUT, name)
    os.makedirs(d, exist_ok=True)
    for f in os.listdir(d):
        if f in ('frames',):
            for g in os.listdir(os.path.join(d, f)):
                os.remove(os.path.join(d, f, g))
        elif os.path.isfile(os.path.join(d, f)):
            os.remove(os.path.join(d, f))

    # --- motion and truth ------------------------------------------------------------------
    st, sm = c['stator_motion'], c['slider_motion']
    t_end = (n - 1) / fps + E
    tg, xg = slider_motion(st, sm, t_end)
    span = {'stator': st['p2p'],
            'slider': float(np.ptp(np.interp(np.linspace(0, t_end, 5000), tg, xg)))}
    cx = {m: W / 2 + rng.uniform(-0.1, 0.1) * (W - span[m]) / 2 + rng.uniform(0, 1)
          for m in ('stator', 'slider')}
    vib = np.zeros(n)
    if c.get('vibration'):
        a = c['vibration']
        ph = rng.uniform(0, 2 * np.pi, 3)
        k = np.arange(n)
        vib = a * (0.5 * np.sin(2 * np.pi * 13.3 * k / fps + ph[0])
                   + 0.3 * np.sin(2 * np.pi * 31.7 * k / fps + ph[1])
                   + 0.2 * rng.uniform(-1, 1, n))
    pos = {'stator': lambda t: cx['stator'] + crank(t, st),
           'slider': lambda t: cx['slider'] + np.interp(t, tg, xg)}
    shifts = {m: np.array([pos[m](sub_times(i, fps, E)) + vib[i] for i in range(n)])
              for m in pos}  # (n, NSUB)

    # --- plates ----------------------------------------------------------------------------
    plates = {}
    for m in ('stator', 'slider'):
        s = shifts[m]
        plates[m] = Plate(c[m], W, H, s.min(), s.max(), c['psf'], rng, grey=grey_weights(c))
    truth = {m: shifts[m].mean(1) + plates[m].u_c for m in plates}

    # --- ROIs --------------------------------------------------------------------------------
    rois = {}
    for m in ('stator', 'slider'):
        hxx, hyy = mark_half_extent(c[m]['mark'])
        mg = c['margin'][0 if m == 'stator' else 1]
        x0 = int(np.floor(truth[m].min() - plates[m].u_c - hxx - mg))
        x1 = int(np.ceil(truth[m].max() - plates[m].u_c + hxx + mg))
        h = int(round(2 * hyy * c['roi_h'][0 if m == 'stator' else 1]))
        y0 = int(round(c[m]['ym'] - h / 2))
        assert (0 <= x0 and x1 < W and c[m]['edges'][0] <= y0
                and y0 + h <= c[m]['edges'][1]), (name, m)
        rois[m] = (x0, y0, x1 - x0 + 1, h)

    scene = Scene(c, W, H, n, fps, E)
    sensor = Sensor(c, rng)
    if c.get('hot'):
        sensor.place_hot((H, W), c['hot'], rng, [rois['stator'], rois['slider']])
    dk = defocus_kernel(c['defocus']) if c.get('defocus') else None

    # background: static rows between/around plates (darker housing, bright chamfers at edges)
    ys = np.arange(H, dtype=float)
    cov = np.zeros(H)
    for p in plates.values():
        cov[p.r0:p.r1] += p.cov_y
    bg_y = (c['bg'][0] * (ys < c['stator']['edges'][0])
            + c['bg'][1] * (ys >= c['stator']['edges'][0]) * (ys < c['slider']['edges'][1])
            + c['bg'][2] * (ys >= c['slider']['edges'][1]))
    for p in ('stator', 'slider'):
        for e, sg in zip(c[p]['edges'], (-1.5, 1.5), strict=True):
            bg_y = bg_y + 0.35 * np.exp(-0.5 * ((ys - e - sg) / max(c['psf'], 0.8)) ** 2)
    bg = (bg_y * np.clip(1 - cov, 0, 1))[:, None] * np.ones((1, W))

    def colours(m):
        P, M = np.atleast_1d(c[m]['P']).astype(float), np.atleast_1d(c[m]['M']).astype(float)
        if c.get('bayer'):
            P, M = P * BAYER_GAIN, M * BAYER_GAIN
        return (np.resize(P, C), np.resize(M, C))

    cols = {m: colours(m) for m in plates}
    need_B = color or any(p.emissive for p in plates.values()) or bool(c.get('dirt'))

    def frame_radiance(i, v, nsub=NSUB, want=('img',)):
        """Noiseless relative radiance (C, H, W) of frame i.

        Optional extras: mark images, derivatives.
        """
        L = scene.lighting(i, v)
        gl = scene.glint(i, v)
        op, orad = scene.dirt(i, v)
        refl = np.repeat(bg[None], C, 0) if C > 1 else bg[None].copy()
        emis = np.zeros((C, H, W))
        extra = {}
        for m, p in plates.items():
            sh = shifts[m][i] if nsub == NSUB else pos[m](sub_times(i, fps, E, nsub)) + vib[i]
            FK = p.kernel(sh)
            P, M = cols[m]
            rows = slice(p.r0, p.r1)
            if need_B or 'B' in want:
                A_img, B_img = p.render(FK, [(1, 0), (0, 1)])
                for ch in range(C):
                    refl[ch, rows] += P[ch] * A_img
                    if p.emissive:
                        emis[ch, rows] += M[ch] * B_img
                    else:
                        refl[ch, rows] += M[ch] * B_img
                extra[m + '_B'] = B_img
            else:
                (img,) = p.render(FK, [(P[0], M[0])])
                refl[0, rows] += img
            # d(radiance)/d(shift): whole plate, and mark only (plate untextured)
            if 'deriv' in want:
                dA, dB, dA0 = p.render(FK, [(1, 0), (0, 1), (0, 0, 1)], deriv=True)
                for key, dplate in (('d_' + m, dA), ('dmark_' + m, 0 * dA if p.emissive else dA0)):
                    dr, de = np.zeros((C, H, W)), np.zeros((C, H, W))
                    for ch in range(C):
                        dr[ch, rows] = P[ch] * dplate + (0 if p.emissive else M[ch] * dB)
                        if p.emissive:
                            de[ch, rows] = M[ch] * dB
                    extra[key] = finish(dr * L + de, op, None, 0.0)
        radiance = finish(refl * L + emis + (gl if gl is not None else 0), op,
                          orad * L if op is not None else None, 1.0)
        return radiance, extra, op

    def finish(radiance, op, orad, use_rad):
        if op is not None:
            radiance = radiance * (1 - op) + (op * orad if use_rad else 0)
        if dk is not None:
            radiance = np.stack([cv2.filter2D(ch.astype(np.float32), -1, dk,
                                              borderType=cv2.BORDER_REFLECT)
                                 for ch in radiance])
        return radiance

    def to_sensor_plane(radiance):
        """(C,H,W) radiance -> what the sensor sees: mono, colour, or the raw Bayer mosaic."""
        if c.get('bayer'):
            return bayer_mosaic(radiance)
        return radiance[0] if C == 1 else radiance

    # --- render ---------------------------------------------------------------------------------
    writer = Writer(d, c['fmt'], W, H, fps, color=c.get('color', False))
    visible = {m: np.ones(n) for m in plates}
    written = []
    noise_res = []
    check_frames = {0, n // 3, 2 * n // 3}
    for i in range(n):
        radiance, extra, op = frame_radiance(i, vib[i])
        if op is not None:
            for m, p in plates.items():
                B = extra[m + '_B']
                vis = float((B * (1 - op[p.r0:p.r1])).sum() / B.sum())
                visible[m][i] = 1.0 if vis > 0.99995 else round(min(max(vis, 0.0), 1.0), 4)
        plane = to_sensor_plane(radiance)
        dn, dn_clean = sensor.expose(plane)
        out = encode(dn, c)
        writer.write(out)
        written.append(out)
        if i in check_frames:
            ok = (dn_clean < sensor.dn_max - 0.5) & (dn > 0)
            if sensor.hot:
                for r, q, _k, _ in sensor.hot:
                    ok[..., r, q] = False
            noise_res.append((dn_clean, sensor.variance(plane), ok, i))
    writer.close()

    # --- self-checks ----------------------------------------------------------------------------
    checks = {}
    # read-back
    rb = list(writer.read_back())
    mx, sq = 0.0, 0.0
    for a, b in zip(rb, written, strict=False):   # read-back may be short
        df = a.astype(np.float32) - b.astype(np.float32)
        mx, sq = max(mx, float(np.abs(df).max())), sq + float(np.mean(df ** 2))
    checks['readback'] = {'frames_read': len(rb), 'frames_written': len(written),
                          'max_abs_diff': mx,
                          'rms_diff': float(np.sqrt(sq / max(1, len(rb)))),
                          'bit_exact': bool(len(rb) == len(written) and mx == 0)}
    # noise: written (read back) minus noiseless, in sensor DN, vs the model
    scale = data_scale(c)
    r_meas, r_exp = [], []
    for dn_clean, var, ok, i in noise_res:
        back = rb[i].astype(float)
        if c.get('color'):
            back = back[..., ::-1].transpose(2, 0, 1)
        res = back / scale - dn_clean
        r_meas.append(res[ok])
        r_exp.append(var[ok])
    rm, re = np.concatenate(r_meas), np.concatenate(r_exp)
    checks['noise'] = {'measured_std_dn': float(rm.std()),
                       'expected_std_dn': float(np.sqrt(re.mean())),
                       'ratio': float(rm.std() / np.sqrt(re.mean())),
                       'mean_offset_dn': float(rm.mean())}
    # exposure: truth from NSUB midpoint samples vs a dense integral; image vs 16x denser sampling
    dense_err = 0.0
    for i in np.linspace(0, n - 1, 12).astype(int):
        for m in plates:
            tt = sub_times(i, fps, E, 65536)
            dense_err = max(dense_err,
                            abs(pos[m](tt).mean() + vib[i] + plates[m].u_c - truth[m][i]))
    # most smeared
    ifr = int(np.argmax(np.abs(np.diff(shifts['stator'][:, [0, -1]], axis=1)).ravel()))
    I1, _, _ = frame_radiance(ifr, vib[ifr])
    I2, _, _ = frame_radiance(ifr, vib[ifr], nsub=16 * NSUB)
    checks['exposure'] = {'truth_vs_dense_max_px': float(dense_err), 'image_frame': ifr,
                          'smear_px': float(np.ptp(shifts['stator'][ifr])),
                          'image_vs_16x_dense_max_dn':
                              float(np.abs(I1 - I2).max() * sensor.dn_max)}
    # centroid of the noiseless mark image (smear + pixels + PSF) over the ROI vs truth
    cen = {}
    for i in np.linspace(0, n - 1, 9).astype(int):
        _, ex, _ = frame_radiance(i, vib[i], want=('B',))
        for m, p in plates.items():
            X, Y, w, h = rois[m]
            B = ex[m + '_B'][Y - p.r0:Y - p.r0 + h, X:X + w]
            cx_ = (B.sum(0) * np.arange(X, X + w)).sum() / B.sum()
            cen.setdefault(m, []).append(cx_ - truth[m][i])
    checks['centroid'] = {m: {'max_abs_err_px': float(np.max(np.abs(v))),
                              'symmetric': c[m]['mark']['kind'] in SYMMETRIC,
                              'u_c_px': plates[m].u_c} for m, v in cen.items()}
    for m, p in plates.items():    # textured plates: contrast-weighted centroid vs shape centroid
        checks['centroid'][m]['texture_contrast_centroid_shift_px'] = p.tex_shift

    # --- Cramer-Rao bound: Fisher information of the plate's x shift over the ROI --------------
    crb, crb_mark = {}, {}
    fr = [i for i in np.linspace(1, n - 2, CRB_FRAMES).astype(int)
          if all(visible[m][i] == 1 for m in plates)]
    inv = {m: [] for m in plates}
    invm = {m: [] for m in plates}
    for i in fr:
        radiance, ex, _ = frame_radiance(i, vib[i], want=('deriv',))
        plane = to_sensor_plane(radiance)
        var = sensor.variance(plane)
        for m in plates:
            X, Y, w, h = rois[m]
            for key, acc in (('d_' + m, inv), ('dmark_' + m, invm)):
                dpl = to_sensor_plane(ex[key]) * sensor.gain * sensor.fwe
                sat = plane * sensor.gain * sensor.fwe + sensor.black >= sensor.dn_max
                fi_map = np.where(sat, 0, dpl ** 2 / var)
                if c.get('color'):      # the tracker sees grey: 0.299 R + 0.587 G + 0.114 B
                    wgt = np.array([0.299, 0.587, 0.114])[:, None, None]
                    fi_map = (np.where(sat.any(0), 0,
                                       (wgt * dpl).sum(0) ** 2 / (wgt ** 2 * var).sum(0)))
                fi = fi_map[..., Y:Y + h, X:X + w].sum()
                acc[m].append(1 / fi)
    for m in plates:
        crb[m] = float(np.sqrt(np.mean(inv[m])))
        crb_mark[m] = float(np.sqrt(np.mean(invm[m])))

    # --- write truth and metadata -------------------------------------------------------------
    with open(os.path.join(d, 'truth.csv'), 'w', newline='') as fh:
        wr = csv.writer(fh)
        wr.writerow(['frame', 'time', 'stator_x', 'slider_x', 'stator_visible', 'slider_visible'])
        for i in range(n):
            wr.writerow([i, f'{i / fps + E / 2:.9f}', f'{truth["stator"][i]:.6f}',
                         f'{truth["slider"][i]:.6f}',
                         f'{visible["stator"][i]:.4f}', f'{visible["slider"][i]:.4f}'])
    marks = {}
    for m in plates:
        mk = c[m]['mark']
        hxx, hyy = mark_half_extent(mk)
        marks[m] = {'kind': mk['kind'], 'polarity': mk['polarity'], 'rot_deg': mk.get('rot', 0.0),
                    'p': mk['p'], 'y': c[m]['ym'], 'half_w': hxx, 'half_h': hyy,
                    'symmetric': mk['kind'] in SYMMETRIC,
                    'truth_offset_from_shape_origin_px': plates[m].u_c,
                    'plate_level': c[m]['P'], 'mark_level': c[m]['M'],
                    'texture': c[m].get('texture', []),
                    'motion': st if m == 'stator' else sm}
    meta = {'name': name, 'note': c.get('note', ''), 'fps': fps, 'exposure': E,
            'exposure_fraction': c['exp'],
            'frames': n, 'meters_per_pixel': c['mpp'], 'size': [W, H],
            'rois': {m: ','.join(map(str, rois[m])) for m in ('slider', 'stator')},
            'marks': marks, 'category': c['category'], 'video': writer.rel,
            'format': format_note(c) + (' (RGB colour)' if c.get('color') else '')
            + (' (raw Bayer RGGB mosaic)' if c.get('bayer') else ''),
            'color': bool(c.get('color')),
            'crb_px': crb, 'crb_mark_only_px': crb_mark,
            'crb_note': 'sqrt(mean over %d clear frames of 1/F), F = sum over ROI pixels of '
                        '(dmu/dx)^2/var, mu = noiseless DN of the rendered frame, dmu/dx its '
                        'derivative w.r.t. the plate x shift (whole plate; crb_mark_only_px: '
                        'mark only), var = gain^2 (mu_e + read^2) + 1/12 DN^2, saturated pixels '
                        'excluded; lossy coding ignored' % len(fr),
            'psf_sigma_px': c['psf'], 'defocus_radius_px': c.get('defocus'),
            'sensor': c['sensor'], 'light': c.get('light', {}), 'dirt': c.get('dirt', {}),
            'hot_pixels': c.get('hot', {}), 'vibration_px': c.get('vibration', 0.0),
            'nsub': NSUB, 'fine_grid': [SX, SY], 'seed': c['seed'],
            'selfcheck': checks, 'render_seconds': round(time.time() - t_start, 1)}
    with open(os.path.join(d, 'case.json'), 'w') as fh:
        json.dump(meta, fh, indent=1,
                  default=lambda o: o.tolist() if hasattr(o, 'tolist') else str(o))
    return meta


BAYER_GAIN = np.array([0.8, 1.0, 0.7])


def grey_weights(c):
    """How the channels add up in the grey image a tracker sees.

    Colour: cv2 BGR2GRAY; Bayer: mosaic mean.
    """
    if c.get('color'):
        return np.array([0.299, 0.587, 0.114])
    if c.get('bayer'):
        return np.array([0.25, 0.5, 0.25]) * BAYER_GAIN
    return np.array([1.0])


def format_note(c):
    f = c['fmt']
    if f in ('png16', 'tiff16'):
        b = c['sensor']['bits']
        how = (f'left-aligned (x{2 ** (16 - b)})' if c.get('align') == 'left'
               else f'right-aligned (0..{2 ** b - 1})')
        return f"16-bit {'PNG' if f == 'png16' else 'TIFF'} sequence, {b}-bit data {how}"
    return {'ffv1': '8-bit FFV1 .mkv (lossless)', 'mp4v': '8-bit MPEG-4 part 2 .mp4 (lossy)',
            'mjpg': '8-bit MJPEG .avi (lossy)'}[f]


def data_scale(c):
    """Factor between sensor DN and the stored value (left-aligned data in a 16-bit container)."""
    return 2 ** (16 - c['sensor']['bits']) if c.get('align') == 'left' else 1


def encode(dn, c):
    """Sensor DN -> the array written: uint8 (mono or BGR) or uint16 (scaled per container)."""
    if c['fmt'] in ('png16', 'tiff16'):
        return (dn * data_scale(c)).astype(np.uint16)
    if c.get('color'):
        return np.ascontiguousarray(dn[::-1].transpose(1, 2, 0)).astype(np.uint8)
    return dn.astype(np.uint8)


def bayer_mosaic(radiance):
    """RGGB: R at (even row, even col), B at (odd, odd), G elsewhere."""
    out = radiance[1].copy()
    out[0::2, 0::2] = radiance[0][0::2, 0::2]
    out[1::2, 1::2] = radiance[2][1::2, 1::2]
    return out


def selftest():
    """Compare the Plate renderer with the analytic pixel integral of a square, static and smeared.

    Analytic: radiance P - (P - M) * box(x) * box(y), blurred by a Gaussian (sigma s), for the
    smeared case averaged over a uniform shift in [x0 - L/2, x0 + L/2], and integrated over each
    pixel; per axis this needs antiderivatives of Phi(u/s) (J1) and of J1 (J2).
    """
    from scipy.special import erf

    def J1(u, s):
        z = u / s
        return s * (z * 0.5 * (1 + erf(z / np.sqrt(2)))
                    + np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi))

    def J2(u, s):
        z = u / s
        return s * s * 0.5 * ((z * z + 1) * 0.5 * (1 + erf(z / np.sqrt(2)))
                              + z * np.exp(-0.5 * z * z) / np.sqrt(2 * np.pi))

    def box_px(c, a, b, s, L=0.0):
        """Pixel integrals (centres c) of box [a, b] * Gaussian(s), smeared uniformly over L."""
        lo, hi = c - 0.5, c + 0.5
        if L == 0:
            return (J1(hi - a, s) - J1(lo - a, s)) - (J1(hi - b, s) - J1(lo - b, s))

        def edge(e):
            return (J2(hi - e + L / 2, s) - J2(lo - e + L / 2, s)
                    - J2(hi - e - L / 2, s) + J2(lo - e - L / 2, s)) / L

        return edge(a) - edge(b)

    rng = np.random.default_rng(0)
    W, H, P, M, w, s = 128, 80, 0.6, 0.1, 13.0, 0.8
    worst = 0.0
    for x0, L in ((40.0, 0), (40.625, 0), (40.3, 0), (41.77, 0), (60.3, 20.3), (58.91, 41.7)):
        spec = plate(mark('square', w=w, h=w), P, M, (10, 70), 40.5)
        p = Plate(spec, W, H, x0 - L / 2 - 1, x0 + L / 2 + 1, s, rng)
        sh = x0 + L * ((np.arange(NSUB) + 0.5) / NSUB - 0.5)
        A, B = p.render(p.kernel(sh), [(1, 0), (0, 1)])
        img = P * A + M * B
        xs, ys = np.arange(W), np.arange(p.r0, p.r1)
        ref = (P * box_px(ys, 10, 70, s)[:, None]
               - (P - M) * np.outer(box_px(ys, 40.5 - w / 2, 40.5 + w / 2, s),
                                    box_px(xs, x0 - w / 2, x0 + w / 2, s, L)))
        err = float(np.abs(img - ref).max() / (P - M))
        worst = max(worst, err)
        print(f'square at x = {x0:6.3f}, smear {L:4.1f} px ({NSUB} samples) vs analytic pixel '
              f'integral: max |diff| = {err:.2e} of the contrast')
    return worst


def main():
    args = sys.argv[1:]
    if args == ['--selftest']:
        selftest()
        return
    if args == ['--list']:
        for k, c in CASES.items():
            print(f'{k:34s} {c.get("note", "")}')
        return
    names = args or list(CASES)
    for nm in names:
        t = time.time()
        meta = render_case(nm)
        ck = meta['selfcheck']
        print(f"{nm:34s} {time.time() - t:6.1f}s"
              f"  crb {meta['crb_px']['stator']:.4f}/{meta['crb_px']['slider']:.4f}"
              f"  readback exact={ck['readback']['bit_exact']}"
              f" max={ck['readback']['max_abs_diff']:.0f}"
              f"  noise ratio {ck['noise']['ratio']:.3f}"
              f"  centroid {max(v['max_abs_err_px'] for v in ck['centroid'].values()):.2e}"
              f"  dense {ck['exposure']['truth_vs_dense_max_px']:.1e}"
              f"/{ck['exposure']['image_vs_16x_dense_max_dn']:.1e}DN",
              flush=True)


if __name__ == '__main__':
    main()
