"""Every built FMU carries documentation/index.html (models/fmu_docs.py, packaged by add_fmu in fmus/CMakeLists.txt):
the page of its model and FMI version, listing every variable of its modelDescription.xml with the same value
reference, causality and unit, self-contained (no links, scripts or external resources); fmpy validates the FMU."""
from __future__ import annotations

import html
import re
import xml.etree.ElementTree as ET
import zipfile
from html.parser import HTMLParser
from pathlib import Path

import pytest
from fmpy.validation import validate_fmu

from fmu_helpers import all_fmus, fmu_id, require_fmu, split_fmu_name
from milling_twin.models import MODELS
from milling_twin.models import fmu_docs


class _Table(HTMLParser):
    """The rows of the page's variable table (cells as text) and every tag and attribute seen."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[list[str]] = []
        self.tags: list[tuple[str, dict]] = []
        self._cell: list[str] | None = None

    def handle_starttag(self, tag: str, attrs: list) -> None:
        self.tags.append((tag, dict(attrs)))
        if tag == "tr":
            self.rows.append([])
        elif tag == "td":
            self._cell = []

    def handle_endtag(self, tag: str) -> None:
        if tag == "td" and self._cell is not None:
            self.rows[-1].append("".join(self._cell).strip())
            self._cell = None

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)


def _contents(path: Path) -> tuple[str, ET.Element]:
    with zipfile.ZipFile(require_fmu(path)) as z:
        names = z.namelist()
        assert "documentation/index.html" in names, f"{path.name}: no documentation/index.html in {names[:8]}..."
        return z.read("documentation/index.html").decode("utf-8"), ET.fromstring(z.read("modelDescription.xml"))


def _described(root: ET.Element) -> dict[str, dict[str, str]]:
    """Variable name -> causality, valueReference, unit (FMI 2: from the type element; arrays: by base name, the
    references of its scalars joined)."""
    out: dict[str, dict[str, str]] = {}
    fmi2 = root.get("fmiVersion", "").startswith("2")
    for v in root.find("ModelVariables"):
        typed = v[0] if fmi2 and len(v) else v
        base = re.sub(r"\[[0-9,]+\]$", "", v.get("name"))
        entry = out.setdefault(base, {"causality": v.get("causality"), "unit": typed.get("unit", ""), "refs": []})
        entry["refs"].append(int(v.get("valueReference")))
    return out


@pytest.mark.parametrize("path", all_fmus(), ids=fmu_id)
def test_the_page_lists_every_variable_of_the_model_description(path: Path) -> None:
    text, root = _contents(path)
    described = _described(root)
    table = _Table()
    table.feed(text)
    rows = [r for r in table.rows if r]  # the header row has <th> cells only
    listed = {}
    for row in rows:
        name = row[0].split()[0]
        listed[name] = row
    assert sorted(listed) == sorted(described), (
        f"{path.name}: page lists {sorted(set(listed) - set(described))} not in modelDescription.xml, misses "
        f"{sorted(set(described) - set(listed))}")
    for name, row in listed.items():
        entry = described[name]
        refs = entry["refs"]
        expected_refs = str(refs[0]) if len(refs) == 1 else f"{refs[0]} .. {refs[-1]}"
        assert row[1] == expected_refs, (path.name, name, row[1], refs[:3])
        assert row[2] == entry["causality"], (path.name, name)
        assert row[5] == entry["unit"] or (entry["unit"] == "" and row[5] in ("", "1")), (path.name, name, row[5])
        if len(refs) > 1:
            assert f"{len(refs)} scalars" in row[0], (path.name, name, row[0])


@pytest.mark.parametrize("path", all_fmus(), ids=fmu_id)
def test_the_page_is_the_generated_one_and_self_contained(path: Path) -> None:
    text, root = _contents(path)
    identifier, version = split_fmu_name(path)
    assert text == fmu_docs.page(MODELS[identifier], version), f"{path.name}: rebuild (models/ changed since)"
    table = _Table()
    table.feed(text)
    tags = {tag for tag, _ in table.tags}
    assert not tags & {"a", "link", "script", "img", "iframe", "object", "embed"}, tags
    assert not any(set(attrs) & {"href", "src"} for _, attrs in table.tags)
    assert "http://" not in text and "https://" not in text
    assert root.get("description") in html.unescape(text)
    assert "<h2>Equations</h2>" in text or not MODELS[identifier].equations


@pytest.mark.parametrize("path", all_fmus(), ids=fmu_id)
def test_fmpy_validates_the_fmu_with_its_documentation(path: Path) -> None:
    assert validate_fmu(str(require_fmu(path))) == []


def test_the_generator_writes_one_page_per_fmi_version(tmp_path: Path) -> None:
    pages = fmu_docs.write(MODELS["ForceNet"], tmp_path)
    assert [p.relative_to(tmp_path).as_posix() for p in pages] == ["fmi2/documentation/index.html",
                                                                  "fmi3/documentation/index.html"]
    fmi2, fmi3 = (p.read_text() for p in pages)
    assert "engagement[1,1]" in fmi2 and "engagement[1,1]" not in fmi3
    before = pages[0].stat().st_mtime_ns
    fmu_docs.write(MODELS["ForceNet"], tmp_path)
    assert pages[0].stat().st_mtime_ns == before  # unchanged: not rewritten (the build does not repackage)
    assert fmu_docs.main(["NoSuchModel", str(tmp_path)]) == 2
