"""Image cross-correlation with a fixed kernel by zero-padded FFTs, shared by the trackers.

Both the warp field (vector kernel, §7.2.3) and the MAP filter's Ψ (scalar kernel, §7.2.2)
are sums over liquid pixels of a kernel of the offset, evaluated at every pixel at once:
``out[c, p] = Σ_d K[c, d] · weights(p + d)``. The kernel and its spectrum are cached: a
session asks for the same kernel and image size every frame.
"""

from __future__ import annotations

import functools

import torch


def correlate(weights: torch.Tensor, make_kernel, *args) -> torch.Tensor:
    """out[c, p] = Σ_d K[c, d] · weights(p + d) at every pixel centre p, zero outside the image.

    Args:
      weights: (H, W) float per-pixel weight.
      make_kernel: ``make_kernel(*args, dtype, device)`` → (C, 2R+1, 2R+1) kernel, entry
        [:, R+dy, R+dx] for the offset d = (dx, dy) px. Must be hashable (a module function)
        and deterministic in its arguments: its results are cached.
      args: hashable arguments of ``make_kernel`` (e.g. length scale and cut-off, px).
    Returns:
      (C, H, W), weights' dtype and device; O(HW log HW) whatever the number of liquid pixels.
    """
    if weights.dim() != 2:
        raise ValueError(f"weights must be an (H, W) image, got shape {tuple(weights.shape)}")
    H, W = weights.shape
    R = _kernel_radius(make_kernel, args)
    # enough zero padding that no offset wraps onto the image, rounded up to a 5-smooth size
    Hp, Wp = fast_size(H + R), fast_size(W + R)
    spectrum = _kernel_spectrum(make_kernel, args, Hp, Wp, weights.dtype, str(weights.device))
    g = torch.fft.rfft2(weights, s=(Hp, Wp))
    return torch.fft.irfft2(spectrum * g, s=(Hp, Wp))[:, :H, :W]


def fast_size(n: int) -> int:
    """Smallest m ≥ n whose prime factors are 2, 3 and 5 (fast FFT lengths)."""
    m = n
    while True:
        k = m
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 1


@functools.lru_cache(maxsize=16)
def _kernel_radius(make_kernel, args: tuple) -> int:
    k = make_kernel(*args, dtype=torch.float64, device=None)
    if k.dim() != 3 or k.shape[-1] != k.shape[-2] or k.shape[-1] % 2 != 1:
        raise ValueError(f"kernel must be (C, 2R+1, 2R+1), got shape {tuple(k.shape)}")
    return (k.shape[-1] - 1) // 2


@functools.lru_cache(maxsize=16)
def _kernel_spectrum(make_kernel, args: tuple, Hp: int, Wp: int, dtype, device: str):
    """conj(K̂) of the kernel laid out on an Hp × Wp torus (offset d at index d mod size): the
    correlation Σ_d K(d) g(p + d) is then irfft(conj(K̂) · ĝ) (K real)."""
    k = make_kernel(*args, dtype=dtype, device=device)
    R = (k.shape[-1] - 1) // 2
    kk = torch.zeros(k.shape[0], Hp, Wp, dtype=dtype, device=device)
    idx_y = torch.arange(-R, R + 1, device=device) % Hp
    idx_x = torch.arange(-R, R + 1, device=device) % Wp
    kk[:, idx_y[:, None], idx_x[None, :]] = k
    return torch.conj(torch.fft.rfft2(kk))
