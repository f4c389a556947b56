"""Volumes read lazily (Zarr, OME-Zarr, TIFF stacks, raw NRRD / MetaImage) give the values and geometry of the
in-memory readers, ``isosimtf`` designs them out of core exactly as it designs the same volume in memory, and pictures
them from a preview (every s-th voxel) without writing a scene or segmentation that would hold only the preview."""

import json
from pathlib import Path

import numpy as np
import pytest
from volume_writers import write_volume

from IsoSimilarityTFLib import memory
from IsoSimilarityTFLib.source import is_dask_array
from isosimtf import chunked_readers, cli, headers, run
from isosimtf.phantom import head_phantom
from isosimtf.read_errors import VolumeReadWarning
from isosimtf.rendering import slicer_core_available
from isosimtf.volume_io import Volume, read_volume

zarr = pytest.importorskip("zarr")
tifffile = pytest.importorskip("tifffile")

SHAPE = (11, 9, 13)  # (k, j, i)


def volume_values(dtype=np.int16) -> np.ndarray:
    rng = np.random.default_rng(3)
    grid = np.indices(SHAPE).astype(float)
    radius = np.sqrt(((grid - np.array([5, 4, 6])[:, None, None, None]) ** 2).sum(axis=0))
    return (np.where(radius < 3.5, 900, np.where(radius < 5, 200, -800)) + rng.normal(0, 20, SHAPE)).astype(dtype)


def geometry_volume(values: np.ndarray) -> Volume:
    rotation = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return Volume(values, (0.7, 1.3, 2.1), (-10.5, 20.25, 33.0), rotation, "v")


@pytest.mark.parametrize("name", ["v.nrrd", "v.nhdr", "v.mha", "v.mhd"])
@pytest.mark.parametrize("dtype", [np.int16, np.uint8, np.float32])
def test_raw_nrrd_and_metaimage_are_read_lazily_with_slicers_geometry(tmp_path: Path, name, dtype) -> None:
    volume = geometry_volume(volume_values(dtype))
    path = tmp_path / name
    write_volume(volume, path, compress=False)
    expected = read_volume(path)  # Slicer's reader
    lazy = chunked_readers.read_chunked(path)
    assert is_dask_array(lazy.values)
    np.testing.assert_array_equal(np.asarray(lazy.values), expected.values)
    np.testing.assert_allclose(lazy.ijk_to_ras(), expected.ijk_to_ras(), atol=1e-6)


def test_raw_chunks_are_whole_planes_of_bounded_size(tmp_path: Path, monkeypatch) -> None:
    values = volume_values()
    (tmp_path / "v.raw").write_bytes(values.astype(">i2").tobytes())
    monkeypatch.setattr(chunked_readers, "RAW_CHUNK_BYTES", 3 * SHAPE[1] * SHAPE[2] * 2)
    lazy = chunked_readers.raw_volume(tmp_path / "v.raw", SHAPE, np.dtype(">i2"))
    assert lazy.chunks == ((3, 3, 3, 2), (9,), (13,))
    np.testing.assert_array_equal(np.asarray(lazy), values)


@pytest.mark.parametrize(
    "key",
    [
        np.s_[:, :, :],
        np.s_[::3, ::3, ::3],
        np.s_[1:10:4, 2:9:2, 3:13:5],
        np.s_[4:5, 8:9, :],
        np.s_[2:2, :, :],
    ],
)
def test_raw_reads_give_the_voxels_asked_for(tmp_path: Path, monkeypatch, key) -> None:
    """Whole chunks, and a strided read folded into each chunk's read: only the planes kept are read."""
    values = volume_values()
    (tmp_path / "v.raw").write_bytes(b"head" + values.astype(">i2").tobytes())
    monkeypatch.setattr(chunked_readers, "RAW_CHUNK_BYTES", 3 * SHAPE[1] * SHAPE[2] * 2)
    lazy = chunked_readers.raw_volume(tmp_path / "v.raw", SHAPE, np.dtype(">i2"), offset=4)
    np.testing.assert_array_equal(lazy[key].compute(), values[key])


