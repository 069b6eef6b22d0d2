"""The history files as a run writes them at every iteration: the same records as the
indented writer's, one line each, and nothing non-finite."""

import json
from dataclasses import asdict

import numpy as np
import pytest

from tofsi.optimization.history import NOT_APPLICABLE, Iteration
from tofsi.runs.output import to_json, write_json_rows


def test_history_rows_are_the_iterations_fields_with_not_applicable_nan_as_none():
    it = Iteration(3, 1, 2.5, 0.9, 0.3, -0.01, 0.02, 8.0, 3.0, 0.1, 1.25, "two-way",
                   min_skewness=0.4, fallbacks=np.int64(2))
    expected = {k: (None if k in NOT_APPLICABLE and v != v else v) for k, v in asdict(it).items()}
    assert it.row() == expected
    assert Iteration.from_row(it.row()).row() == expected


def test_history_json_holds_the_records_one_per_line_as_the_indented_writer_does(tmp_path):
    rows = [{"iteration": np.int64(k), "objective": np.float32(0.5 * k), "coupling": "one-way",
             "min_skewness": None} for k in range(3)]
    path = write_json_rows(tmp_path / "history.json", rows)
    text = path.read_text()
    assert json.loads(text) == json.loads(to_json(rows))
    assert len(text.splitlines()) == len(rows) + 2
    assert json.loads(write_json_rows(tmp_path / "empty.json", []).read_text()) == []


@pytest.mark.parametrize("bad", [float("nan"), np.float32("inf"), np.array([1.0, np.nan])],
                         ids=["float", "numpy-scalar", "numpy-array"])
def test_a_non_finite_history_value_is_refused_not_written_as_null(tmp_path, bad):
    with pytest.raises(ValueError):
        write_json_rows(tmp_path / "history.json", [{"objective": bad}])
