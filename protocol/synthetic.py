"""Valid signal values made up for benchmarks, bus checks and tests (never used by the control path)."""

from __future__ import annotations

from typing import Any

import numpy as np

from protocol.catalog import MessageSpec, SignalSpec


def _physical(sig: SignalSpec, raw: int) -> float | int:
    return raw if sig.is_integer else raw * sig.scale + sig.offset


def random_record(spec: MessageSpec, rng: np.random.Generator) -> Any:
    """A record of ``spec`` with every value drawn uniformly from its valid raw grid."""
    values = []
    for sig in spec.signals:
        if sig.choices is not None:
            values.append(int(rng.choice(sorted(sig.choices))))
        else:
            values.append(_physical(sig, int(rng.integers(sig.raw_min, sig.raw_max, endpoint=True))))
    return spec.record(*values)


def sweep_record(spec: MessageSpec, tick: int) -> Any:
    """A deterministic record for ``tick`` that walks every signal over its whole range.

    Each signal follows a sawtooth over its raw grid with its own period, so over a few hundred
    ticks every signal takes its minimum, its maximum and values between, and enumerations take
    every listed value. Both ends of a bus check compute the same record from the tick number.
    """
    values = []
    for k, sig in enumerate(spec.signals):
        if sig.choices is not None:
            keys = sorted(sig.choices)
            values.append(keys[(tick + k) % len(keys)])
            continue
        period = 97 + 10 * k  # distinct periods: signals do not move in lock-step
        span = sig.raw_max - sig.raw_min
        phase = (tick + 13 * k) % period
        raw = sig.raw_min + (span * phase) // (period - 1)
        values.append(_physical(sig, raw))
    return spec.record(*values)