def test_a_missing_or_truncated_raw_file_is_a_read_error(tmp_path: Path) -> None:
    header = "NRRD0004\ntype: int16\ndimension: 3\nsizes: 13 9 11\nencoding: raw\nendian: little\ndata file: v.raw\n"
    (tmp_path / "v.nhdr").write_text(header)
    with pytest.raises(ValueError, match=r"data file '.*v\.raw' does not exist"):
        chunked_readers.read_chunked(tmp_path / "v.nhdr")
    data = volume_values().astype("<i2").tobytes()
    (tmp_path / "v.raw").write_bytes(data[:-1])
    with pytest.raises(ValueError, match=f"truncated: {len(data)} bytes of voxel data expected, {len(data) - 1} found"):
        chunked_readers.read_chunked(tmp_path / "v.nhdr")
    lazy = chunked_readers.raw_volume(tmp_path / "v.raw", SHAPE, np.dtype("<i2"))  # a file cut short after opening
    with pytest.raises(ValueError, match=r"ends before its last voxel \(truncated\)"):
        lazy.compute()


@pytest.mark.parametrize(
    ("shape", "limit", "step"),
    [
        ((11, 9, 13), 1 << 25, 1),
        ((1024, 1024, 1024), 1 << 25, 4),  # 256^3
        ((3200, 2048, 2048), 1 << 25, 8),  # 400 x 256 x 256 (7 would give 458 x 293 x 293, over 2^25)
        ((11, 9, 13), 100, 3),  # 4 x 3 x 5 = 60; step 2 gives 6 x 5 x 7 = 210
        ((5, 5, 5), 1, 5),
    ],
)
def test_the_preview_step_is_the_smallest_that_fits(shape, limit, step) -> None:
    assert chunked_readers.preview_step(shape, limit) == step


@pytest.mark.parametrize("name", ["v.nhdr", "v.mha", "v.zarr", "v.tif"])
def test_the_preview_is_every_step_th_voxel_in_the_same_space(tmp_path: Path, name) -> None:
    values = volume_values(np.uint16)
    volume = geometry_volume(values)
    path = tmp_path / name
    if name == "v.zarr":
        zarr.create_array(str(path), data=values, chunks=(4, 5, 13))
    elif name == "v.tif":
        tifffile.imwrite(path, values)
    else:
        write_volume(volume, path, compress=False)
    lazy = chunked_readers.read_chunked(path)
    preview = chunked_readers.read_preview(lazy, 3)
    assert isinstance(preview.values, np.ndarray)
    np.testing.assert_array_equal(preview.values, values[::3, ::3, ::3])
    assert preview.shape == (4, 3, 5)
    np.testing.assert_allclose(preview.spacing, np.asarray(lazy.spacing) * 3)
    # Preview voxel (i, j, k) lies where input voxel (3i, 3j, 3k) lies.
    corner = np.array([4, 2, 3, 1.0])
    np.testing.assert_allclose(preview.ijk_to_ras() @ corner, lazy.ijk_to_ras() @ (corner * [3, 3, 3, 1]), atol=1e-9)


def test_compressed_files_are_not_read_lazily(tmp_path: Path) -> None:
    write_volume(geometry_volume(volume_values()), tmp_path / "v.nrrd", compress=True)
    assert not headers.stored_voxels(tmp_path / "v.nrrd").raw
    assert not chunked_readers.reads_chunked(tmp_path / "v.nrrd", 256)
    with pytest.raises(ValueError, match="not stored raw"):
        chunked_readers.read_chunked(tmp_path / "v.nrrd")


def test_raw_files_are_read_lazily_only_when_too_large_for_memory(tmp_path: Path, monkeypatch) -> None:
    write_volume(geometry_volume(volume_values()), tmp_path / "v.nhdr", compress=False)
    assert not is_dask_array(read_volume(tmp_path / "v.nhdr").values)
    needed = memory.design_memory_bytes(SHAPE, 256) + 2 * np.prod(SHAPE)
    monkeypatch.setattr(chunked_readers, "available_memory_bytes", lambda: 2 * needed - 2)
    assert is_dask_array(read_volume(tmp_path / "v.nhdr").values)


