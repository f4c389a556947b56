"""Every error type of IsoSimilarityTF, engine and command line, in one place.

Each derives from the built-in exception a caller would already catch (``ValueError`` for bad input,
``MemoryError``, ``RuntimeError``) and from :class:`IsoSimilarityTFError`, so ``except IsoSimilarityTFError`` catches
exactly what this project raises on purpose; its message is one line meant for the user.
"""


class IsoSimilarityTFError(Exception):
    """Base of the errors raised on purpose by IsoSimilarityTF."""


class OptionError(IsoSimilarityTFError, ValueError):
    """An option of the design has a value outside its table entry (see :mod:`.options`)."""


class InsufficientMemoryError(IsoSimilarityTFError, MemoryError):
    """The volume (or the number of bins) needs more memory than the machine has available."""


class ClusteringError(IsoSimilarityTFError, RuntimeError):
    """Affinity propagation could not give a usable grouping (no exemplar, or no convergence where it is required)."""


class TransferFunctionFileError(IsoSimilarityTFError, ValueError):
    """A volume property file that cannot be read."""


class VolumeReadError(IsoSimilarityTFError, ValueError):
    """A volume file could not be read; the message is one human-readable line naming the file."""


class UsageError(IsoSimilarityTFError, ValueError):
    """The command was asked something it cannot do (e.g. the output folder is a file)."""


class OutputError(IsoSimilarityTFError, RuntimeError):
    """The output folder or a file in it cannot be written."""


class RenderError(IsoSimilarityTFError, RuntimeError):
    """Rendering with headless Slicer failed (the other outputs are written)."""


class DependencyError(IsoSimilarityTFError, RuntimeError):
    """A package the run needs cannot be imported (the command line names it and how to install it)."""
