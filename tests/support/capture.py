"""Bus captures for the tests: candump as the independent witness of what is on the bus, and
reading its logs back (our reader and DBC, and cantools with the same DBC)."""

from __future__ import annotations

import math
import re
import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import can

from protocol.bus import RECEIVE_BUFFER_BYTES
from protocol.catalog import DBC_PATH
from protocol.clock import MonotonicClock
from protocol.codec import Codec, Decoded
from protocol.e2e import Receiver
from tools.trace.reader import ReadReport, read_frames

CODEC = Codec()


PROBE_ID = 0x7FF  # not in the DBC: sent until candump shows it listens, then left out


@contextmanager
def candump(channel, path):
    """``candump -L channel > path`` from the moment it listens until the block ends, and until it
    has written every frame sent before the end: a last probe frame (frames arrive in order) must
    be in the file before candump is stopped (in the slow sandbox it can be a few frames behind)."""
    clock = MonotonicClock()
    with path.open("w") as out:
        # Our sockets' receive buffer for candump's too: with the kernel's default it dropped 93
        # frames of a flood while the guest was slow, and the witness must see every frame.
        proc = subprocess.Popen(["candump", "-L", "-r", str(RECEIVE_BUFFER_BYTES), channel], stdout=out, stderr=subprocess.PIPE)
        try:
            with can.Bus(interface="socketcan", channel=channel, ignore_config=True) as probe:
                deadline = clock.now_ns() + 20_000_000_000
                while path.stat().st_size == 0:
                    assert clock.now_ns() < deadline, "candump did not start"
                    probe.send(can.Message(arbitration_id=PROBE_ID, data=b"", is_extended_id=False))
                    clock.sleep_until(clock.now_ns() + 50_000_000)
                yield
                probe.send(can.Message(arbitration_id=PROBE_ID, data=b"\xff", is_extended_id=False))
                deadline = clock.now_ns() + 20_000_000_000
                while f"{PROBE_ID:03X}#FF" not in path.read_text():
                    assert clock.now_ns() < deadline, "candump did not catch up"
                    clock.sleep_until(clock.now_ns() + 20_000_000)
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=30)


def read_log(path):
    report = ReadReport()
    frames = list(read_frames([path], report))
    assert report.skipped == 0 and not report.problems, report
    return frames


def recorded(path: Path) -> int:
    return sum(m.arbitration_id != PROBE_ID for m in can.CanutilsLogReader(str(path)))


def decode_capture(path: Path) -> tuple[list[Decoded], Receiver]:
    """candump's log through our DBC: every frame must decode, with no counter gap."""
    receiver = Receiver(CODEC)
    frames = [m for m in can.CanutilsLogReader(str(path)) if m.arbitration_id != PROBE_ID]
    assert frames, "candump recorded nothing"
    results = [receiver.receive(m) for m in frames]
    rejected = [r for r in results if not isinstance(r, Decoded)]
    assert not rejected, (len(rejected), rejected[:3])
    assert receiver.stats.lost == 0 and receiver.stats.rejected_total == 0, receiver.stats.as_dict()
    return results, receiver


def assert_cantools_agrees(rows, candump_log_text):
    """``cantools decode`` with our DBC gives our rows' messages, counters and values (labels for
    enumerations); returns how many signals were compared."""
    theirs = subprocess.run([sys.executable, "-m", "cantools", "decode", "--single-line", str(DBC_PATH)],
                            input=candump_log_text, capture_output=True, text=True, timeout=300, check=True).stdout.splitlines()
    assert len(theirs) == len(rows)
    compared = 0
    for row, line in zip(rows, theirs):
        match = re.search(r" :: (\w+)\((.*)\)$", line)
        assert match and match.group(1) == row.spec.name, line
        values = dict(item.split(": ", 1) for item in match.group(2).split(", "))
        assert int(values["e2e_counter"]) == row.counter
        for sig, value in zip(row.spec.signals, row.values):
            text = values[sig.name].split(" ")[0]
            if sig.choices:
                assert text == sig.choices[value], (row.spec.name, sig.name)
            else:
                assert math.isclose(float(text), value, abs_tol=1e-9), (row.spec.name, sig.name, text, value)
            compared += 1
    return compared
