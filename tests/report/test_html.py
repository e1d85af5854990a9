"""report.html: the Markdown-to-HTML converter, the page's parts, and no network."""

import base64
import re

import numpy as np
import pandas as pd

from magbench.report.build import HTML_DETAILS, REVIEW_SECTIONS, build_report
from magbench.report.html import FOLD_ROWS, build_html, figure_note, md_to_html, slug
from tests.report.helpers import gamma_case

PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAYAAAAfFcSJAAAADUlEQVR42mNkYPhfDwAChwGA60e6kgAAAABJRU5ErkJggg==")


def test_tables_are_sortable_and_long_ones_folded(tmp_path):
    short = "| a | b |\n|---|---|\n| 1 | x |"
    html = md_to_html(short, tmp_path)
    assert html.startswith('<table class="sortable"><thead><tr><th>a</th><th>b</th>')
    assert "<details>" not in html
    long = short + "".join(f"\n| {i} | y |" for i in range(FOLD_ROWS))
    html = md_to_html(long, tmp_path)
    assert html.startswith("<details><summary>Table: a, b, ... (") and html.endswith(
        "</details>")


def test_headings_sections_and_folded_subsections(tmp_path):
    html = md_to_html("## A b: `c`\n\ntext\n\n### Sub\n\nmore\n\n## D", tmp_path)
    assert '<section id="a-b-c"><h2>A b: <code>c</code></h2>' in html
    assert '<details id="sub"><summary>Sub</summary>\n<p>more</p>\n</details>' in html
    assert html.count("<section") == html.count("</section>") == 2


def test_inline_markup_code_is_literal_and_html_escaped(tmp_path):
    html = md_to_html("**bold** *it* `a*b*<c>` x < y, a * b", tmp_path)
    assert html == ("<p><strong>bold</strong> <em>it</em> <code>a*b*&lt;c&gt;</code> "
                    "x &lt; y, a * b</p>")


def test_images_are_embedded_with_their_n(tmp_path):
    (tmp_path / "f").mkdir()
    (tmp_path / "f" / "pic.png").write_bytes(PNG)
    pd.DataFrame({"x": [1, 2], "n": [250, 250], "n_meaningful": [240, 250]}).to_csv(
        tmp_path / "f" / "pic.csv", index=False)
    html = md_to_html("![A picture](<f/pic.png>)", tmp_path)
    assert 'src="data:image/png;base64,' + base64.b64encode(PNG).decode() in html
    assert "n per point (pic.csv): n 250; n_meaningful 240-250" in html
    assert "[figure f/nope.png missing]" in md_to_html("![x](f/nope.png)", tmp_path)


def test_figure_note_counts_runs_without_an_n_column(tmp_path):
    pd.DataFrame({"method": ["ML", "ML", "NM"], "run": [0, 1, 0], "v": 1.0}).to_csv(
        tmp_path / "fig.csv", index=False)
    assert figure_note(tmp_path / "fig.png") == "n per point (fig.csv): runs per point 1-2"


def test_slug_matches_github_anchors():
    assert slug("Figure 2: sweep `gamma`") == "figure-2-sweep-gamma"
    assert slug("The paper's claims, checked") == "the-papers-claims-checked"


def test_page_from_a_results_folder_is_self_contained(tmp_path):
    (tmp_path / "gamma").mkdir()
    gamma_case().to_csv(tmp_path / "gamma" / "summary.csv", index=False)
    html = build_html(tmp_path, REVIEW_SECTIONS, HTML_DETAILS)
    assert html.startswith("<!DOCTYPE html>")
    assert '<nav class="toc" id="contents">' in html
    assert '<a href="#figure-2-sweep-gamma">' in html
    # nothing fetched from elsewhere: no src or stylesheet pointing at a network address
    assert not re.search(r'(src|href)="(https?:)?//', html)
    assert "<script src" not in html and "<link" not in html


def test_markdown_report_has_contents_and_names_no_other_folder(tmp_path):
    (tmp_path / "gamma").mkdir()
    gamma_case().to_csv(tmp_path / "gamma" / "summary.csv", index=False)
    text = build_report(tmp_path)
    assert "results/" not in text
    assert "- [Figure 2: sweep gamma](#figure-2-sweep-gamma)" in text
    # the contents list exactly the sections the report has
    toc = re.findall(r"^- \[.*\]\(#(.*)\)$", text, flags=re.MULTILINE)
    heads = [slug(h) for h in re.findall(r"^## (.*)$", text, flags=re.MULTILINE)]
    assert toc == heads


def test_svg_points_say_value_and_n():
    from magbench.figures.svg import line_chart_svg

    data = pd.DataFrame({"series": ["twostep", "twostep"], "label": "TWOSTEP", "x": [0.1, 1.0],
                         "RB_pct": [100.0, 50.0], "n": [250, 250],
                         "n_meaningful": [250, 125]})
    svg = line_chart_svg(data, "RB_pct", "RB")
    assert svg.count("<circle") == 2
    assert "<title>TWOSTEP, x = 1.0: RB_pct = 50 (n = 250, meaningful 125)</title>" in svg
    assert line_chart_svg(data.assign(RB_pct=np.nan), "RB_pct", "RB") == ""


def test_references_to_absent_sections_are_left_out():
    from magbench.report.build import link_sections

    text = "x (the section 'A b' says so) y.\n\n## C: d\n\nsee the section 'C' below"
    assert link_sections(text) == ("x y.\n\n## C: d\n\nsee [the section 'C'](#c-d) below")


def test_markdown_leaves_html_only_blocks_and_long_tables_to_the_page():
    from magbench.report.format import MD_MAX_ROWS, html_only, shorten_for_markdown

    long = "| a | b |\n|---|---|" + "".join(f"\n| {i} | y |" for i in range(MD_MAX_ROWS + 1))
    text = shorten_for_markdown("p\n\n" + html_only("| s |\n|---|\n| 1 |", "Speeds") + "\n\n"
                                + long + "\nq")
    assert text == (f"p\n\n*Speeds: in `report.html`.*\n\n*A table of {MD_MAX_ROWS + 1} rows "
                    "(a, b, ...): in `report.html`.*\nq")
