"""The design in a child process: same result as in-process, progress, errors, and Cancel within a second at every
stage (the child is killed, clustering included)."""

import os
import time

import numpy as np
import pytest

from IsoSimilarityTFLib import OptionError, design_transfer_function
from IsoSimilarityTFLib.worker import DesignProcess
from isosimtf.phantom import head_phantom


@pytest.fixture(scope="module")
def phantom():
    return head_phantom(40, seed=2)


def test_child_gives_the_same_design_as_in_process(phantom):
    reports = []
    with DesignProcess(phantom.values, phantom.spacing, {"n_bins": 128}) as job:
        design = job.wait(timeout=120, progress=lambda *report: reports.append(report))
        folder = job.folder
    assert not os.path.exists(folder)
    expected = design_transfer_function(phantom.values, phantom.spacing, n_bins=128)
    np.testing.assert_array_equal(design.labels, expected.labels)
    assert design.to_dict()["classes"] == expected.to_dict()["classes"]
    # The Slicer module's child gets the look's visibility step, and its preview for the Detail slider.
    assert design.to_dict()["tissues"] == expected.to_dict()["tissues"]
    assert all(t.picture_share is not None for t in design.tissues)
    np.testing.assert_array_equal(design.preview.bins, expected.preview.bins)
    np.testing.assert_array_equal(design.similarity, expected.similarity)
    assert design.spacing == expected.spacing
    stages = [stage for stage, _, _ in reports]
    assert stages[0] == "quantize" and stages[-1] == "tissues" and "similarity" in stages and "clustering" in stages


def test_child_errors_come_back_with_their_type_and_message(phantom):
    with DesignProcess(phantom.values, None, {"n_bins": 1}) as job:
        with pytest.raises(OptionError, match="n_bins"):
            job.wait(timeout=120)
    with DesignProcess(np.zeros((8, 8, 8)), None, {}) as job:
        with pytest.raises(ValueError, match="constant"):
            job.wait(timeout=120)


def test_a_child_that_dies_is_reported(phantom, tmp_path):
    script = tmp_path / "python"
    script.write_text("#!/bin/sh\necho 'Fatal Python error: on purpose'\nexit 3\n")
    script.chmod(0o755)
    with DesignProcess(phantom.values, None, {}, python=str(script)) as job:
        with pytest.raises(RuntimeError, match="ended with code 3: Fatal Python error: on purpose"):
            job.wait(timeout=120)


def cancel_at(stage_wanted, values, options):
    """Start a design, cancel it as soon as ``stage_wanted`` is reported; seconds from Cancel to the child's end."""
    with DesignProcess(values, None, options) as job:
        deadline = time.monotonic() + 300
        seen = []
        while time.monotonic() < deadline and job.running:
            seen += [stage for stage, _, _ in job.poll()]
            if stage_wanted in seen:
                break
            time.sleep(0.02)
        assert stage_wanted in seen and job.running, f"never saw {stage_wanted} while running: {seen}"
        start = time.monotonic()
        job.cancel()
        elapsed = time.monotonic() - start
        assert not job.running
        with pytest.raises(RuntimeError, match="cancelled"):
            job.result()
    return elapsed


@pytest.mark.parametrize("stage", ["similarity", "clustering"])
def test_cancel_stops_every_stage_within_a_second(stage):
    # 1024 bins of a 64^3 phantom: similarity and affinity propagation each take seconds here.
    values = head_phantom(64, seed=1).values
    assert cancel_at(stage, values, {"n_bins": 1024}) < 1.0
