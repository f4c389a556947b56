"""A deadline for tests of inputs that could hang (a FIFO opened for reading, a run that never ends)."""

import contextlib
import signal
from collections.abc import Iterator


class Hung(Exception):
    """A run still going at its deadline: not an OSError (as TimeoutError is), which the code under test may catch
    around the very open that waits."""


@contextlib.contextmanager
def deadline(seconds: int) -> Iterator[None]:
    """Interrupt the block after ``seconds`` (a blocking open of a FIFO in the main thread returns to raise)."""

    def expire(signum, frame) -> None:
        raise Hung(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
