"""Output files that never look complete before they are, and the metadata sidecar of a recording.

Every file the trace tool writes (recordings, decoded tables, plots, sidecars) is written under a
temporary name beside its final one and renamed onto it only once complete, so an interrupted
run, a full disk or a bad input never leaves a partly written file under the name asked for.

The sidecar ``<trace>.meta.json`` says where a recording comes from: the configuration's hash,
the software version, the seed of a simulated run, the bitrate, the DBC (hash and protocol
version), the bus, the timebase, and the frames and time span recorded.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import re
import subprocess
from pathlib import Path
from typing import Any

from config import Config, config_hash
from config.files import write_text
from protocol.catalog import Catalog
from tools.trace import TraceError

SIDECAR_SUFFIX = ".meta.json"
SIDECAR_SCHEMA = "aider-exo trace metadata 1"
ROOT = Path(__file__).resolve().parents[2]


def partial_path(path: Path) -> Path:
    """Where ``path`` is written until complete: same folder and suffix, marked partial."""
    return path.with_name(f"{path.stem}.partial{path.suffix}")


def write_json(path: str | Path, data: Any) -> None:
    write_text(path, json.dumps(data, indent=2) + "\n")


def sidecar_path(trace: str | Path) -> Path:
    trace = Path(trace)
    return trace.with_name(trace.name + SIDECAR_SUFFIX)


def read_sidecar(trace: str | Path) -> dict[str, Any] | None:
    """The metadata of a recording (of a rotated part ``NAME_007.EXT``: ``NAME.EXT``'s), None when
    it has none; a broken sidecar is one clear error."""
    if str(trace) == "-":
        return None
    trace = Path(trace)
    rotated = re.fullmatch(r"(.+)_\d{3}", trace.stem)
    candidates = [sidecar_path(trace)] + ([sidecar_path(trace.with_name(rotated.group(1) + trace.suffix))] if rotated else [])
    path = next((c for c in candidates if c.is_file()), None)
    if path is None:
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TraceError(f"{path}: unreadable metadata sidecar ({exc})") from None
    if not isinstance(data, dict) or data.get("schema") != SIDECAR_SCHEMA:
        raise TraceError(f"{path}: not an aider-exo trace metadata file")
    return data


def dbc_info(catalog: Catalog) -> dict[str, Any]:
    try:
        digest = hashlib.sha256(Path(catalog.source).read_bytes()).hexdigest()
    except OSError:
        digest = None
    return {"path": catalog.source, "sha256": digest, "protocol_version": catalog.version}


def software_version() -> str:
    """The package version, with the git commit (and ``.dirty``) when run from a checkout."""
    try:
        version = importlib.metadata.version("aider-exo")
    except importlib.metadata.PackageNotFoundError:
        version = "unknown"
    try:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                                capture_output=True, text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return version
    return f"{version}+g{commit}{'.dirty' if dirty else ''}" if commit else version


def recording_metadata(cfg: Config, catalog: Catalog, *, seed: int | None, bitrate_bit_s: int, timebase: str,
                       source: dict[str, Any]) -> dict[str, Any]:
    """The sidecar's fields known when a recording starts (the frames are added at its end)."""
    return {
        "software_version": software_version(),
        "config_sha256": config_hash(cfg),
        "seed": seed,
        "bitrate_bit_s": bitrate_bit_s,
        "dbc": dbc_info(catalog),
        "bus": {"interface": cfg.bus.interface, "channel": cfg.bus.channel},
        "timebase": timebase,
        "source": source,
    }
