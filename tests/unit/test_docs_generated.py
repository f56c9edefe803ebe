"""The generated blocks of docs/FIRMWARE.md, docs/TRACE.md and docs/FAULTS.md (``tools/docgen.py``, ``make docs``)
are what the code gives today, and what they show is right by independent references: the CRC
vectors against AUTOSAR's published values, the C code of FIRMWARE.md compiled and run on them,
the example frames decoded by cantools."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest

from protocol.catalog import DBC_PATH, default_catalog
from protocol.codec import Codec
from tests.conftest import ROOT
from tools import docgen

FIRMWARE = ROOT / "docs" / "FIRMWARE.md"
TRACE = ROOT / "docs" / "TRACE.md"
FAULTS = ROOT / "docs" / "FAULTS.md"
STALE = "stale: run `make docs` (python -m tools.docgen)"


def _block(path, name: str) -> str:
    text = path.read_text()
    for found, start, end in docgen.blocks_of(text, path):
        if found == name:
            return text[start:end]
    raise AssertionError(f"{path.name} has no generated block {name!r}")


@pytest.mark.parametrize("name", ["crc-vectors", "messages", "frame-examples", "node-ids", "node-timing"])
def test_firmware_md_blocks_are_what_the_code_gives(name):
    assert _block(FIRMWARE, name) == docgen.render(name), f"docs/FIRMWARE.md {name}: {STALE}"


def test_faults_md_lists_every_fault_kind_of_the_controller():
    assert _block(FAULTS, "fault-kinds") == docgen.render("fault-kinds"), f"docs/FAULTS.md fault-kinds: {STALE}"


def test_trace_md_bench_figures_are_docs_perf_trace_json():
    assert _block(TRACE, "trace-bench") == docgen.render("trace-bench"), f"docs/TRACE.md trace-bench: {STALE}"


def test_trace_md_resim_example_is_what_the_commands_print():
    """Runs the three commands of the example through the real command line (a one-cycle walk)."""
    pytest.importorskip("pybullet")
    assert _block(TRACE, "resim-example") == docgen.render("resim-example"), f"docs/TRACE.md resim-example: {STALE}"


def test_every_document_names_only_known_blocks_and_each_is_closed():
    for path in docgen.DOCUMENTS:
        names = [name for name, _, _ in docgen.blocks_of(path.read_text(), path)]
        assert names and len(names) == len(set(names)), (path, names)
    assert {n for p in docgen.DOCUMENTS for n, _, _ in docgen.blocks_of(p.read_text(), p)} == set(docgen.BLOCKS)


#: AUTOSAR SWS CRC Library, CRC8 (SAE J1850) check values, and the standard check of "123456789".
PUBLISHED = {
    "31 32 33 34 35 36 37 38 39": "0x4B", "(none)": "0x00", "00 00 00 00": "0x59", "F2 01 83": "0x37",
    "0F AA 00 55": "0x79", "00 FF 55 11": "0xB8", "33 22 55 AA BB CC DD EE FF": "0xCB", "92 6B 55": "0x8C",
    "FF FF FF FF": "0x74",
}


def test_the_crc_vectors_are_the_published_ones():
    rows = dict(re.findall(r"^\| [^|]+ \| `?([^|`]+?)`? \| (0x[0-9A-F]{2})", _block(FIRMWARE, "crc-vectors"), flags=re.M))
    assert {k: rows.get(k) for k in PUBLISHED} == PUBLISHED


def _c_source() -> str:
    blocks = re.findall(r"```c\n(.*?)```", FIRMWARE.read_text(), flags=re.S)
    assert len(blocks) == 1
    return blocks[0]


def test_the_c_crc_of_firmware_md_gives_every_vector_and_every_frame_crc(tmp_path):
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    catalog = default_catalog()
    codec = Codec(catalog)
    vectors = [bytes.fromhex(k.replace(" ", "")) if k != "(none)" else b"" for k in PUBLISHED]
    frames = [(m.data_id, docgen.example_frame(codec, m)[0]) for m in catalog.messages]
    arrays = "\n".join(f"static const uint8_t v{i}[] = {{{', '.join(str(b) for b in v) or '0'}}};" for i, v in enumerate(vectors))
    arrays += "\n" + "\n".join(f"static const uint8_t f{i}[] = {{{', '.join(str(b) for b in f)}}};" for i, (_, f) in enumerate(frames))
    calls = "\n".join(f'    printf("%02X\\n", crc8_sae_j1850(v{i}, {len(v)}));' for i, v in enumerate(vectors))
    calls += "\n" + "\n".join(f'    printf("%02X\\n", aider_frame_crc({d}, f{i}, {len(f)}));' for i, (d, f) in enumerate(frames))
    source = tmp_path / "crc.c"
    source.write_text("#include <stdio.h>\n" + _c_source() + arrays + "\nint main(void)\n{\n" + calls + "\n    return 0;\n}\n")
    subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-o", str(tmp_path / "crc"), str(source)], check=True)
    out = subprocess.run([str(tmp_path / "crc")], check=True, capture_output=True, text=True).stdout.split()
    assert out == [v.removeprefix("0x") for v in PUBLISHED.values()] + [f"{f[0]:02X}" for _, f in frames]


def test_cantools_decodes_every_example_frame_to_the_values_shown():
    import cantools

    db = cantools.database.load_file(str(DBC_PATH))
    codec = Codec()
    for spec in default_catalog().messages:
        data, decoded = docgen.example_frame(codec, spec)
        theirs = db.decode_message(spec.frame_id, data, decode_choices=False)
        ours = decoded.values._asdict()
        assert theirs["e2e_counter"] == docgen.EXAMPLE_COUNTER == decoded.counter and theirs["e2e_crc"] == data[0]
        for name, value in ours.items():
            assert theirs[name] == pytest.approx(value, abs=1e-9), (spec.name, name)
        for name, wanted in docgen.EXAMPLES[next(n for n in docgen.EXAMPLES if codec.spec(n).family == spec.family)].items():
            assert ours[name] == pytest.approx(float(wanted), abs=spec.signal(name).scale / 2), (spec.name, name)


def test_docgen_check_names_a_stale_block_and_update_rewrites_only_the_blocks(tmp_path, capsys):
    doc = tmp_path / "doc.md"
    doc.write_text("# before\n\n<!-- generated: node-ids (x) -->\nold\n<!-- /generated: node-ids -->\n\nafter 1.5 %\n")
    assert docgen.main(["--check", str(doc)]) == 1
    assert f"stale {doc}: node-ids" in capsys.readouterr().out and "old" in doc.read_text()
    assert docgen.main([str(doc)]) == 0
    text = doc.read_text()
    assert text.startswith("# before\n\n<!-- generated: node-ids (x) -->\n| node |") and text.endswith(
        "<!-- /generated: node-ids -->\n\nafter 1.5 %\n")
    assert docgen.main(["--check", str(doc)]) == 0
    doc.write_text("<!-- generated: nonsense -->\n<!-- /generated: nonsense -->\n")
    assert docgen.main(["--check", str(doc)]) == 1
    assert "unknown generated block 'nonsense'" in capsys.readouterr().err


def test_firmware_md_is_linked_from_the_readme_and_deploy_md():
    assert "(docs/FIRMWARE.md)" in (ROOT / "README.md").read_text()
    assert "(FIRMWARE.md)" in (ROOT / "docs" / "DEPLOY.md").read_text()
