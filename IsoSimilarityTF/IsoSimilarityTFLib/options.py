"""The one table of design options: names, defaults, allowed values and help, for every front end.

:func:`~.design.design_transfer_function` validates its keywords with :func:`check_options`, the ``isosimtf``
command builds its arguments from :data:`OPTIONS`, and the Slicer module's parameter node takes its ranges and
choices from it, so an option is declared once.
"""

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

from .errors import OptionError

# Every word list and bound of the options. The modules that use them import them from here, and this module imports
# none of them: the table is a leaf of the library, read by every front end without importing the engine.
CROSSINGS = ("inclusive", "strict")
NORMALIZATIONS = ("thesis", "ma-entezari")
PREFERENCES = ("median", "minimum")
#: What the design does when affinity propagation does not converge (see design_transfer_function).
UNCONVERGED_RULES = ("raise-damping", "error", "keep")
BACKGROUND_RULES = ("largest", "lowest", "none")
KINDS = ("ct", "mr", "8bit")
COLOR_SCHEMES = ("ramp", "distinct")
GRADIENT_OPACITY = ("off", "auto")
#: The looks of the gallery, in the order it offers them after the first click (see :mod:`.gallery`).
LOOK_NAMES = (
    "dense-parts",
    "densest-parts",
    "outer-surface",
    "see-through",
    "thin-structures",
    "all-tissues",
    "classes",
)
MAX_BINS = 4096


@dataclass(frozen=True)
class Option:
    """One keyword of :func:`~.design.design_transfer_function`.

    Attributes:
        name: the Python keyword.
        default: its default value.
        kind: ``"int"``, ``"float"``, ``"choice"`` (one of ``choices``, any letter case), ``"choice-or-int"`` /
            ``"choice-or-float"`` (one of ``choices`` or a number) or ``"range"`` (``(low, high)`` with low < high,
            in volume units).
        help: one line for ``--help`` and tooltips.
        flag: the command-line flag.
        choices: allowed words, for the choice kinds.
        minimum, maximum: inclusive bounds, for numbers.
        none_means: what ``None`` stands for, when ``None`` is allowed (``None`` is refused otherwise).
        metavar: placeholder in the command-line help.
    """

    name: str
    default: Any
    kind: str
    help: str
    flag: str
    choices: tuple[str, ...] = ()
    minimum: Optional[float] = None
    maximum: Optional[float] = None
    none_means: Optional[str] = None
    metavar: Optional[str] = field(default=None)

    def check(self, value: Any) -> Any:
        """Return ``value`` in its canonical type (int, float, str, tuple) or raise :class:`OptionError`."""
        if value is None:
            if self.none_means is None:
                raise OptionError(f"{self.name} must be given (None is not allowed)")
            return None
        if self.kind == "range":
            return self._check_range(value)
        if self.choices and isinstance(value, str):
            if value.lower() in self.choices:
                return value.lower()
            if self.kind == "choice":
                raise OptionError(f"{self.name} must be one of {', '.join(self.choices)}; got {value!r}")
        if self.kind == "choice":
            raise OptionError(f"{self.name} must be one of {', '.join(self.choices)}; got {value!r}")
        return self._check_number(value)

    def _check_number(self, value: Any) -> Any:
        whole = self.kind in ("int", "choice-or-int")
        what = "an integer" if whole else "a number"
        if self.choices:
            what = f"{', '.join(self.choices)} or {what}"
        integral = isinstance(value, numbers.Integral) and not isinstance(value, bool)
        real = isinstance(value, numbers.Real) and not isinstance(value, bool)
        if not (integral if whole else real) or not math.isfinite(value):
            raise OptionError(f"{self.name} must be {what}{self._bounds_text()}; got {value!r}")
        value = int(value) if whole else float(value)
        if (self.minimum is not None and value < self.minimum) or (self.maximum is not None and value > self.maximum):
            raise OptionError(f"{self.name} must be {what}{self._bounds_text()}; got {value!r}")
        return value

    def _check_range(self, value: Any) -> tuple[float, float]:
        try:
            low, high = (float(v) for v in value)
        except (TypeError, ValueError):
            raise OptionError(f"{self.name} must be two numbers (low, high); got {value!r}") from None
        if not (math.isfinite(low) and math.isfinite(high) and low < high):
            raise OptionError(f"{self.name} must be two finite numbers with low < high; got {value!r}")
        return low, high

    def _bounds_text(self) -> str:
        if self.minimum is not None and self.maximum is not None:
            return f" from {self.minimum:g} to {self.maximum:g}"
        if self.minimum is not None:
            return f" of at least {self.minimum:g}"
        return ""


