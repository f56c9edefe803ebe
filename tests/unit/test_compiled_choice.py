"""The choice at import between a compiled module and its source (protocol/compiled.py)."""

from __future__ import annotations

import importlib.machinery

from protocol import compiled


def _module(tmp_path, *, extension: bool, digest: str | None):
    source = tmp_path / "mod.py"
    source.write_text("X = 1\n")
    if extension:  # the chooser looks for the file; the standard finder would load it
        (tmp_path / f"mod{importlib.machinery.EXTENSION_SUFFIXES[0]}").write_bytes(b"")
    if digest is not None:
        (tmp_path / f"mod{compiled.SIDECAR}").write_text(digest + "\n")
    return source


def test_an_extension_built_from_this_source_is_used(tmp_path, monkeypatch):
    monkeypatch.delenv(compiled.PURE_ENV, raising=False)
    source = _module(tmp_path, extension=True, digest=None)
    (tmp_path / f"mod{compiled.SIDECAR}").write_text(compiled.source_digest(source) + "\n")
    assert compiled._Chooser()._interpreted_because(source, "mod") is None


def test_the_source_runs_without_an_extension_or_when_the_reference_is_asked_for(tmp_path, monkeypatch):
    monkeypatch.delenv(compiled.PURE_ENV, raising=False)
    source = _module(tmp_path, extension=False, digest=None)
    assert "not compiled" in compiled._Chooser()._interpreted_because(source, "mod")
    source = _module(tmp_path, extension=True, digest=None)
    (tmp_path / f"mod{compiled.SIDECAR}").write_text(compiled.source_digest(source) + "\n")
    for value, pure in (("1", True), ("0", False), ("", False)):
        monkeypatch.setenv(compiled.PURE_ENV, value)
        why = compiled._Chooser()._interpreted_because(source, "mod")
        assert (why == f"{compiled.PURE_ENV} is set") if pure else why is None


def test_an_extension_of_another_source_is_not_used_and_said_once(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(compiled.PURE_ENV, raising=False)
    source = _module(tmp_path, extension=True, digest="0" * 64)
    chooser = compiled._Chooser()
    assert "another source" in chooser._interpreted_because(source, "mod")
    assert "another source" in chooser._interpreted_because(source, "mod")
    err = capsys.readouterr().err
    assert err.count("changed since it was compiled") == 1 and str(source) in err
    # its C types are part of the source: an edited .pxd is a changed source too
    (tmp_path / f"mod{compiled.SIDECAR}").write_text(compiled.source_digest(source) + "\n")
    assert chooser._interpreted_because(source, "mod") is None
    source.with_suffix(".pxd").write_text("cdef int x\n")
    assert "another source" in chooser._interpreted_because(source, "mod")
