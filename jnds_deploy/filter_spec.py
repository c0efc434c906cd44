"""The parameter-free stages of the pipeline, in PyTorch: tonemapping, history warping,
per-pixel kernel application, the filter paths, compositing and the upsample filter.

These are the specification of the numpy/opencv filter stage of the runtime; a test
holds the two equal. Array contract: NCHW float tensors; radiance linear HDR >= 0 unless
stated; kernels are (N, 9, H, W) in row-major 3x3 order (dy, dx) = (-1,-1), (-1,0), ...
Borders replicate the edge pixel everywhere (padding, warping, upsampling).
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

from .layout import (
    BACKGROUND,
    DIFFUSE_FILL_MIN,
    DIFFUSE_FILL_TAPS,
    HDR_MAX,
    LUMINANCE,
    REJECT_ALBEDO,
    REJECT_COS,
    RING_MIN,
    ROOT_FLOOR,
    SCATTERED_CHANGES,
    SCATTERED_SHARE,
    TONEMAP_FLOOR,
)


def tonemap(x: torch.Tensor) -> torch.Tensor:
    """Eq. 1 of the paper: (log(x + 1))^(1/2.2), after clamping to [0, 65535].

    The power is written as exp(log(.) / 2.2) (the floor keeps the log finite): the same
    values, but ONNX Runtime's Pow is scalar code where Exp and Log are vectorized
    (docs/architecture.md, "The network graph")."""
    return torch.exp(torch.log(torch.log1p(x.clamp(0.0, HDR_MAX)).clamp_min(TONEMAP_FLOOR)) * (1.0 / 2.2))


def inverse_tonemap(y: torch.Tensor) -> torch.Tensor:
    return torch.expm1(y.clamp_min(0.0).pow(2.2))


def apply_kernel(x: torch.Tensor, kernel: torch.Tensor) -> torch.Tensor:
    """Per-pixel 3x3 filter: out[n, c, y, x] = sum_k kernel[n, k, y, x] * x[n, c, y+dy_k, x+dx_k]."""
    h, w = x.shape[-2:]
    p = F.pad(x, (1, 1, 1, 1), mode="replicate")
    out = p[:, :, :h, :w] * kernel[:, 0:1]
    for i in range(1, 9):  # shifted views, no im2col copy (faster than unfold, docs/architecture.md)
        dy, dx = divmod(i, 3)
        out = out + p[:, :, dy : dy + h, dx : dx + w] * kernel[:, i : i + 1]
    return out


def warp(x: torch.Tensor, motion: torch.Tensor) -> torch.Tensor:
    """Bicubic resampling of ``x`` (previous frame) along motion vectors (N, 2, H, W) in
    pixels: out(x, y) = x_prev(x + 0.5 + mx, y + 0.5 + my) in continuous coordinates."""
    n, _, h, w = x.shape
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=x.dtype, device=x.device), torch.arange(w, dtype=x.dtype, device=x.device), indexing="ij"
    )
    px = xs + 0.5 + motion[:, 0]
    py = ys + 0.5 + motion[:, 1]
    grid = torch.stack([2 * px / w - 1, 2 * py / h - 1], dim=-1)
    if x.requires_grad and torch.is_grad_enabled() and x.device.type == "cpu" and x.dtype == torch.float32:
        return _WarpCPU.apply(x, grid)
    return F.grid_sample(x, grid, mode="bicubic", padding_mode="border", align_corners=False)


def offscreen(motion: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W) bool: the pixels whose position in the previous frame (motion (N, 2, H,
    W) in pixels) lies outside it, nearer another pixel than any of the frame's: they enter
    the view, and ``warp``'s border replication would give them the edge's history, a smear
    across a fast pan (docs/ghosting.md)."""
    h, w = motion.shape[-2:]
    ys, xs = torch.meshgrid(
        torch.arange(h, dtype=motion.dtype, device=motion.device),
        torch.arange(w, dtype=motion.dtype, device=motion.device),
        indexing="ij",
    )
    px, py = xs + motion[:, 0], ys + motion[:, 1]
    return ((px < -0.5) | (px > w - 0.5) | (py < -0.5) | (py > h - 0.5)).unsqueeze(1)