OPTIONS: dict[str, Option] = {
    option.name: option
    for option in (
        Option("n_bins", 256, "int", "number of isovalues (bins)", "--bins", minimum=2, maximum=MAX_BINS,
               metavar="N"),
        Option("value_range", None, "range", "value range quantized, in volume units", "--range",
               none_means="the volume's minimum and maximum", metavar=("LOW", "HIGH")),
        Option("crossing", "inclusive", "choice", "when an isovalue crosses a cell: min <= v <= max (inclusive, "
               "thesis) or min < v < max (strict, the method authors' code)", "--crossing", choices=CROSSINGS),
        Option("normalization", "thesis", "choice", "per-level similarity: overlap / max(n_i, n_j) (thesis) or "
               "overlap / n_j then the minimum with the transpose (ma-entezari)", "--normalization",
               choices=NORMALIZATIONS),
        Option("levels", None, "int", "keep only the K coarsest octree levels", "--levels", minimum=1, maximum=32,
               none_means="all levels", metavar="K"),
        Option("preference", "median", "choice-or-float", "affinity propagation preference (lower: fewer classes)",
               "--preference", choices=PREFERENCES, metavar="median|minimum|NUMBER"),
        Option("damping", 0.5, "float", "affinity propagation damping", "--damping", minimum=0.5, maximum=0.99),
        Option("max_iter", 200, "int", "affinity propagation iteration limit", "--max-iter", minimum=1,
               maximum=100_000, metavar="N"),
        Option("convergence_iter", 15, "int", "stable iterations that mean convergence", "--convergence-iter",
               minimum=1, maximum=10_000, metavar="N"),
        Option("max_classes", 15, "int", "classes shown besides the background, whole tissues, largest first; the "
               "densest real tissue, and every tissue between two shown ones where a shown tissue fills the object, "
               "are shown even past it (0: that tissue alone)", "--max-classes", minimum=0,
               maximum=1000, metavar="N"),
        Option("background", "largest", "choice", "which class is the hidden background", "--background",
               choices=BACKGROUND_RULES),
        Option("unconverged", "raise-damping", "choice", "what to do when affinity propagation does not converge",
               "--unconverged", choices=UNCONVERGED_RULES),
        Option("tissues", "auto", "choice-or-int", "tissues the classes are grouped into: auto, all (one per class, "
               "the thesis) or a count", "--tissues", choices=("auto", "all"), minimum=1, maximum=MAX_BINS,
               metavar="auto|all|N"),
        Option("colors", "ramp", "choice", "tissue colours: an intensity-ordered ramp (dark red, tan, ivory, white) "
               "or a distinct qualitative palette", "--colors", choices=COLOR_SCHEMES),
        Option("modality", None, "choice", "kind of volume (a hint; ct shows its dense tail)", "--modality",
               choices=KINDS, none_means="detected from the histogram, whatever the units"),
        Option("gradient_opacity", "off", "choice", "gradient opacity: off (constant, as Slicer's presets) or auto "
               "(homogeneous insides fade, boundaries stay)", "--gradient-opacity", choices=GRADIENT_OPACITY),
    )
}  # fmt: skip

DEFAULT_OPTIONS: dict[str, Any] = {name: option.default for name, option in OPTIONS.items()}


def check_options(options: Mapping[str, Any]) -> dict[str, Any]:
    """Every option, defaults filled in, each value checked against its table entry.

    Raises:
        TypeError: an unknown option name. OptionError: a value outside its entry.
    """
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise TypeError(f"unknown option(s): {', '.join(unknown)}; known: {', '.join(OPTIONS)}")
    checked = {name: option.check(options.get(name, option.default)) for name, option in OPTIONS.items()}
    check_together(checked)
    return checked


def check_together(options: Mapping[str, Any], name: Callable[[str], str] = str) -> None:
    """The checks that take two options, on options each already checked (missing ones at their default);
    ``name(option)`` words the message (the command line gives its flags).

    Raises:
        OptionError: a ``convergence_iter`` chosen above ``max_iter`` (affinity propagation could never count that
            many stable iterations; the default with a small ``max_iter`` is a run that stops early, which the
            clustering reports itself); a number of ``tissues`` above ``n_bins`` (at most one tissue per bin).
    """
    max_iter = options.get("max_iter", DEFAULT_OPTIONS["max_iter"])
    convergence_iter = options.get("convergence_iter", DEFAULT_OPTIONS["convergence_iter"])
    chosen = convergence_iter != DEFAULT_OPTIONS["convergence_iter"]
    if chosen and max_iter is not None and convergence_iter is not None and convergence_iter > max_iter:
        raise OptionError(
            f"{name('convergence_iter')} {convergence_iter} is more than {name('max_iter')} {max_iter}: affinity "
            f"propagation could never count that many stable iterations; lower {name('convergence_iter')} or raise "
            f"{name('max_iter')}"
        )
    tissues, n_bins = options.get("tissues"), options.get("n_bins", DEFAULT_OPTIONS["n_bins"])
    if isinstance(tissues, int) and not isinstance(tissues, bool) and n_bins is not None and tissues > n_bins:
        # The classes (at most one per bin) are known only after the design; more tissues than bins never fit.
        raise OptionError(
            f"{name('tissues')} {tissues} is more than {name('n_bins')} {n_bins}: there can be at most one tissue "
            "per bin"
        )
