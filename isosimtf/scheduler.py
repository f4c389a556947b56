"""Where a volume read lazily is computed: dask's local threaded scheduler, or a ``dask.distributed`` cluster.

Only the reading and quantizing of the chunks run on the scheduler (each row of chunks is gathered into the
``isosimtf`` process, which folds it into the octree); an in-memory volume never touches dask.
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