class _WarpCPU(torch.autograd.Function):
    """``grid_sample`` (bicubic, border, align_corners=False) with its input gradient from
    ``_warp_input_grad``: PyTorch's CPU backward of it was the largest single cost of a
    training step after the convolutions (benchmarks/results/train_throughput.md). The grid
    gets no gradient (warp's motion is an input)."""

    @staticmethod
    def forward(ctx, x, grid):
        ctx.save_for_backward(grid)
        ctx.size = x.shape[-2:]
        return F.grid_sample(x, grid, mode="bicubic", padding_mode="border", align_corners=False)

    @staticmethod
    def backward(ctx, grad):
        (grid,) = ctx.saved_tensors
        g = grad.detach().contiguous().numpy()
        out = torch.zeros((*g.shape[:2], *ctx.size), dtype=grad.dtype)
        _warp_input_grad()(g, grid.detach().contiguous().numpy(), out.numpy())
        return out, None


@functools.cache
def _warp_input_grad():
    """The numba kernel (compiled on first use; numba is the runtime's, not the model's,
    dependency): the adjoint of PyTorch's bicubic ``grid_sample`` (aten's
    GridSamplerKernel.cpp: the source coordinate (g + 1) * size / 2 - 0.5, the cubic
    convolution of A = -0.75 as the runtime's warp weighs it, ``bicubic.cubic_weights``,
    each of the 4x4 taps clamped to the border), scattering each output's gradient onto its
    16 taps, the 16 weights computed once per output pixel for every channel. Images in
    parallel, so no two threads add to one value. Written here: PyTorch has no faster
    adjoint of it on the CPU."""
    import numpy as np
    from numba import njit, prange

    from .bicubic import cubic_weights  # the runtime warp's weights, the same cubic

    @njit(parallel=True, cache=True)
    def kernel(g, grid, out):
        n_img, n_ch, ho, wo = g.shape
        hi, wi = out.shape[2], out.shape[3]
        sx, sy = np.float32(wi / 2), np.float32(hi / 2)
        one, half = np.float32(1), np.float32(0.5)
        for n in prange(n_img):
            wx, wy = np.empty(4, np.float32), np.empty(4, np.float32)
            cols, rows = np.empty(4, np.int64), np.empty(4, np.int64)
            for y in range(ho):
                for x in range(wo):
                    fx = (grid[n, y, x, 0] + one) * sx - half
                    fy = (grid[n, y, x, 1] + one) * sy - half
                    # far outside, every tap is the border pixel whatever the fraction:
                    # clamped first so that the integer conversion stays defined
                    fx = min(max(fx, np.float32(-4)), np.float32(wi + 3)) if fx == fx else np.float32(0)
                    fy = min(max(fy, np.float32(-4)), np.float32(hi + 3)) if fy == fy else np.float32(0)
                    x0, y0 = np.floor(fx), np.floor(fy)
                    tx, ty = fx - x0, fy - y0
                    wx[0], wx[1], wx[2], wx[3] = cubic_weights(tx)
                    wy[0], wy[1], wy[2], wy[3] = cubic_weights(ty)
                    for k in range(4):
                        cols[k] = min(max(np.int64(x0) - 1 + k, 0), wi - 1)
                        rows[k] = min(max(np.int64(y0) - 1 + k, 0), hi - 1)
                    for c in range(n_ch):
                        v = g[n, c, y, x]
                        plane = out[n, c]
                        for j in range(4):
                            vy = wy[j] * v
                            r = plane[rows[j]]
                            for i in range(4):
                                r[cols[i]] += wx[i] * vy

    return kernel


# Geometric history rejection, not in the paper (its network gets the warped history and
# must learn where not to trust it): the per-pixel normal test of SVGF (Schied et al.
# 2017) with a 3x3 tolerance. Without it the shipped model pulled an area light's
# radiance across the black background next to it and kept the ghost frame after frame,
# and history cost more than no history at all (commit 8f1dc31: benchmarks/results/history_gain.md).
def disoccluded(
    normal: torch.Tensor, warped_normal: torch.Tensor, albedo: torch.Tensor, warped_albedo: torch.Tensor
) -> torch.Tensor:
    """(N, 1, H, W) bool: where the warped history must not be used, from the current
    normals and albedo and the warped history's (N, 3, H, W; background normal 0).

    - The current sample sees background: its radiance is exact, there is nothing to
      accumulate, and the history there may hold a surface's radiance warped across a
      silhouette.
    - The history holds a surface whose normal is further than acos(REJECT_COS) from the
      normal of every current pixel in the 3x3 neighbourhood (a disocclusion). The
      neighbourhood tolerates the one-pixel silhouette shifts of the jittered, aliased
      G-buffer; without it every silhouette pixel lost its history (commit 44f2027).
    - The history's albedo lies outside the range of the current 3x3 albedos, per channel,
      widened by REJECT_ALBEDO: another surface facing the same way, or a surface where
      the history saw background (docs/ghosting.md).
    """
    h, w = normal.shape[-2:]
    background = normal.abs().sum(1, keepdim=True) < BACKGROUND
    length = torch.sqrt((warped_normal * warped_normal).sum(1, keepdim=True))
    p = F.pad(normal, (1, 1, 1, 1), mode="replicate")
    a = F.pad(albedo, (1, 1, 1, 1), mode="replicate")
    best = lo = hi = None
    for i in range(9):
        dy, dx = divmod(i, 3)
        d = (p[:, :, dy : dy + h, dx : dx + w] * warped_normal).sum(1, keepdim=True)
        n = a[:, :, dy : dy + h, dx : dx + w]
        best = d if best is None else torch.maximum(best, d)
        lo = n if lo is None else torch.minimum(lo, n)
        hi = n if hi is None else torch.maximum(hi, n)
    surface = warped_normal.abs().sum(1, keepdim=True) >= BACKGROUND
    outside = ((warped_albedo < lo - REJECT_ALBEDO) | (warped_albedo > hi + REJECT_ALBEDO)).any(1, keepdim=True)
    return background | (surface & (best < REJECT_COS * length)) | outside


