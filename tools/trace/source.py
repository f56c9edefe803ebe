"""The input of every trace command: the files, the DBC, the selection, and what reading them met.

Besides the reader's counted skips and problems (:class:`tools.trace.reader.ReadReport`), it says
when a trace does not fit the DBC: no frame with one of its IDs (a trace of another bus), most
known frames failing their CRC (the wrong DBC or another protocol version, whose Data IDs seed
other CRCs), or a sidecar naming another DBC than the one decoding.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from typing import Any

from protocol.catalog import default_catalog, load_catalog
from protocol.codec import Codec, RejectReason
from tools.trace import TraceError
from tools.trace.decode import Selection
from tools.trace.files import dbc_info, read_sidecar
from tools.trace.reader import Frame, ReadReport, check_readable, read_frames


class TraceInput:
    def __init__(self, files: Sequence[str], *, dbc: str | None = None, selection: Selection | None = None,
                 role: str = "all", stdin: bool = True) -> None:
        check_readable(files)
        if "-" in files and (not stdin or len(files) > 1):
            raise TraceError("standard input (-) can only be the one trace" if stdin else "this command reads files, not standard input")
        self.files = list(files)
        self.catalog = load_catalog(dbc) if dbc else default_catalog()
        self.codec = Codec(self.catalog)
        self.sidecars = [m for m in (read_sidecar(f) for f in files) if m is not None]
        controller = self.catalog.by_name("SYNC").sender  # the DBC's sender of SYNC is the controller
        senders = {"all": (), "nodes": tuple(n for n in self.catalog.nodes if n != controller), "controller": (controller,)}[role]
        self.selection = dataclasses.replace(selection or Selection(), senders=senders).compile(self.catalog)
        self.report = ReadReport()
        self.streaming = self.files == ["-"]

    @property
    def metadata(self) -> dict[str, Any]:
        """The first file's sidecar (empty without one)."""
        return self.sidecars[0] if self.sidecars else {}

    def frames(self) -> Iterator[Frame]:
        """The frames of the files in order; a file without one readable frame is a :class:`TraceError`."""
        return read_frames(self.files, self.report, require_frames=True)

    def warnings(self, receiver: Any = None) -> list[str]:
        """One line per problem met so far (``receiver``: the one that checked the frames)."""
        out = self.report.warnings()
        if receiver is not None and self.report.frames:
            rejected = receiver.stats.rejected
            known = self.report.frames - rejected.get(RejectReason.UNKNOWN_ID, 0)
            if known == 0:
                out.append(f"none of the {self.report.frames} frames has an ID of {self.catalog.source}: "
                           "a trace of another bus, or the wrong DBC?")
            elif rejected.get(RejectReason.BAD_CRC, 0) * 2 > known:
                out.append(f"{rejected[RejectReason.BAD_CRC]} of the {known} frames with known IDs fail their CRC: "
                           "the wrong DBC, or another protocol version?")
        ours = dbc_info(self.catalog)["sha256"]
        for meta in self.sidecars:
            theirs = (meta.get("dbc") or {}).get("sha256")
            if theirs and ours and theirs != ours:
                out.append(f"the trace was recorded with another DBC (protocol version {meta['dbc'].get('protocol_version')}, "
                           f"sha256 {theirs[:12]}); decoding with {self.catalog.source} (sha256 {ours[:12]})")
                break
        return out
