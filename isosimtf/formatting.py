"""Numbers and colours as text, the same in the console summary and in the picture labels."""

import math


def value_decimals(value_range: tuple[float, float], n_bins: int) -> int:
    """Decimals that tell neighbouring bin edges apart (0 for HU over 256 bins)."""
    width = (value_range[1] - value_range[0]) / max(n_bins, 1)
    if not width > 0 or not math.isfinite(width):
        return 0
    return int(min(6, max(0, math.ceil(-math.log10(width)))))


def format_ranges(ranges: list, decimals: int, limit: int = 3) -> str:
    """``"-100 .. 250, 300 .. 310"`` for a class's value ranges; past ``limit`` runs, ``"+N more"``."""
    parts = [f"{lo:.{decimals}f} .. {hi:.{decimals}f}" for lo, hi in ranges[:limit]]
    if len(ranges) > limit:
        parts.append(f"+{len(ranges) - limit} more")
    return ", ".join(parts)


def format_percent(fraction: float, decimals: int = 1) -> str:
    """A voxel share in percent; ``"<0.1"`` rather than ``"0.0"`` for a small but non-zero share."""
    percent = 100.0 * float(fraction)
    if 0.0 < percent < 10.0**-decimals:
        return f"<{10.0**-decimals:.{decimals}f}"
    return f"{percent:.{decimals}f}"


def color_hex(color) -> str:
    """``#rrggbb`` of an RGB colour in 0..1."""
    return "#" + "".join(f"{int(round(255 * min(max(float(c), 0.0), 1.0))):02x}" for c in color)


def format_bytes(count: float) -> str:
    """``"512 bytes"``, ``"3.2 KiB"``, ``"41 MiB"``, ``"1.5 GiB"``: never ``"0 MiB"`` for a small size."""
    for unit, scale in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if count >= scale:
            value = count / scale
            return f"{value:.1f} {unit}" if value < 10 else f"{value:.0f} {unit}"
    return f"{int(count)} bytes"
