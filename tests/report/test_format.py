"""Numbers, labels and prose templates shared by the report's sections."""

import numpy as np
import pytest

from magbench.report.format import compact_number, format_number, names, render


def test_numbers_in_tables_and_in_sentences():
    assert format_number(2.28e5) == "2.28e+05" and format_number(np.nan) == "-"
    assert compact_number(2.28e5) == "2.28e5" and compact_number(1 / 2.28e5, 2) == "4.4e-6"
    assert compact_number(35.3) == "35.3" and compact_number(3.31e3) == "3.31e3"


def test_names_are_the_registered_labels():
    assert names(["magical", "ali", "not_registered"]) == "MAG.I.C.AL, Ali PSO, not_registered"


def test_a_template_block_is_one_paragraph_filled_from_its_context():
    text = render("table2.legend", n=250, delta=0.5, speed="S")
    assert text.startswith("250 trials at the nominal point of eq. (80), delta = 0.5 in eq.")
    assert "\n" not in text and "speed is S;" in text
    with pytest.raises(KeyError):
        render("table2.legend", n=250)
