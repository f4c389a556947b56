"""``isosimtf``: the command-line application of IsoSimilarityTF.

It reads a volume (:mod:`.volume_io` through Slicer's own readers in :mod:`.slicer_readers`, :mod:`.inputs`, or the
built-in :mod:`.phantom`), designs its transfer function with the engine (``IsoSimilarityTFLib``, the library the
Slicer extension ships), and writes an output folder (:mod:`.output_folder`: only our own files change) with data
files and pictures rendered by Slicer's own volume rendering, headless (:mod:`.outputs`, :mod:`.figures`,
:mod:`.rendering`). :mod:`.cli` parses the command line, :mod:`.run` runs it, :mod:`.console` prints.
"""

from IsoSimilarityTFLib import __version__

__all__ = ["__version__"]
