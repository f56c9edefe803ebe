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


def test_an_extension_of_a_module_off_the_list_is_never_loaded(tmp_path, monkeypatch):
    """A module compiled once and since taken off MODULES: its source runs, not the old extension."""
    monkeypatch.delenv(compiled.PURE_ENV, raising=False)
    name = "controller.zz_once_compiled"
    assert name not in compiled.MODULES
    source = _module(tmp_path, extension=True, digest=None).rename(tmp_path / "zz_once_compiled.py")
    (tmp_path / "mod.py").write_text("")
    (tmp_path / f"mod{importlib.machinery.EXTENSION_SUFFIXES[0]}").rename(tmp_path / f"zz_once_compiled{importlib.machinery.EXTENSION_SUFFIXES[0]}")
    chooser = compiled._Chooser()
    spec = chooser.find_spec(name, [str(tmp_path)])
    assert spec is not None and spec.origin == str(source) and "MODULES" in chooser.why[name]
    # without an extension beside it, the standard finder's business
    assert chooser.find_spec("controller.mod", [str(tmp_path)]) is None
    # and nothing outside the project's packages
    assert chooser.find_spec("numpyish.zz_once_compiled", [str(tmp_path)]) is None