def test_zarr_array_and_ome_zarr_level_0(tmp_path: Path) -> None:
    values = volume_values()
    zarr.create_array(str(tmp_path / "plain.zarr"), data=values, chunks=(4, 9, 13))
    lazy = read_volume(tmp_path / "plain.zarr")
    assert is_dask_array(lazy.values) and lazy.spacing == (1.0, 1.0, 1.0)
    np.testing.assert_array_equal(np.asarray(lazy.values), values)

    group = zarr.open_group(str(tmp_path / "image.ome.zarr"), mode="w")
    group.create_array("0", data=values[np.newaxis], chunks=(1, 4, 9, 13))
    group.create_array("1", data=values[np.newaxis, ::2, ::2, ::2])
    scale = [{"type": "scale", "scale": [1.0, 2.1, 1.3, 0.7]}]
    group.attrs["multiscales"] = [
        {
            "version": "0.4",
            "axes": [{"name": n} for n in "czyx"],
            "datasets": [{"path": "0", "coordinateTransformations": scale}, {"path": "1"}],
        }
    ]
    with pytest.warns(VolumeReadWarning, match="gives no unit for some of its axes: they are taken as millimetres"):
        ome = read_volume(tmp_path / "image.ome.zarr")
    np.testing.assert_array_equal(np.asarray(ome.values), values)
    assert ome.spacing == (0.7, 1.3, 2.1)


def test_tiff_file_and_folder_of_planes(tmp_path: Path) -> None:
    values = volume_values(np.uint16)
    tifffile.imwrite(tmp_path / "stack.tif", values)
    np.testing.assert_array_equal(np.asarray(read_volume(tmp_path / "stack.tif").values), values)
    (tmp_path / "planes").mkdir()
    for k, plane in enumerate(values):
        tifffile.imwrite(tmp_path / "planes" / f"z{k:03d}.tiff", plane)
    lazy = read_volume(tmp_path / "planes")
    assert is_dask_array(lazy.values)
    np.testing.assert_array_equal(np.asarray(lazy.values), values)


def _classes_json(outdir: Path) -> dict:
    data = json.loads((outdir / "classes.json").read_text())
    data.pop("timings_s")
    data.pop("written_stamps")  # modification times: the run's own, like its timings
    data.pop("input")
    return data


def test_isosimtf_designs_a_zarr_volume_as_the_same_volume_in_memory(tmp_path: Path, capsys) -> None:
    values = volume_values()
    np.save(tmp_path / "v.npy", values)
    zarr.create_array(str(tmp_path / "v.zarr"), data=values, chunks=(3, 5, 13))
    assert cli.main([str(tmp_path / "v.npy"), "-o", str(tmp_path / "memory"), "--no-render", "-q"]) == 0
    assert cli.main([str(tmp_path / "v.zarr"), "-o", str(tmp_path / "lazy"), "--no-render", "-q"]) == 0
    assert not capsys.readouterr().err
    assert _classes_json(tmp_path / "lazy") == _classes_json(tmp_path / "memory")
    info = json.loads((tmp_path / "lazy" / "classes.json").read_text())["input"]
    assert info["read_lazily"] and info["value_min"] is None and info["preview"] is None
    np.testing.assert_array_equal(
        np.load(tmp_path / "lazy" / "similarity.npy"), np.load(tmp_path / "memory" / "similarity.npy")
    )


def test_isosimtf_on_a_distributed_cluster(tmp_path: Path) -> None:
    """--scheduler: the chunks are read and quantized by a dask.distributed cluster (on loopback here), and the
    similarity pass runs there too, one part per worker thread, merged there."""
    distributed = pytest.importorskip("distributed")
    values = volume_values()
    zarr.create_array(str(tmp_path / "v.zarr"), data=values, chunks=(3, 5, 13))
    assert cli.main([str(tmp_path / "v.zarr"), "-o", str(tmp_path / "local"), "--no-render", "-q"]) == 0
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        argv = [str(tmp_path / "v.zarr"), "-o", str(tmp_path / "cluster"), "--no-render", "-q"]
        assert cli.main([*argv, "--scheduler", cluster.scheduler_address]) == 0
        distributed.default_client().close()  # the command's client; its process would end here
        ran = {str(entry[0]).split("-")[0] for entry in cluster.scheduler.transition_log}
        assert any("from-zarr" in key or "getitem" in key for key in ran), ran  # the chunks were read there
        assert {"isosimtf", "merge_counts"} <= ran, ran  # the parts were counted and merged there
    assert _classes_json(tmp_path / "cluster") == _classes_json(tmp_path / "local")


