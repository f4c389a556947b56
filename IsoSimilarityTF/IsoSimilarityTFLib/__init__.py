"""IsoSimilarityTF: automatic transfer functions for direct volume rendering.

The pipeline, one module per step: :mod:`.source` (the volume, numpy or dask, read in slabs), :mod:`.survey` (one
pass for the value range's facts), :mod:`.value_range` (the default range's rules: padding and outliers left out),
:mod:`.quantize` (isovalue bins), :mod:`.cells` (unit cells and octree levels), :mod:`.stream` (one pass over the
bins for the levels' joint histograms, its :mod:`.taps` gathering what later steps need), :mod:`.similarity`
(hierarchical isovalue similarity from those tables),
:mod:`.clustering` (affinity propagation), :mod:`.classes` (ranked classes), :mod:`.tissues` (classes grouped into
tissues), :mod:`.roles`, :mod:`.look` and :mod:`.gallery` (the looks), :mod:`.transfer_function` (VTK objects and
Slicer files), tied together by :func:`design_transfer_function`, whose options are the table in :mod:`.options` and
whose errors are in :mod:`.errors`. :mod:`.mrml` puts a design into a Slicer scene, :mod:`.pictures` draws the
similarity matrix. Needs only numpy and VTK, which Slicer ships (affinity propagation is its own,
:mod:`.affinity_propagation`), and dask only when given a dask array; never Qt or the Slicer application, so it runs
headless.
"""

from .cells import octree_levels, unit_cell_intervals
from .classes import IsovalueClass
from .clustering import ClusteringResult, cluster_isovalues
from .design import Tissue, TransferFunctionDesign, design_transfer_function
from .errors import (
    ClusteringError,
    InsufficientMemoryError,
    IsoSimilarityTFError,
    OptionError,
    TransferFunctionFileError,
)
from .options import DEFAULT_OPTIONS, OPTIONS
from .quantize import Quantization, quantize
from .similarity import IsovalueSimilarity, isovalue_similarity, similarity_matrix
from .transfer_function import TransferFunctionPoints, read_vp, read_vp_json

__version__ = "0.1.0"

__all__ = [
    "DEFAULT_OPTIONS",
    "OPTIONS",
    "ClusteringError",
    "ClusteringResult",
    "InsufficientMemoryError",
    "IsoSimilarityTFError",
    "IsovalueClass",
    "IsovalueSimilarity",
    "OptionError",
    "Quantization",
    "Tissue",
    "TransferFunctionDesign",
    "TransferFunctionFileError",
    "TransferFunctionPoints",
    "cluster_isovalues",
    "design_transfer_function",
    "isovalue_similarity",
    "octree_levels",
    "quantize",
    "read_vp",
    "read_vp_json",
    "similarity_matrix",
    "unit_cell_intervals",
]
