"""report.html in a real browser: headless Chromium renders the page and runs its script.

Skipped when ``chromium`` is not on the PATH (``.ci/run`` installs Debian's package; locally:
``apt-get install -y chromium``).
"""

import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from magbench.report.build import HTML_DETAILS, REVIEW_SECTIONS
from magbench.report.html import write_html
from tests.report.helpers import gamma_case

CHROMIUM = shutil.which("chromium")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium is not installed (apt-get install -y chromium; "
                             ".ci/run installs it)")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
COMMITTED = Path(__file__).resolve().parents[2] / "results" / "report.html"


def chromium(tmp_path: Path, *args: str) -> str:
    profile = tmp_path / "profile"
    profile.mkdir(exist_ok=True)
    done = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", *args],
                          capture_output=True, text=True, timeout=120, check=True)
    return done.stdout


class Tables(HTMLParser):
    """The page's tables as seen after the script ran: class, id and cell texts per row."""

    def __init__(self):
        super().__init__()
        self.tables, self.cell, self.nav = [], None, False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "table":
            self.tables.append({"class": a.get("class", ""), "id": a.get("id"), "rows": []})
        elif tag == "tr" and self.tables:
            self.tables[-1]["rows"].append([])
        elif tag in ("td", "th") and self.tables:
            self.cell = ""
        elif tag == "nav" and a.get("id") == "contents":
            self.nav = True

    def handle_data(self, data):
        if self.cell is not None:
            self.cell += data

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self.cell is not None:
            self.tables[-1]["rows"][-1].append(self.cell.strip())
            self.cell = None


def _page(tmp_path: Path) -> Path:
    (tmp_path / "gamma").mkdir()
    gamma_case().to_csv(tmp_path / "gamma" / "summary.csv", index=False)
    return write_html(tmp_path, REVIEW_SECTIONS, HTML_DETAILS)


def test_sorting_runs_in_the_browser(tmp_path):
    page = _page(tmp_path)
    before = Tables()
    before.feed(chromium(tmp_path, "--dump-dom", page.as_uri()))
    sweep = next(i for i, t in enumerate(before.tables) if t["rows"][0][:1] == ["method"])
    rows = before.tables[sweep]["rows"][1:]
    column = 1                   # the first value column
    dom = chromium(tmp_path, "--dump-dom", page.as_uri() + f"?sort={sweep},{column},desc")
    assert f'data-sorted="{sweep},{column},desc"' in dom         # the script ran
    after = Tables()
    after.feed(dom)
    assert after.nav                                             # the contents are there
    sorted_rows = after.tables[sweep]["rows"][1:]
    assert sorted(map(tuple, sorted_rows)) == sorted(map(tuple, rows))   # same rows
    keys = [float(re.match(r"-?[\d.]+(e[-+]?\d+)?", r[column])[0]) for r in sorted_rows
            if re.match(r"-?[\d.]", r[column])]
    assert keys == sorted(keys, reverse=True) and len(set(keys)) > 1
    assert 'aria-sort="descending"' in dom


def test_screenshot_is_drawn(tmp_path):
    page = _page(tmp_path)
    shot = tmp_path / "page.png"
    chromium(tmp_path, "--window-size=1000,1400", f"--screenshot={shot}", page.as_uri())
    data = shot.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert (width, height) == (1000, 1400)


@pytest.mark.skipif(not COMMITTED.exists(), reason="no committed results/report.html")
def test_committed_report_shows_contents_and_the_answer_first(tmp_path):
    dom = chromium(tmp_path, "--dump-dom", COMMITTED.as_uri() + "?sort=0,3,desc")
    seen = Tables()
    seen.feed(dom)
    assert seen.nav
    decision = seen.tables[0]
    assert "decision" in decision["class"] and decision["id"] == "decision"
    assert decision["rows"][0] == ["setting", "method", "why", "n", "interval"]
    assert len(decision["rows"]) > 5
    n = [int(r[3]) for r in decision["rows"][1:]]
    assert n == sorted(n, reverse=True)
    # the answer comes before the first section's details
    assert dom.index('id="decision"') < dom.index('<section id="baseline-table-2"')
