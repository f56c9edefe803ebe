"""Checked numeric arrays at the boundaries of the numerical cores (the DMP, PI²): one rule for
what a caller may pass, raised as the core's own error with a one-line message."""

from __future__ import annotations

from typing import Any

import numpy as np


def float_array(
    value: Any, name: str, error: type[Exception], *, ndim: int | None = None,
    shape: tuple[int, ...] | None = None, finite: bool = True,
) -> np.ndarray:
    """A fresh float64 copy of ``value`` (never aliasing the caller's data) of numbers only (no
    bool, text or object), with ``ndim`` dimensions or the ``shape`` given, and finite unless
    ``finite`` is False (PI²'s costs: a non-finite cost is a roll-out given weight 0)."""
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise error(f"{name} must be numeric: {exc}") from None
    if array.dtype.kind not in "iuf":
        raise error(f"{name} must be numeric, got dtype {array.dtype}")
    array = np.array(array, dtype=np.float64)
    if ndim is not None and array.ndim != ndim:
        raise error(f"{name} must have {ndim} dimension(s), got shape {array.shape}")
    if shape is not None and array.shape != shape:
        raise error(f"{name} must have shape {shape}, got {array.shape}")
    if finite and not np.isfinite(array).all():
        raise error(f"{name} contains non-finite values")
    return array
