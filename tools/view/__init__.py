"""``aider-exo view``: a live view of the walk in the browser, from the bus alone.

A passive listener (:mod:`tools.view.source`) decodes every frame with the DBC and the project's
receiver checks and runs the controller's own estimator on them (:mod:`tools.view.model`); an
aiohttp server (:mod:`tools.view.server`) sends snapshots over a WebSocket to one page of plain
static assets (``static/``: HTML, CSS and canvas drawing, no build step, nothing from outside).
See docs/VIEW.md.
"""

from __future__ import annotations

from typing import Any

from protocol.catalog import Catalog, default_catalog
from tools.view.model import ViewModel
from tools.view.source import Feed


def make_feed(cfg: Any, catalog: Catalog | None = None) -> Feed:
    """The view's model of configuration ``cfg`` (its controller's body and legs, the bus's
    bitrate, the protocol's counter tolerance) behind its lock."""
    return Feed(ViewModel(cfg.controller, catalog or default_catalog(), bitrate_bit_s=cfg.bus.bitrate_bit_s,
                          max_delta_counter=cfg.protocol.max_delta_counter))
