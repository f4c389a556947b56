"""What the stream's one pass over the bins gathers besides the similarity's counts: a tap sees every slab.

The stream (:func:`~.stream.interval_histograms`) hands every slab of bins it reads, in order along
axis 0, to a :class:`SlabTap`, which counts the voxels per bin and keeps the planes later steps measure (the planes
the background rule samples, the look's preview), so that no later step reads the volume again. A tap knows no
policy: which planes to keep is its caller's.
"""

import numpy as np

from .quantize import count_bins


class SlabTap:
    """The voxel counts and kept planes of a volume of bins, gathered from its slabs.

    Called as ``tap(first, slab)`` with every slab of bins in order along axis 0 (slabs may overlap by a halo plane);
    taps of parts of the volume side by side are merged (:meth:`merge`). Memory: ``n_bins`` counts, the kept planes and
    the preview.
    """

    def __init__(
        self,
        shape: tuple[int, int, int],
        n_bins: int,
        start: int = 0,
        preview_steps: tuple[int, int, int] = (0, 0, 0),
        kept_planes: tuple[int, ...] = (),
    ) -> None:
        """
        Args:
            shape: the whole volume's shape.
            n_bins: bins counted.
            start: the first plane this tap sees (a part of the volume; the taps of the parts are then merged).
            preview_steps: ``(sz, sy, sx)``: every ``sz``-th plane is kept, strided by ``sy, sx``, for the look's
                preview (:func:`~.visibility.preview_steps`); 0 keeps none.
            kept_planes: planes kept whole (read with ``tap[plane]``).
        """
        self.preview_steps = tuple(int(s) for s in preview_steps)
        self.kept_planes = tuple(sorted({int(k) for k in kept_planes}))
        self.shape = tuple(int(n) for n in shape)
        self.voxel_counts = np.zeros(n_bins, dtype=np.int64)
        self._kept = set(self.kept_planes)
        self._planes: dict[int, np.ndarray] = {}
        self._preview: dict[int, np.ndarray] = {}
        self._next = int(start)  # first plane not yet counted

    def __call__(self, first: int, slab: np.ndarray) -> None:
        new = slab[self._next - first :]  # the planes of the halo were counted with the previous slab
        self.voxel_counts += count_bins(new, self.voxel_counts.size)
        sz, sy, sx = self.preview_steps
        for k in range(self._next, first + len(slab)):
            if k in self._kept:
                self._planes[k] = slab[k - first].copy()
            if sz and k % sz == 0:
                self._preview[k] = slab[k - first, ::sy, ::sx].copy()
        self._next = first + len(slab)

    def merge(self, other: "SlabTap") -> None:
        """Add what ``other`` gathered from planes this tap has not seen (another part of the volume)."""
        self.voxel_counts += other.voxel_counts
        self._planes.update(other._planes)
        self._preview.update(other._preview)

    def preview(self) -> np.ndarray:
        """The kept preview planes, ``(nz', ny', nx')``, in order (after the whole pass)."""
        return np.stack([self._preview[k] for k in sorted(self._preview)])

    def __getitem__(self, plane: int) -> np.ndarray:
        """A kept plane, shape ``(n1, n2)``."""
        return self._planes[plane]
