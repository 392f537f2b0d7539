"""gonio report: one self-contained HTML file (styles and figures inline, nothing fetched),
rendered by headless Chromium with every image loaded and no console error."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from acquisition import api
from acquisition.cli import main

SECTIONS = ("What was measured", "Physical checks", "Coverage", "Signal to noise", "Slices",
            "Energy", "Reciprocity", "Fits", "Comparison", "Rendered")
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update",
                  "--disable-sync"]


@pytest.fixture(scope="module")
def report(quick_tables: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("report") / "report.html"
    assert main(["report", str(quick_tables["ggx-session"]), "-o", str(out)]) == 0
    return out


def test_the_report_is_one_self_contained_file(report: Path) -> None:
    text = report.read_text(encoding="utf-8")
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    for section in SECTIONS:
        assert f"<h2>{section}</h2>" in text, section
    assert not re.search(r"""(src|href)=["'](?!data:)""", text)  # nothing fetched
    assert "<script" not in text and "http://" not in text and "https://" not in text
    images = re.findall(r'<img src="data:image/png;base64,[A-Za-z0-9+/=]+" alt="[^"]+">', text)
    assert len(images) >= 9
    assert "ggx:albedo=0.2,alpha=0.3,f0=0.04" in text  # what was measured
    assert "rig time: planned / actual" in text


def test_the_report_of_a_table_and_its_json(quick_tables: dict[str, Path], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "t.html"
    assert main(["report", str(quick_tables["beckmann"]), "-o", str(out), "--models",
                 "beckmann", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["report"] == str(out) and result["checks_passed"] is True
    assert [f["model"] for f in result["fits"]] == ["beckmann"]
    # a report replaces an earlier report, never the table it reads
    assert main(["report", str(quick_tables["beckmann"]), "-o", str(out), "--models", "ggx"]) == 0
    capsys.readouterr()
    assert main(["report", str(quick_tables["beckmann"]), "-o",
                 str(quick_tables["beckmann"])]) == 2
    assert "gonio: error:" in capsys.readouterr().err
    assert api.open_table(quick_tables["beckmann"]).count.sum() > 0  # the table is intact


def test_report_refuses_unknown_models_and_other_formats(quick_tables: dict[str, Path],
                                                          tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(quick_tables["ggx"]), "-o", str(tmp_path / "r.html"),
                 "--models", "gxx"]) == 2
    assert "--models: unknown model 'gxx'" in capsys.readouterr().err
    assert main(["report", str(quick_tables["ggx"]), "-o", str(tmp_path / "r.pdf")]) == 2
    assert "end the name in .html" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def _browser() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome", "chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


def test_the_report_renders_in_headless_chromium(report: Path, tmp_path: Path) -> None:
    browser = _browser()
    if browser is None:
        pytest.skip("no Chromium on this machine (Debian: apt-get install chromium; .ci/run "
                    "installs it when it runs as root)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a test extra")
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        chrome = p.chromium.launch(executable_path=browser, args=CHROMIUM_FLAGS)
        try:
            page = chrome.new_page(viewport={"width": 1200, "height": 900})
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(report.resolve().as_uri())
            loaded = page.evaluate(
                "Array.from(document.images).map(i => i.complete && i.naturalWidth > 0)")
            shot = tmp_path / "report.png"
            page.screenshot(path=str(shot), full_page=True)
        finally:
            chrome.close()
    assert len(loaded) >= 9 and all(loaded), loaded
    assert errors == []
    assert shot.stat().st_size > 50_000
