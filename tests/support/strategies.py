"""Hypothesis strategies derived from the catalogue (valid records, frames)."""

from __future__ import annotations

from hypothesis import strategies as st

from protocol.catalog import MessageSpec, SignalSpec


def signal_value(sig: SignalSpec) -> st.SearchStrategy:
    if sig.choices is not None:
        return st.sampled_from(sorted(sig.choices))
    raw = st.integers(sig.raw_min, sig.raw_max)
    if sig.is_integer:
        return raw
    return raw.map(lambda r: r * sig.scale + sig.offset if sig.offset else r * sig.scale)


def record(spec: MessageSpec) -> st.SearchStrategy:
    return st.tuples(*(signal_value(s) for s in spec.signals)).map(lambda values: spec.record(*values))
