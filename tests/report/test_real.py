"""The real-recordings section's flag of accuracies set by the recordings kept."""

import pandas as pd

from magbench.report.real import _selection_lines


def test_selection_artefacts_are_named_with_what_the_others_score_there():
    per_rec = pd.DataFrame([
        {"dataset": f"r{i}", "preprocess": "scale", "algorithm": a, "skipped": False,
         "meaningful": not (a == "dorveaux" and i >= 2), "J_r_in": 1e-4 if i < 2 else 1e-2}
        for i in range(4) for a in ("dorveaux", "magical", "ali")])
    per_method = pd.DataFrame({"preprocess": "scale", "algorithm": ["dorveaux"],
                               "accuracy_in": [1e4]})
    text = _selection_lines(per_method, per_rec)[0]
    assert "Dorveaux (`scale`) 1e+04 on its 2 recordings, where the others score 1e+04 " \
           "(51x their accuracy on all they solve)" in text        # 1e4 / 198
    assert _selection_lines(per_method, per_rec.assign(meaningful=True)) == []