def history_rejected(
    normal: torch.Tensor,
    warped_normal: torch.Tensor,
    albedo: torch.Tensor,
    warped_albedo: torch.Tensor,
    motion: torch.Tensor,
) -> torch.Tensor:
    """(N, 1, H, W) bool: where the current inputs replace the warped history: ``disoccluded``
    or ``offscreen``, and a ring around trails. The ring: a pixel beside another surface's
    trail takes its temporal kernel's taps from that trail's neighbourhood, and the warp's
    bicubic taps blend the trail into its edge, so the 3x3 around a rejected pixel that
    sees a surface is rejected too, where at least RING_MIN of that 3x3's pixels are such
    pixels: a trail, not one pixel of a fine texture whose filtered albedo left the range
    (docs/ghosting.md). Background pixels are not dilated: their radiance is exact."""
    rejected = disoccluded(normal, warped_normal, albedo, warped_albedo) | offscreen(motion)
    surface = (rejected & (normal.abs().sum(1, keepdim=True) >= BACKGROUND)).to(normal.dtype)
    ones = torch.ones(1, 1, 3, 3, dtype=normal.dtype, device=normal.device)
    trail = (surface > 0) & (F.conv2d(surface, ones, padding=1) >= RING_MIN)
    ring = F.max_pool2d(trail.to(normal.dtype), 3, stride=1, padding=1) > 0
    return rejected | ring