def test_unreachable_scheduler_is_a_usage_error(tmp_path: Path, capsys) -> None:
    pytest.importorskip("distributed")
    zarr.create_array(str(tmp_path / "v.zarr"), data=volume_values(), chunks=(3, 5, 13))
    status = cli.main([str(tmp_path / "v.zarr"), "-o", str(tmp_path / "out"), "--no-render", "--scheduler",
                       "tcp://127.0.0.1:9"])  # fmt: skip
    assert status == cli.EXIT_USAGE and "no dask scheduler answers" in capsys.readouterr().err


needs_slicer = pytest.mark.skipif(not slicer_core_available(), reason="slicer-core is not installed")

PREVIEW_SKIPPED = ("classes.seg.nrrd", "scene/scene.mrml")


def _micro_ct(tmp_path: Path, monkeypatch) -> Path:
    """The 32^3 head phantom as a raw NRRD that isosimtf reads lazily (as if larger than half the memory)."""
    phantom = head_phantom(32, seed=2)
    path = tmp_path / "micro-ct.nhdr"
    write_volume(Volume(phantom.values, (0.25, 0.25, 0.5), (1.0, -2.0, 3.0), name="micro-ct"), path, compress=False)
    monkeypatch.setattr(chunked_readers, "available_memory_bytes", lambda: 1 << 16)
    return path


@needs_slicer
def test_a_lazy_volume_is_pictured_from_a_preview(tmp_path: Path, monkeypatch, capfd) -> None:
    """Pictures from every 2nd voxel, said in one warning that also names the files skipped; the stage counter of a
    rendered run from its first line; the scene and segmentation of a previous run into the folder are removed."""
    path = _micro_ct(tmp_path, monkeypatch)
    outdir = tmp_path / "out"
    in_memory = tmp_path / "micro-ct.npy"
    np.save(in_memory, head_phantom(32, seed=2).values)
    assert cli.main([str(in_memory), "-o", str(outdir), "--size", "64", "-q"]) == 0
    assert all((outdir / name).is_file() for name in PREVIEW_SKIPPED)  # an earlier run's, in memory
    capfd.readouterr()

    monkeypatch.setattr(chunked_readers, "PREVIEW_VOXELS", 16**3)
    assert cli.main([str(path), "-o", str(outdir), "--size", "64"]) == 0
    err = capfd.readouterr().err
    lines = err.splitlines()
    stages = [line for line in lines if line.startswith("[")]
    assert [line.split()[0] for line in stages] == [f"[{i}/{len(run.STAGES)}]" for i in range(1, len(run.STAGES) + 1)]
    assert [line.split()[1] for line in stages] == list(run.STAGES)
    assert "from every 2nd voxel" in stages[-1]
    preview_lines = [line for line in lines if "preview" in line]
    assert len(preview_lines) == 1, err
    assert "every 2nd voxel along each axis (16 x 16 x 16 voxels of 0.5 x 0.5 x 1 mm)" in preview_lines[0]
    assert all(name.split("/")[0] in preview_lines[0] for name in PREVIEW_SKIPPED)
    removed = [line for line in lines if "of a previous run that this run did not write" in line]
    assert len(removed) == 1 and all(name in removed[0] for name in PREVIEW_SKIPPED)  # none of another run left

    document = json.loads((outdir / "classes.json").read_text())
    assert document["input"]["read_lazily"] and document["input"]["shape"] == [32, 32, 32]
    preview = document["input"]["preview"]
    assert {k: preview[k] for k in ("step", "shape", "dimensions", "spacing")} == {
        "step": 2, "shape": [16, 16, 16], "dimensions": [16, 16, 16], "spacing": [0.5, 0.5, 1.0]
    }  # fmt: skip
    assert preview["read_s"] >= 0
    assert {"render_png", "classes_png"} <= set(document["outputs"])
    for name in ("render.png", "classes.png"):
        assert name in document["written"] and (outdir / name).stat().st_size > 0
    for name in PREVIEW_SKIPPED:
        assert name not in document["written"] and not (outdir / name).exists()
    assert document["timings_s"]["render"] > 0


