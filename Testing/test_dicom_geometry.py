"""DICOM series whose slices are not one regular volume are refused with the reason, as Slicer's DICOM module warns
(issue 18, item 5): before, missing slices were averaged into a wrong spacing, uneven gaps shifted the origin and
tilted slices under the same Series Instance UID were silently dropped. Slices built from the phantom."""

from pathlib import Path

import numpy as np
import pytest
from test_volume_io import _rotation, _write_dicom_slice

from isosimtf.phantom import head_phantom
from isosimtf.volume_io import VolumeReadError, read_volume

AXIAL = np.array([1.0, 0, 0, 0, 1, 0])


def _slices(folder: Path, z_positions, orientations=None, sizes=None) -> np.ndarray:
    """Write one slice of the phantom per z position (mm, along the normal); return the (K, J, I) HU written."""
    folder.mkdir(parents=True, exist_ok=True)
    phantom = head_phantom(24, seed=0).values
    written = []
    for k, z in enumerate(z_positions):
        orientation = AXIAL if orientations is None else orientations[k]
        rows, columns = (12, 14) if sizes is None else sizes[k]
        pixels = phantom[4 + k % 16, 5 : 5 + rows, 4 : 4 + columns].astype(np.int16)
        normal = np.cross(orientation[:3], orientation[3:])
        _write_dicom_slice(folder / f"IM{k:03d}", pixels + 1024, z * normal, orientation, (0.5, 0.5), k + 1, -1024.0)
        written.append(pixels)
    return np.array(written) if sizes is None else np.empty(0)


def _error(path: Path) -> str:
    with pytest.raises(VolumeReadError) as info:
        read_volume(path)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_a_regular_series_reads_with_its_spacing(tmp_path: Path) -> None:
    hu = _slices(tmp_path / "s", [0.0, 1.25, 2.5, 3.75, 5.0, 6.25])
    volume = read_volume(tmp_path / "s")
    np.testing.assert_array_equal(volume.values, hu)
    np.testing.assert_allclose(volume.spacing, (0.5, 0.5, 1.25), atol=1e-6)


def test_missing_slices_are_refused_not_averaged(tmp_path: Path) -> None:
    z = [k * 1.0 for k in range(24) if not 8 <= k < 18]  # 10 slices missing: Slicer's reader gave 1.78 mm
    _slices(tmp_path / "s", z)
    message = _error(tmp_path / "s")
    assert "not equally spaced (about 10 missing slice(s): gaps of 1 mm, but 11 mm between IM007 and IM008" in message


def test_uneven_gaps_are_refused(tmp_path: Path) -> None:
    _slices(tmp_path / "s", [0.0, 1.0, 2.0, 3.4, 4.0, 5.0, 6.0])
    assert "not equally spaced (uneven slice gaps" in _error(tmp_path / "s")


def test_tilted_slices_in_the_series_are_refused(tmp_path: Path) -> None:
    tilted = np.concatenate([_rotation(20.0, 0)[:, 0], _rotation(20.0, 0)[:, 1]])
    orientations = [AXIAL if k % 2 == 0 else tilted for k in range(8)]
    _slices(tmp_path / "s", [float(k) for k in range(8)], orientations)
    message = _error(tmp_path / "s")
    assert "4 of its 8 slices (e.g. IM001) have another Image Orientation than IM000" in message


def test_slices_of_different_sizes_are_refused(tmp_path: Path) -> None:
    _slices(tmp_path / "s", [0.0, 1.0, 2.0, 3.0], sizes=[(12, 14), (12, 14), (10, 14), (12, 14)])
    assert "its slices have different sizes (10 x 14, 12 x 14 pixels)" in _error(tmp_path / "s")


def test_a_folder_of_series_folders_names_a_subfolder(tmp_path: Path) -> None:
    _slices(tmp_path / "study" / "series1", [0.0, 1.0, 2.0])
    message = _error(tmp_path / "study")
    assert "no DICOM file itself but 1 subfolder(s) (e.g. 'series1'): give the folder of one series" in message
    assert read_volume(tmp_path / "study" / "series1").shape == (3, 12, 14)
