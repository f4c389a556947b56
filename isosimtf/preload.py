"""The run's slow import, done in a background thread while the volume is read and its similarity measured.

Importing scikit-learn takes about a second (most of it scipy.stats, which scikit-learn imports), yet affinity
propagation needs it only after the similarity. Reading the volume (zlib in 4 MiB calls), quantizing and the similarity
(numpy) release the GIL, so the import runs beside them on another core instead of after them. Only
:func:`isosimtf.run.run` starts it, after the arguments were parsed: ``--help`` and usage errors never pay for it.

slicer-core (another second) is not imported so: the stages that would run beside it (classes, tissues, writing) hold
the GIL, and sharing it made the tissue stage wait for the whole import (measured: 0.25 s became 2 s), a net loss.
"""

import importlib
import threading
from collections.abc import Sequence

from IsoSimilarityTFLib.errors import DependencyError

#: What ``cluster_isovalues`` imports for affinity propagation.
CLUSTERING_MODULE = "sklearn.cluster"
#: Top-level module -> (the distribution to install, what it is needed for), for the error message.
_PACKAGES = {"sklearn": ("scikit-learn", "affinity propagation")}


class BackgroundImports:
    """Import ``modules`` in order in one daemon thread, started at once; :meth:`wait` joins one of them.

    The thread is a daemon so that a run failing early (e.g. a missing input file) exits at once. A module nobody
    waits for needs no join: its importer blocks on Python's import lock until the thread is done with it, and a failed
    import fails again there with its usual error.
    """

    def __init__(self, modules: Sequence[str]) -> None:
        self._done = {name: threading.Event() for name in modules}
        self._errors: dict[str, Exception] = {}
        self._thread = threading.Thread(
            target=self._import_all, args=(tuple(modules),), name="isosimtf-imports", daemon=True
        )
        self._thread.start()

    def _import_all(self, modules: tuple[str, ...]) -> None:
        for name in modules:
            try:
                importlib.import_module(name)
            except Exception as error:  # reported by wait(), in the thread that needs the module
                self._errors[name] = error
            finally:
                self._done[name].set()

    def wait(self, module: str) -> None:
        """Block until ``module`` is imported.

        Raises:
            DependencyError: its import failed: one line naming the package, the reason and how to install it.
        """
        self._done[module].wait()
        error = self._errors.get(module)
        if error is not None:
            top = module.split(".")[0]
            package, purpose = _PACKAGES.get(top, (top, "this run"))
            reason = " ".join(str(error).split()) or type(error).__name__
            raise DependencyError(
                f"{package} cannot be imported ({reason}); it is needed for {purpose}: pip install {package}"
            ) from error
