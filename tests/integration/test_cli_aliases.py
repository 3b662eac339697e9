"""The report functions that left the library faces for `identification.cli` stay reachable at their old
paths for one release, with a `DeprecationWarning` naming the new path."""

import importlib

import pytest

import identification.cli

MOVED = [("identification", "calibration_report", "calibration_report"),
         ("identification.calibration", "calibration_report", "calibration_report"),
         ("identification.diagnosis", "summary", "diagnosis_summary"),
         ("identification.diagnosis", "progress_lines", "progress_lines")]


@pytest.mark.parametrize(("module", "old", "new"), MOVED)
def test_old_path_warns_and_returns_the_moved_function(module, old, new):
    with pytest.warns(DeprecationWarning, match=rf"{module}\.{old} moved to identification\.cli\.{new}"):
        found = getattr(importlib.import_module(module), old)
    assert found is getattr(identification.cli, new)


def test_unknown_name_is_still_an_attribute_error():
    identification = importlib.import_module("identification")
    with pytest.raises(AttributeError, match="no attribute 'calibration_reprot'"):
        identification.calibration_reprot  # noqa: B018 - the attribute access is what is tested
