"""The whole pipeline under faults, tick by tick, with the invariants checked on every tick.

:class:`FaultRig` runs the controller (:class:`~controller.loop.LockstepLoop` over
:class:`~controller.core.ControllerCore`), the four emulated node boards and the simulated HHEA on
the in-process virtual bus, in lock-step. The controller's end of the bus is a
:class:`~protocol.faultbus.FaultBus` (injection layer BW), the node boards have their fault hooks
(layer NE, :meth:`inject_node`), and a passive listener on the same channel records what is really
on the bus, which :class:`~tools.safety.oracle.Oracle` checks after every tick.
"""

from __future__ import annotations

import itertools
import weakref
from collections.abc import Callable, Iterable
from functools import cache

import can
import numpy as np

from config import Config, with_overrides
from config.loader import build
from config.nodes_schema import FaultConfig
from controller.core import ControllerCore, TickResult
from controller.hardware import CanHardware
from controller.loop import LockstepLoop
from controller.session import Session
from nodes.host import NodesHost
from protocol.bus import virtual_bus
from protocol.codec import Codec
from protocol.enums import GaitState
from protocol.faultbus import BusFault, FaultBus
from tools.safety.oracle import Oracle

_channels = itertools.count()


@cache
def shared_codec() -> Codec:
    """One codec for every rig of the process (a codec is stateless). Each :class:`Codec` compiles
    a decoder and an encoder per message into functions whose globals hold them: cyclic garbage
    that only a full collection frees, made by every rig's host, loop and oracle if each built its
    own (about 1,000 objects a rig)."""
    return Codec()


def _weak_pump(rig: FaultRig) -> Callable[[], None]:
    """The loop's pump, holding the rig weakly: a bound ``rig._pump`` in ``rig.loop`` would make
    rig and loop a reference cycle, so a finished rig (its world's Python side, the loop's two 8 MiB
    tick-timing rings, its codecs) would wait for the garbage collector's next full collection
    instead of going at the last reference. Episodes of a soak then pile up, and the heap that new
    episodes allocate around them fragments (measured: +0.15 MiB resident an episode, faulted or not)."""
    ref = weakref.ref(rig)

    def pump() -> None:
        r = ref()
        if r is not None:
            r._pump()

    return pump


class _AnsweredBus(FaultBus):
    """A :class:`FaultBus` whose every sent frame the node boards answer at once (``answer``, the
    rig's pump): as across processes, where the boards run while the controller sends."""

    def __init__(self, inner: can.BusABC, faults: Iterable[BusFault], *, rng: np.random.Generator,
                 answer: Callable[[], None]) -> None:
        super().__init__(inner, faults, rng=rng)
        self._answer = answer

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        super().send(msg, timeout)
        self._answer()


class FaultRig:
    def __init__(
        self, cfg: Config, *, seed: int = 0, bus_faults: Iterable[BusFault] = (), tick_timeout_s: float = 0.05,
        mode: str = "sagittal", keep_results: bool = True, answering: bool = False,
    ) -> None:
        """``keep_results``: keep every tick's result in :attr:`results` (a soak does not).
        ``answering``: the loop reads as across processes (no pump: a tick's read ends once the
        frames it waits for are in, and what comes after waits for the next tick) and the node
        boards answer each frame as it is sent, every tick's frames queued at once."""
        channel = f"fault-rig-{next(_channels)}"
        self.cfg = cfg = with_overrides(cfg, {"bus.channel": channel, "sim.mode": mode})
        self.listener = virtual_bus(channel)
        self.node_bus = virtual_bus(channel)
        pump = _weak_pump(self)
        rng = np.random.default_rng(seed)
        self.bus = (_AnsweredBus(virtual_bus(channel), bus_faults, rng=rng, answer=pump) if answering
                    else FaultBus(virtual_bus(channel), bus_faults, rng=rng))
        try:
            self.host = NodesHost(cfg, self.node_bus, lockstep=True, seed=seed, codec=shared_codec())
        except Exception:
            self._shutdown_buses()
            raise
        self.host.boot()
        self.core = ControllerCore(cfg.controller)
        self.hardware = CanHardware(cfg.controller, self.bus, codec=shared_codec(), pump=None if answering else pump,
                                    max_delta_counter=cfg.protocol.max_delta_counter)
        self.loop = LockstepLoop(self.core, self.hardware, tick_timeout_s=tick_timeout_s)
        self.session = Session(self.loop)
        self.operator = self.session.operator
        self.oracle = Oracle(self.core, self.hardware, codec=shared_codec())
        self.results: list[TickResult] = []
        self.keep_results = keep_results
        self.last: TickResult | None = None
        self.nodes_running = True  # False: the node process is gone (F1)

    def _pump(self) -> None:
        if self.nodes_running:
            self.host.poll(0.0)

    def _shutdown_buses(self) -> None:
        for b in (self.listener, self.node_bus, self.bus):
            b.shutdown()

    def close(self) -> None:
        self.host.close()
        self._shutdown_buses()

    def __enter__(self) -> FaultRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- running ---------------------------------------------------------------------------------

    @property
    def tick(self) -> int:
        return self.loop.tick

    @property
    def state(self) -> GaitState:
        return self.core.fsm.state

    def step(self) -> TickResult:
        """One tick, then the invariants on what it put on the bus."""
        result = self.session.step()
        frames: list[can.Message] = []
        while (m := self.listener.recv(timeout=0)) is not None:
            frames.append(m)
        self.oracle.check(result, frames)
        self.last = result
        if self.keep_results:
            self.results.append(result)
        return result

    def run(self, ticks: int) -> list[TickResult]:
        return [self.step() for _ in range(ticks)]

    def run_until(self, done: Callable[[FaultRig], bool], max_ticks: int) -> bool:
        """Step until ``done(self)`` holds (True) or ``max_ticks`` have passed (False)."""
        for _ in range(max_ticks):
            self.step()
            if done(self):
                return True
        return False

    def walk_to(self, state: GaitState, max_ticks: int = 1500) -> None:
        """Stand up, start walking and run until the FSM is in ``state``."""
        self.operator.start()
        if not self.run_until(lambda r: r.state == state, max_ticks):
            raise AssertionError(f"not in {state.name} within {max_ticks} ticks (at {self.state.name}, tick {self.tick})")

    # -- faults ----------------------------------------------------------------------------------

    def foreign(self) -> can.BusABC:
        """Another sender on the bus (close it after use): foreign frames, a flood."""
        return virtual_bus(self.cfg.bus.channel)

    def inject_bus(self, fault: BusFault) -> None:
        self.bus.add(fault)

    def inject_node(self, kind: str, node: str, *, start_tick: int | None = None, end_tick: int | None = None, **values) -> None:
        """A node-level fault (layer NE) from ``start_tick`` (default: the next tick)."""
        raw = {"kind": kind, "node": node, "start_tick": self.tick + 1 if start_tick is None else start_tick,
               "end_tick": end_tick, **values}
        self.host.faults.add(f"{kind}-{node}-{self.tick}", build(FaultConfig, {k: v for k, v in raw.items() if v is not None},
                                                                "nodes.faults.injected"))
