"""The command line writes the classes as Slicer's segmentation file (classes.seg.nrrd), read back here with Slicer's
own storage node: one segment per shown class, named and coloured as in classes.json, with the class's voxels."""

import json
import re

import numpy as np
import pytest
from volume_writers import write_volume

from IsoSimilarityTFLib.classes import IsovalueClass
from IsoSimilarityTFLib.mrml import segment_name
from IsoSimilarityTFLib.quantize import quantize
from isosimtf import cli
from isosimtf.phantom import head_phantom
from isosimtf.rendering import slicer_core_available
from isosimtf.volume_io import Volume


@pytest.mark.skipif(not slicer_core_available(), reason="slicer-core is not installed")
def test_cli_writes_classes_seg_nrrd(tmp_path):
    from vtkmodules.util import numpy_support

    from isosimtf.rendering import HeadlessSlicer

    phantom = head_phantom(32, seed=3)
    source = tmp_path / "head.nrrd"
    write_volume(Volume(phantom.values, (6.0, 6.0, 6.0), (0.0, 0.0, 0.0), np.eye(3), "head"), source)
    outdir = tmp_path / "out"
    assert cli.main([str(source), "-o", str(outdir), "--size", "64", "--quiet"]) == 0
    document = json.loads((outdir / "classes.json").read_text(encoding="utf-8"))
    assert document["outputs"]["segmentation"] == "classes.seg.nrrd"
    shown = [c for c in document["classes"] if c["visible"]]
    with HeadlessSlicer(size=(32, 32)) as headless:
        node = headless.scene.AddNewNodeByClass("vtkMRMLSegmentationNode")
        reader = headless.scene.AddNewNodeByClass("vtkMRMLSegmentationStorageNode")
        reader.SetFileName(str(outdir / "classes.seg.nrrd"))
        assert reader.ReadData(node)
        segmentation = node.GetSegmentation()
        assert segmentation.GetNumberOfSegments() == len(shown) > 1
        labels = np.asarray(document["labels"])[
            quantize(phantom.values, document["n_bins"], document["value_range"]).bins
        ]
        for index, entry in enumerate(shown):
            segment = segmentation.GetNthSegment(index)
            assert segment.GetName() == segment_name(IsovalueClass.from_dict(entry))
            assert segment.GetColor() == pytest.approx(entry["color"], abs=1e-6)
            image = segment.GetRepresentation("Binary labelmap")
            scalars = numpy_support.vtk_to_numpy(image.GetPointData().GetScalars())
            assert np.count_nonzero(scalars == segment.GetLabelValue()) == entry["voxels"]
            assert np.count_nonzero(labels == entry["id"]) == entry["voxels"]


@pytest.mark.skipif(not slicer_core_available(), reason="slicer-core is not installed")
def test_cli_logs_no_vtk_message(tmp_path):
    """The whole run, segmentation export included, writes only its own lines to stderr: no VTK or MRML log line
    (such as "vtkMRMLSubjectHierarchyNode::GetSubjectHierarchyNode: Invalid scene given", which detaching a
    Segmentations module logic from the scene used to log)."""
    import subprocess
    import sys

    argv = [sys.executable, "-m", "isosimtf", "phantom", "-o", str(tmp_path / "out"), "--phantom-size", "32"]
    result = subprocess.run([*argv, "--size", "64"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "out" / "classes.seg.nrrd").is_file()
    foreign = [line for line in result.stderr.splitlines() if not re.match(r"\[\d+/\d+\] ", line)]
    assert not foreign, "\n".join(foreign)
    assert not re.search(r"\bvtk[A-Z]|WARN\||ERR\|", result.stderr)
