"""Where a volume read lazily is computed: dask's local threaded scheduler, or a ``dask.distributed`` cluster.

On the local scheduler the ``isosimtf`` process folds the chunks into the octree, one row of chunks at a time, while
dask's threads read and quantize the next one. On a cluster the similarity pass runs on the workers: one part of the
volume (whole rows of chunks along axis 0) per worker thread, each read and counted by its worker, the counts merged
on the workers (see ``IsoSimilarityTFLib.source`` and ``IsoSimilarityTFLib.stream``); only the merged counts come
back. An in-memory volume never touches dask.
"""

from typing import Any, Optional

from IsoSimilarityTFLib.errors import UsageError


def use_scheduler(address: Optional[str]) -> Optional[Any]:
    """Run the dask computations of this process on the cluster at ``address`` (e.g. ``tcp://10.0.0.5:8786``).

    ``None`` keeps dask's default, the local threaded scheduler. The cluster's workers read the input themselves: it
    must be on a file system they share with this process.

    Returns:
        The ``distributed.Client``, now dask's default (closed when the process ends), or None.

    Raises:
        UsageError: ``dask.distributed`` is not installed, or no scheduler answers at ``address``.
    """
    if address is None:
        return None
    try:
        from distributed import Client
    except ImportError:
        raise UsageError("--scheduler needs dask.distributed (pip install 'isosimilaritytf[outofcore]')") from None
    try:
        return Client(address, timeout=10, set_as_default=True)
    except (OSError, TimeoutError) as error:
        raise UsageError(f"no dask scheduler answers at {address} ({error})") from None
