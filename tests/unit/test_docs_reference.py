"""The documents are reference: no dated measurement outside CHANGELOG.md (history lives there),
and every relative link in them points to a file of the repository."""

from __future__ import annotations

import re

import pytest

from tests.conftest import ROOT

DOCS = sorted([ROOT / "README.md", *(ROOT / "docs").rglob("*.md")])
DATED = re.compile(
    r"\b20\d\d-[01]\d-[0-3]\d\b"  # 2026-12-03
    r"|\b(jan|feb|mar|apr|may|jun|jul|aug|sep|oct|nov|dec)[a-z]*\.? [0-3]?\d(st|nd|rd|th)?,? 20\d\d\b"  # Dec 3, 2026
    r"|\b[0-3]?\d (jan|feb|mar|apr|may|jun|jul|aug|sep|oct|nov|dec)[a-z]* 20\d\d\b"  # 3 December 2026
    r"|\b(this|that|earlier|same|one|previous) sessions?\b"  # a development session, not a patient's
    r"|\b(this|that) (morning|evening|afternoon)\b|\byesterday\b",
    re.IGNORECASE,
)


def _rel(path):
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize("path", DOCS, ids=_rel)
def test_no_dated_measurement_outside_the_changelog(path):
    hits = [f"{_rel(path)}:{n}: {line.strip()[:120]}" for n, line in enumerate(path.read_text().splitlines(), 1)
            if DATED.search(line)]
    assert not hits, "dated text belongs in CHANGELOG.md:\n" + "\n".join(hits)


def test_the_pattern_finds_what_it_is_for():
    for dated in ("measured on 2026-12-03", "Dec 3, 2026", "3 December 2026", "in the same session", "that evening"):
        assert DATED.search(dated), dated
    for fine in ("Every session on the bench is analysed", "commit 32f1460", "ISO 13482", "2026 patients"):
        assert not DATED.search(fine), fine


@pytest.mark.parametrize("path", DOCS, ids=_rel)
def test_every_relative_link_points_to_a_file(path):
    broken = []
    for target in re.findall(r"\]\(([^)\s#]+)(?:#[^)]*)?\)", path.read_text()):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        if not (path.parent / target).exists():
            broken.append(target)
    assert not broken, f"{_rel(path)}: links to missing files {broken}"


def test_the_changelog_holds_the_history():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert re.search(r"^## 20\d\d-\d\d-\d\d$", text, flags=re.M)