@needs_slicer
def test_a_lazy_volume_small_enough_is_pictured_whole(tmp_path: Path, monkeypatch, capfd) -> None:
    """A preview of step 1 is the volume itself: every output is written, and no warning is given."""
    path = _micro_ct(tmp_path, monkeypatch)
    assert cli.main([str(path), "-o", str(tmp_path / "out"), "--size", "64", "-q"]) == 0
    assert not capfd.readouterr().err
    document = json.loads((tmp_path / "out" / "classes.json").read_text())
    assert document["input"]["read_lazily"] and document["input"]["preview"]["step"] == 1
    for name in ("render.png", "classes.png", *PREVIEW_SKIPPED):
        assert (tmp_path / "out" / name).is_file(), name


def test_tiff_planes_are_stacked_in_natural_order(tmp_path: Path) -> None:
    """plane_0 .. plane_11 were stacked in text order (0, 1, 10, 11, 2, ...): a scrambled volume (issue 18, item 8)."""
    values = head_phantom(16, seed=0).values[:12]
    folder = tmp_path / "planes"
    folder.mkdir()
    for k, plane in enumerate(values):
        tifffile.imwrite(folder / f"plane_{k}.tif", plane)
    np.testing.assert_array_equal(np.asarray(read_volume(folder).values), values)


def test_tiff_planes_of_different_sizes_are_refused_in_one_line(tmp_path: Path) -> None:
    folder = tmp_path / "planes"
    folder.mkdir()
    values = head_phantom(16, seed=0).values
    for k in range(3):
        tifffile.imwrite(folder / f"p{k}.tif", values[k, : 16 - (k == 2)])
    with pytest.raises(ValueError, match=r"TIFF planes differ: p0\.tif is \(16, 16\) of int16, p2\.tif is \(15, 16\)"):
        read_volume(folder)


def test_ome_zarr_micrometres_become_millimetres(tmp_path: Path) -> None:
    values = volume_values()
    group = zarr.open_group(str(tmp_path / "um.ome.zarr"), mode="w")
    group.create_array("0", data=values, chunks=(4, 9, 13))
    axes = [{"name": n, "type": "space", "unit": "micrometer"} for n in "zyx"]
    scale = [{"type": "scale", "scale": [2.0, 0.5, 0.25]}]
    group.attrs["multiscales"] = [
        {"version": "0.4", "axes": axes, "datasets": [{"path": "0", "coordinateTransformations": scale}]}
    ]
    messages = []
    volume = read_volume(tmp_path / "um.ome.zarr", warn=messages.append)
    np.testing.assert_allclose(volume.spacing, (0.00025, 0.0005, 0.002))
    assert len(messages) == 1 and "converted to mm" in messages[0]
    axes[0]["unit"] = "parsec"
    group.attrs["multiscales"] = [
        {"version": "0.4", "axes": axes, "datasets": [{"path": "0", "coordinateTransformations": scale}]}
    ]
    with pytest.raises(ValueError, match="its axes are in 'parsec', a unit not known here"):
        read_volume(tmp_path / "um.ome.zarr")


@pytest.mark.parametrize("step", [1, 2, 3, 7])
def test_the_preview_kept_from_the_designs_read_is_the_one_read_apart(tmp_path: Path, step) -> None:
    """The render preview of a volume read lazily comes from the design's first read (its value_tap): the same
    voxels, the same space, as a read of its own."""
    import dask.array as da

    from IsoSimilarityTFLib import design_transfer_function

    values = head_phantom(24, seed=1).values[:, :20, :22]
    lazy = Volume(da.from_array(values, chunks=(5, 20, 22)), (0.5, 0.6, 1.0), (1.0, 2.0, 3.0), np.eye(3), "v")
    tap = chunked_readers.PreviewTap(lazy.shape, step)
    assert not tap.complete
    design_transfer_function(lazy.values, lazy.spacing, value_tap=tap, n_bins=32)
    assert tap.complete
    kept, read = tap.preview(lazy), chunked_readers.read_preview(lazy, step)
    np.testing.assert_array_equal(kept.values, read.values)
    assert (kept.spacing, kept.origin, kept.name) == (read.spacing, read.origin, read.name)
    np.testing.assert_array_equal(kept.directions, read.directions)
