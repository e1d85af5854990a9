"""The whole report: its sections in order, from hand-made result folders."""

from magbench.cli import main
from tests.report.helpers import gamma_case


def test_report_from_fixture_files(tmp_path):
    (tmp_path / "gamma").mkdir()
    gamma_case().to_csv(tmp_path / "gamma" / "summary.csv", index=False)
    assert main(["report", f"results_dir={tmp_path}"]) == 0     # figures, then report.md
    text = (tmp_path / "report.md").read_text()
    assert "## Figure 2: sweep `gamma`" in text and "(gamma/fig2_gamma.png)" in text
    assert (tmp_path / "gamma" / "fig2_gamma.png").exists()
    page = (tmp_path / "report.html").read_text()       # the page, beside it, same sections
    assert '<section id="figure-2-sweep-gamma">' in page and "data:image/png;base64," in page
    assert text.count("**holds**") == 5
    assert "| Figure 6 |" in text and "**not evaluated**" in text


def test_sections_come_in_order_and_empty_ones_are_left_out(tmp_path):
    from magbench.report.build import build_report, header_section

    # Without results: the title, and the claims table saying Figure 6 was not evaluated.
    text = build_report(tmp_path, sections=())
    assert text.startswith(header_section(tmp_path) + "\n\n**Contents**\n\n"
                           "- [The paper's claims, checked](#the-papers-claims-checked)\n\n"
                           "## The paper's claims, checked")
    assert text.count("\n## ") == 1
    text = build_report(tmp_path, sections=(lambda d: "## A\n", lambda d: "", lambda d: "## B"))
    assert text.endswith("\n## A\n\n## B\n")


def test_figures_drawn_by_two_workers_are_the_files_drawn_by_one(tmp_path):
    """The report draws the folders' figures on n_jobs workers while it writes report.md:
    every file, the PNGs included, is byte for byte what one process writes."""
    for jobs in (1, 2):
        (tmp_path / f"j{jobs}" / "gamma").mkdir(parents=True)
        gamma_case().to_csv(tmp_path / f"j{jobs}" / "gamma" / "summary.csv", index=False)
        assert main(["report", f"results_dir={tmp_path / f'j{jobs}'}", f"n_jobs={jobs}"]) == 0
    files = sorted(p.relative_to(tmp_path / "j1") for p in (tmp_path / "j1").rglob("*")
                   if p.is_file())
    assert {"gamma/fig2_gamma.png", "report.md", "report.html"} <= set(map(str, files))
    for name in files:
        assert (tmp_path / "j1" / name).read_bytes() == (tmp_path / "j2" / name).read_bytes()


def test_figure_workers_know_the_plugins_methods(tmp_path):
    """The report draws each folder's figures in a worker process: a plugin's method keeps
    its registered label there, as when one process draws them."""
    import sys

    import pandas as pd
    from joblib.externals.loky import get_reusable_executor

    from magbench.cli.commands import draw_figures
    from magbench.methods.registry import methods, unregister
    from tests.report.helpers import rb_sweep

    before, imported = set(methods()), "tests.plugins.counting" in sys.modules
    import tests.plugins.counting  # noqa: F401  (registers counting_a here, as main does)

    try:
        for sweep, case in (("gamma", gamma_case()),
                            ("beta", rb_sweep("beta", [0.1, 0.5], {}))):
            added = case[case["algorithm"] == "twostep"].assign(algorithm="counting_a")
            (tmp_path / sweep).mkdir()
            pd.concat([case, added], ignore_index=True).to_csv(
                tmp_path / sweep / "summary.csv", index=False)
        get_reusable_executor().shutdown(wait=True)          # fresh workers: nothing imported
        draw_figures(tmp_path, n_jobs=2)
        for sweep, figure in (("gamma", "fig2_gamma.csv"), ("beta", "fig3_beta.csv")):
            drawn = pd.read_csv(tmp_path / sweep / figure)
            assert set(drawn.loc[drawn["series"] == "counting_a", "label"]) == {"counting A"}
    finally:
        # The plugin's methods leave with this test: the tests after it see the shipped ones.
        for name in set(methods()) - before:
            unregister(name)
        if not imported:
            sys.modules.pop("tests.plugins.counting", None)


def test_a_sweeps_text_left_to_the_report_is_written_beside_its_figures(tmp_path):
    """reproduce leaves each sweep's own text (its kind's section) to the report step, whose
    figure workers write it; the sweep's folder stays locked until then."""
    import contextlib

    import pytest

    from magbench.cli.commands import SectionQueue, draw_figures
    from magbench.engine.sweep import FolderBusy, folder_lock, run_lock

    for case in ("one", "queued"):
        (tmp_path / case / "gamma").mkdir(parents=True)
        gamma_case().to_csv(tmp_path / case / "gamma" / "summary.csv", index=False)
    alone = draw_figures(tmp_path / "one", n_jobs=1)
    queue = SectionQueue()
    with contextlib.ExitStack() as held:     # the sweep's folder lock, handed to the queue
        held.enter_context(run_lock(tmp_path / "queued" / "gamma"))
        queue.submit("gamma", _note_section, held.pop_all())
    with pytest.raises(FolderBusy):          # held until its files are written
        with folder_lock(tmp_path / "queued" / "gamma"):
            pass
    drawn = draw_figures(tmp_path / "queued", n_jobs=2, queue=queue)
    queue.release()
    with folder_lock(tmp_path / "queued" / "gamma"):
        pass
    assert (tmp_path / "queued" / "gamma" / "section.md").read_text() == "gamma: 0 figures\n"
    assert [p.relative_to(tmp_path / "queued") for p in drawn] == [
        p.relative_to(tmp_path / "one") for p in alone]
    for name in ("gamma/fig2_gamma.png", "gamma/fig2_gamma.csv"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "queued" / name).read_bytes()


def _note_section(out_dir):
    """A section that says how many figures it found (none: they are drawn after it)."""
    (out_dir / "section.md").write_text(f"{out_dir.name}: "
                                        f"{len(list(out_dir.glob('*.png')))} figures\n")