def fill_diffuse_holes(diffuse: torch.Tensor, albedo: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    """The demodulated ``diffuse`` (N, 3, H, W) with its holes filled: a pixel whose
    sample hit no diffuse surface (albedo 0, normal not background: a metal, a hair
    strand, a scattering volume) gets the weighted mean of the diffuse of its 5x5
    neighbours that did (``layout.DIFFUSE_FILL_TAPS``), where their weights sum to at least
    ``DIFFUSE_FILL_MIN``; elsewhere unchanged. Borders count as no sample.

    Why: the renderer divides the diffuse light by the diffuse colour, and where that is 0
    it writes 0, which says nothing about the light there. The filters took it as black
    light, so where such samples are scattered among diffuse ones (a thin medium over a
    floor, fur over a rug, sub-pixel metal), the filtered light came out darkened and the
    composite, that light times the albedo (itself darkened by the same samples), speckled
    and dark (docs/model-gap.md, "Diffuse holes"). The composite of the pixel itself is
    unchanged: its albedo is 0. Not in the paper."""
    c = diffuse.shape[1]
    valid = (albedo.amax(1, keepdim=True) > 0).to(diffuse.dtype)
    hole = diffuse_holes(albedo, normal)
    taps = torch.tensor(DIFFUSE_FILL_TAPS, dtype=diffuse.dtype, device=diffuse.device)
    k = len(DIFFUSE_FILL_TAPS)

    def blur(x):  # separable, zero padding: out-of-frame taps carry no weight
        n = x.shape[1]
        x = F.conv2d(x, taps.view(1, 1, 1, k).expand(n, 1, 1, k), padding=(0, k // 2), groups=n)
        return F.conv2d(x, taps.view(1, 1, k, 1).expand(n, 1, k, 1), padding=(k // 2, 0), groups=n)

    sums = blur(torch.cat([diffuse * valid, valid], 1))
    weight = sums[:, c:]
    fill = hole & (weight >= DIFFUSE_FILL_MIN)
    return torch.where(fill, sums[:, :c] / weight.clamp_min(DIFFUSE_FILL_MIN), diffuse)


def diffuse_holes(albedo: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W) bool: the samples that hit no diffuse surface (albedo 0, normal not
    background), ``fill_diffuse_holes``'s holes."""
    return (albedo.amax(1, keepdim=True) <= 0) & (normal.abs().sum(1, keepdim=True) >= BACKGROUND)


def _binomial(x: torch.Tensor) -> torch.Tensor:
    """The 5x5 binomial mean of each channel (``DIFFUSE_FILL_TAPS`` both ways), the border
    replicated."""
    c, k = x.shape[1], len(DIFFUSE_FILL_TAPS)
    taps = torch.tensor(DIFFUSE_FILL_TAPS, dtype=x.dtype, device=x.device)
    x = F.pad(x, (k // 2,) * 4, mode="replicate")
    x = F.conv2d(x, taps.view(1, 1, 1, k).expand(c, 1, 1, k), groups=c)
    return F.conv2d(x, taps.view(1, 1, k, 1).expand(c, 1, k, 1), groups=c)


def scattered_holes(hole: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W) bool: where ``diffuse_holes`` lie scattered among diffuse samples: their
    5x5 share strictly inside ``SCATTERED_SHARE`` and the 5x5 mean of the hole mask's changes
    from pixel to pixel above ``SCATTERED_CHANGES`` (hair, a medium over a floor; the edge of
    a solid metal object changes once, and its neighbours keep their albedo)."""
    h = hole.float()
    changes = F.pad((h[..., :, 1:] - h[..., :, :-1]).abs(), (0, 1)) + F.pad(
        (h[..., 1:, :] - h[..., :-1, :]).abs(), (0, 0, 0, 1)
    )
    share, moves = _binomial(torch.cat([h, changes], 1)).split(1, 1)
    lo, hi = SCATTERED_SHARE
    return (share > lo) & (share < hi) & (moves > SCATTERED_CHANGES)


def albedo_at_holes(albedo: torch.Tensor, scattered: torch.Tensor) -> torch.Tensor:
    """The filtered ``albedo`` (N, 3, H, W) the composite takes: its 5x5 binomial mean where
    ``scattered`` (``scattered_holes``), else itself.

    Why: the auxiliary filter keeps each hole's albedo 0, so where holes lie scattered (fur
    over a rug, a medium over a floor) the composite, even with the diffuse light filled
    (``fill_diffuse_holes``), keeps the 1-spp coverage pattern as grain; the reference has its
    mean (docs/model-gap.md, "Diffuse holes"). Not in the paper, not a weight."""
    return torch.where(scattered, _binomial(albedo), albedo)


def luminance(x: torch.Tensor) -> torch.Tensor:
    """(N, 1, H, W) Rec. 709 luminance of RGB ``x`` (N, 3, H, W)."""
    return x[:, 0:1] * LUMINANCE[0] + x[:, 1:2] * LUMINANCE[1] + x[:, 2:3] * LUMINANCE[2]


def clamp_fireflies(x: torch.Tensor, history: torch.Tensor, k: float) -> torch.Tensor:
    """A 1-spp radiance ``x`` (N, 3, H, W) with each pixel's luminance limited to ``k``
    times the brightest of its 8 neighbours and of the warped ``history`` (N, 3, H, W) in
    its 3x3 neighbourhood; an RGB above the bound is scaled down to it (hue kept).

    Why: a rare, very bright path sample (a caustic, a small light seen in a glossy
    surface) is a firefly in one frame and gone the next; the filter paths spread its
    energy over their coarse levels into a blotch that the history then keeps
    (docs/model-gap.md). Something bright in its neighbourhood or in the history (a small
    emitter, a highlight seen before) keeps it. Where the history is the current frame
    (first frame, disocclusion) the pixel bounds itself: nothing changes. Biased: the
    energy above the bound is dropped. Not in the paper; borders replicate."""
    h, w = x.shape[-2:]
    lum = luminance(x)
    cur = F.pad(lum, (1, 1, 1, 1), mode="replicate")
    hist = F.pad(luminance(history), (1, 1, 1, 1), mode="replicate")
    bound = None
    for i in range(9):
        dy, dx = divmod(i, 3)
        m = hist[:, :, dy : dy + h, dx : dx + w]
        if i != 4:
            m = torch.maximum(m, cur[:, :, dy : dy + h, dx : dx + w])
        bound = m if bound is None else torch.maximum(bound, m)
    bound = bound * k
    # lum > bound >= 0 where the ratio is taken; the floor keeps 0 / 0 out of the other branch
    return x * torch.where(lum > bound, bound / lum.clamp_min(torch.finfo(lum.dtype).tiny), torch.ones_like(lum))


def downsample(x: torch.Tensor) -> torch.Tensor:
    """2x2 average pooling (sizes must be even)."""
    return F.avg_pool2d(x, 2)


def upsample(x: torch.Tensor, factor: int = 2) -> torch.Tensor:
    """Bilinear upsampling, pixel centres aligned as in cv2.resize(INTER_LINEAR)."""
    return F.interpolate(x, scale_factor=factor, mode="bilinear", align_corners=False)


def spatiotemporal(
    x: torch.Tensor, history: torch.Tensor, k_spatial: torch.Tensor, k_temporal: torch.Tensor, blend: torch.Tensor
) -> torch.Tensor:
    """Separate 3x3 kernels on the current frame and on the warped history, blended
    linearly with the per-pixel weight ``blend`` in [0, 1] (1 = all history); ReLU."""
    return F.relu(torch.lerp(apply_kernel(x, k_spatial), apply_kernel(history, k_temporal), blend))


def filter_path(x: torch.Tensor, history: torch.Tensor, native: dict, levels: list[dict]) -> torch.Tensor:
    """The hierarchical filter of one signal (diffuse or specular).

    ``native``: spatial, temporal (N, 9, H, W), blend (N, 1, H, W) for the spatiotemporal
    filter, and if ``levels`` is not empty up (N, 9, H, W), up_blend (N, 1, H, W) for the
    last upsampling filter. ``levels[k]`` (resolution H / 2^(k+1)): down kernel, and for
    every level but the coarsest, up kernel and up_blend.
    Down: 2x2 average pooling, then the 3x3 kernel. Up: bilinear upsampling of the
    coarser result, the 3x3 kernel, then a linear blend with the same level's down
    result (the skip image). Every filter is followed by a ReLU.
    """
    skips = [spatiotemporal(x, history, native["spatial"], native["temporal"], native["blend"])]
    for lv in levels:
        skips.append(F.relu(apply_kernel(downsample(skips[-1]), lv["down"])))
    y = skips[-1]
    for k in range(len(levels) - 1, -1, -1):
        p = levels[k - 1] if k > 0 else native
        y = F.relu(torch.lerp(skips[k], apply_kernel(upsample(y), p["up"]), p["up_blend"]))
    return y


def composite(albedo: torch.Tensor, diffuse: torch.Tensor, specular: torch.Tensor) -> torch.Tensor:
    """Eq. 2: albedo * diffuse + specular."""
    return albedo * diffuse + specular


def to_phases(kernel: torch.Tensor, factor: int) -> torch.Tensor:
    """A target-resolution map (N, C, sH, sW) in phase layout (N, s*s*C, H, W): channel
    (py * s + px) * C + c at native (i, j) holds target pixel (s*i + py, s*j + px)."""
    n, c, h, w = kernel.shape
    s = factor
    return kernel.reshape(n, c, h // s, s, w // s, s).permute(0, 3, 5, 1, 2, 4).reshape(n, s * s * c, h // s, w // s)


def from_phases(kernel: torch.Tensor, factor: int) -> torch.Tensor:
    """Inverse of ``to_phases``."""
    n, _, h, w = kernel.shape
    s = factor
    return kernel.reshape(n, s, s, -1, h, w).permute(0, 3, 4, 1, 5, 2).reshape(n, -1, h * s, w * s)


def upsample_filter(color: torch.Tensor, kernel: torch.Tensor, factor: int, root: int = 1) -> torch.Tensor:
    """The upsample block's filter: bilinear upsampling of the linear composite, then the
    per-pixel 3x3 kernel predicted at target resolution; ReLU.

    ``root`` > 1 (not in the paper) interpolates the composite's ``root``-th root and
    raises the result back to the power ``root`` before the kernel: a bright pixel then
    does not spread its linear energy into its neighbours' target pixels, which after
    display tonemapping reads as a halo. Validation references pooled to native and
    upsampled back score higher in fourth roots than linearly
    (docs/architecture.md, "The filter stage")."""
    if factor == 1:
        up = color
    elif root == 1:
        up = upsample(color, factor)
    else:
        up = upsample(color.clamp_min(ROOT_FLOOR).pow(1.0 / root), factor).pow(root)
    return F.relu(apply_kernel(up, kernel))
