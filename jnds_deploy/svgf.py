"""SVGF, the classical real-time baseline (Schied et al., "Spatiotemporal Variance-Guided
Filtering", HPG 2017), at native resolution, for the run-time/error benchmark.

Faithful to the paper's algorithm, per illumination signal (diffuse and specular, both
demodulated, as our renderer writes them):

1. temporal accumulation: the previous integrated colour and first/second luminance
   moments are reprojected along the motion vectors (bilinear, taps rejected by depth and
   normal consistency); an exponential moving average with alpha = max(0.2, 1 / history
   length) for colour and moments (the paper's 0.2, with a cumulative average while the
   history is short);
2. variance estimation: second minus squared first moment; where fewer than 4 frames are
   accumulated, from a 7x7 bilateral neighbourhood of the current frame instead;
3. a 5-level edge-avoiding a-trous wavelet (5x5 B3 spline, step 2^i) with the paper's
   edge-stopping functions: depth (sigma_z = 1, scaled by the depth gradient), normal
   (sigma_n = 128), luminance (sigma_l = 4, scaled by the 3x3-Gaussian-prefiltered
   standard deviation); variance is filtered with squared weights; the output of the
   first level becomes the colour history.

Then remodulation (albedo * diffuse + specular). The kernels are numba-compiled loops
(``numba``, in the ``bench`` extra): SVGF is a GPU algorithm, and a pure numpy version
would be timed as slow for the wrong reason.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

ALPHA = 0.2
ALPHA_MOMENTS = 0.2
SIGMA_Z, SIGMA_N, SIGMA_L = 1.0, 128.0, 4.0  # sigma_n is fixed in _pow128
LEVELS = 5
B3 = np.array([1 / 16, 1 / 4, 3 / 8, 1 / 4, 1 / 16], np.float32)


@njit(cache=True, fastmath=True)
def _lum(r, g, b):
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


@njit(cache=True, fastmath=True)
def _pow128(x):
    """max(x, 0)^128 (sigma_n) by seven squarings: a general pow per tap dominated the time."""
    x = max(x, 0.0)
    for _ in range(7):
        x = x * x
    return x


@njit(parallel=True, cache=True, fastmath=True)
def _reproject(
    color,
    prev_color,
    prev_moments,
    prev_len,
    motion,
    depth,
    prev_depth,
    normal,
    prev_normal,
    out_color,
    out_moments,
    out_len,
):
    h, w = depth.shape
    for y in prange(h):
        for x in range(w):
            c = color[y, x]
            lum = _lum(c[0], c[1], c[2])
            # where this pixel's surface point was in the previous frame (sequence format)
            px = x + motion[y, x, 0]
            py = y + motion[y, x, 1]
            x0, y0 = int(np.floor(px)), int(np.floor(py))
            fx, fy = px - x0, py - y0
            acc = np.zeros(3, np.float32)
            m1 = 0.0
            m2 = 0.0
            hl = 0.0
            wsum = 0.0
            for j in range(2):
                for i in range(2):
                    xx, yy = x0 + i, y0 + j
                    if xx < 0 or yy < 0 or xx >= w or yy >= h:
                        continue
                    # consistency: relative depth and normal agreement
                    if abs(prev_depth[yy, xx] - depth[y, x]) > 0.1 * max(depth[y, x], 1e-3):
                        continue
                    nd = (
                        normal[y, x, 0] * prev_normal[yy, xx, 0]
                        + normal[y, x, 1] * prev_normal[yy, xx, 1]
                        + normal[y, x, 2] * prev_normal[yy, xx, 2]
                    )
                    if nd < 0.9:
                        continue
                    wt = (fx if i else 1 - fx) * (fy if j else 1 - fy)
                    if wt <= 0:
                        continue
                    for k in range(3):
                        acc[k] += wt * prev_color[yy, xx, k]
                    m1 += wt * prev_moments[yy, xx, 0]
                    m2 += wt * prev_moments[yy, xx, 1]
                    hl += wt * prev_len[yy, xx]
                    wsum += wt
            if wsum > 1e-4:
                n = hl / wsum + 1.0
                a = max(ALPHA, 1.0 / n)
                am = max(ALPHA_MOMENTS, 1.0 / n)
                for k in range(3):
                    out_color[y, x, k] = (1 - a) * acc[k] / wsum + a * c[k]
                out_moments[y, x, 0] = (1 - am) * m1 / wsum + am * lum
                out_moments[y, x, 1] = (1 - am) * m2 / wsum + am * lum * lum
                out_len[y, x] = n
            else:
                for k in range(3):
                    out_color[y, x, k] = c[k]
                out_moments[y, x, 0] = lum
                out_moments[y, x, 1] = lum * lum
                out_len[y, x] = 1.0


@njit(parallel=True, cache=True, fastmath=True)
def _variance(color, moments, hist_len, depth, normal, out_var):
    """Temporal variance, or a 7x7 bilateral spatial estimate where history is short."""
    h, w = depth.shape
    for y in prange(h):
        for x in range(w):
            if hist_len[y, x] >= 4.0:
                out_var[y, x] = max(moments[y, x, 1] - moments[y, x, 0] ** 2, 0.0)
                continue
            lp = _lum(color[y, x, 0], color[y, x, 1], color[y, x, 2])
            s1 = 0.0
            s2 = 0.0
            ws = 0.0
            for dy in range(-3, 4):
                for dx in range(-3, 4):
                    yy, xx = y + dy, x + dx
                    if xx < 0 or yy < 0 or xx >= w or yy >= h:
                        continue
                    nd = (
                        normal[y, x, 0] * normal[yy, xx, 0]
                        + normal[y, x, 1] * normal[yy, xx, 1]
                        + normal[y, x, 2] * normal[yy, xx, 2]
                    )
                    wn = _pow128(nd)
                    wz = np.exp(-abs(depth[y, x] - depth[yy, xx]) / (SIGMA_Z * max(depth[y, x], 1e-3) * 0.05 + 1e-6))
                    lq = _lum(color[yy, xx, 0], color[yy, xx, 1], color[yy, xx, 2])
                    wt = wn * wz * np.exp(-abs(lp - lq) / SIGMA_L)
                    s1 += wt * lq
                    s2 += wt * lq * lq
                    ws += wt
            m1 = s1 / max(ws, 1e-8)
            # boost the spatial estimate while the history is short, as in the paper's code
            out_var[y, x] = max(s2 / max(ws, 1e-8) - m1 * m1, 0.0) * 4.0 / hist_len[y, x]


@njit(parallel=True, cache=True, fastmath=True)
def _atrous(color, var, depth, dgrad, normal, step, out_color, out_var):
    h, w = depth.shape
    for y in prange(h):
        for x in range(w):
            # 3x3 Gaussian prefilter of the variance for the luminance edge-stopping function
            gv = 0.0
            gw = 0.0
            for dy in range(-1, 2):
                for dx in range(-1, 2):
                    yy, xx = min(max(y + dy, 0), h - 1), min(max(x + dx, 0), w - 1)
                    k = (0.5 if dx == 0 else 0.25) * (0.5 if dy == 0 else 0.25)
                    gv += k * var[yy, xx]
                    gw += k
            sd = np.sqrt(max(gv / gw, 0.0))
            lp = _lum(color[y, x, 0], color[y, x, 1], color[y, x, 2])
            acc = np.zeros(3, np.float32)
            av = 0.0
            ws = 0.0
            for j in range(5):
                for i in range(5):
                    dy, dx = (j - 2) * step, (i - 2) * step
                    yy, xx = y + dy, x + dx
                    if xx < 0 or yy < 0 or xx >= w or yy >= h:
                        continue
                    k = B3[i] * B3[j]
                    if dx == 0 and dy == 0:
                        wt = 1.0
                    else:
                        nd = (
                            normal[y, x, 0] * normal[yy, xx, 0]
                            + normal[y, x, 1] * normal[yy, xx, 1]
                            + normal[y, x, 2] * normal[yy, xx, 2]
                        )
                        wn = _pow128(nd)
                        dist = np.sqrt(float(dx * dx + dy * dy))
                        wz = -abs(depth[y, x] - depth[yy, xx]) / (SIGMA_Z * dgrad[y, x] * dist + 1e-6)
                        lq = _lum(color[yy, xx, 0], color[yy, xx, 1], color[yy, xx, 2])
                        wl = -abs(lp - lq) / (SIGMA_L * sd + 1e-6)
                        wt = wn * np.exp(wz + wl)
                    wk = wt * k
                    for c in range(3):
                        acc[c] += wk * color[yy, xx, c]
                    av += wk * wk * var[yy, xx]
                    ws += wk
            for c in range(3):
                out_color[y, x, c] = acc[c] / ws
            out_var[y, x] = av / (ws * ws)


class SVGF:
    """Frame-recurrent SVGF over diffuse and specular illumination; ``__call__`` takes a
    frame's input layers (HWC float32, as ``jnds_deploy.io`` reads them) and returns the
    remodulated colour at native resolution."""

    def __init__(self, levels: int = LEVELS):
        self.levels = levels
        self.reset()

    def reset(self) -> None:
        self.state: dict | None = None

    def _signal(self, name, color, depth, dgrad, normal, prev):
        h, w = depth.shape
        col = np.empty_like(color)
        mom = np.empty((h, w, 2), np.float32)
        hl = np.empty((h, w), np.float32)
        if prev is None:
            lum = 0.2126 * color[..., 0] + 0.7152 * color[..., 1] + 0.0722 * color[..., 2]
            col[:], mom[..., 0], mom[..., 1], hl[:] = color, lum, lum * lum, 1.0
        else:
            _reproject(
                color,
                prev[name]["color"],
                prev[name]["moments"],
                prev[name]["len"],
                self.motion,
                depth,
                prev["depth"],
                normal,
                prev["normal"],
                col,
                mom,
                hl,
            )
        var = np.empty((h, w), np.float32)
        _variance(col, mom, hl, depth, normal, var)
        history = col
        for level in range(self.levels):
            out_c, out_v = np.empty_like(col), np.empty_like(var)
            _atrous(col, var, depth, dgrad, normal, 1 << level, out_c, out_v)
            col, var = out_c, out_v
            if level == 0:
                history = col  # the paper feeds the first level's output back
        return col, {"color": history, "moments": mom, "len": hl}

    def __call__(self, layers: dict, camera_cut: bool = False) -> np.ndarray:
        h, w = layers["diffuse"].shape[:2]
        # depth is optional in the sequence format: without it, depth edge-stopping is off
        depth = np.ascontiguousarray(layers["depth"][..., 0] if "depth" in layers else np.zeros((h, w)), np.float32)
        normal = np.ascontiguousarray(layers["normal"], np.float32)
        self.motion = np.ascontiguousarray(layers["motion"], np.float32)
        if camera_cut or (self.state is not None and self.state["depth"].shape != depth.shape):
            self.state = None
        gy, gx = np.gradient(depth)
        dgrad = np.maximum(np.maximum(np.abs(gx), np.abs(gy)), 1e-3).astype(np.float32)
        state = {"depth": depth, "normal": normal}
        out = {}
        for name in ("diffuse", "specular"):
            sig = np.ascontiguousarray(np.nan_to_num(layers[name], nan=0.0, posinf=0.0).clip(0, 65535), np.float32)
            out[name], state[name] = self._signal(name, sig, depth, dgrad, normal, self.state)
        self.state = state
        return (layers["albedo"] * out["diffuse"] + out["specular"]).astype(np.float32)
