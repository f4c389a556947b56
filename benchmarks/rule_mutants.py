"""Are the look's thresholds tested where they are used? A mutation run over every use of a ``LookRules`` field.

Usage::

    .venv/bin/python benchmarks/rule_mutants.py            # every use, both factors (about 20 min on 2 cores)
    .venv/bin/python benchmarks/rule_mutants.py --jobs 1 --factors 1.1

Tests written relative to ``RULES`` (``RULES.fog_separation - 0.01``) cannot see a change of the constant, so the
constant is not what is mutated: each *use* of a field in the library (an attribute ``rules.x``, ``RULES.x``,
``context.rules.x`` or ``self.rules.x`` in code, found with :mod:`ast`, so docstrings and comments are left out) is
replaced by ``(use * factor)``, one use at a time, in a copy of the repository, and the look's tests
(``TESTS``) are run on the copy. A mutant is *killed* when a test fails. A survivor is a use no test pins at its
boundary, or an equivalent mutant (a condition that only guards a change the next line makes anyway).

Outputs: a markdown table on stdout and ``benchmarks/results/rule-mutants.md``.
"""

from __future__ import annotations

import argparse
import ast
import datetime
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields
from pathlib import Path

from IsoSimilarityTFLib.roles import LookRules

REPOSITORY = Path(__file__).resolve().parent.parent
LIBRARY = Path("IsoSimilarityTF") / "IsoSimilarityTFLib"
RESULTS = REPOSITORY / "benchmarks" / "results" / "rule-mutants.md"
TESTS = ("Testing/test_look.py", "Testing/test_gallery.py", "Testing/test_design.py", "Testing/test_thumbnails.py")
FACTORS = (0.9, 1.1)
# The names a LookRules is read through: the module's default, the arguments and attributes holding one, and the
# gallery's descriptions (``lambda r: ...``).
RULE_HOLDERS = ("RULES", "rules", "r")


@dataclass(frozen=True)
class Use:
    """One use of a rule: ``path`` (relative to the repository), 1-based ``line``, 0-based byte columns in the line's
    UTF-8 (as :mod:`ast` counts), the source text, and whether the field is a pair (``see_through``: both ends are
    scaled)."""

    path: Path
    line: int
    start: int
    end: int
    text: str
    pair: bool


def _name_of(node: ast.expr) -> str | None:
    """``x`` for a name ``x`` or an attribute ``a.x``, else None."""
    if isinstance(node, ast.Name):
        return node.id
    return node.attr if isinstance(node, ast.Attribute) else None


def rule_uses(root: Path, pairs: dict[str, bool]) -> list[Use]:
    """Every attribute ``<holder>.<field>`` in the library's code (``holder`` one of :data:`RULE_HOLDERS`, or an
    attribute named so: ``context.rules``; ``pairs`` maps each field to whether it is a pair), in file and line
    order."""
    uses = []
    for path in sorted((root / LIBRARY).glob("*.py")):
        source = path.read_text(encoding="utf-8")
        lines = source.splitlines()
        for node in ast.walk(ast.parse(source)):
            if not (isinstance(node, ast.Attribute) and node.attr in pairs):
                continue
            if _name_of(node.value) in RULE_HOLDERS and node.lineno == node.end_lineno:
                text = lines[node.lineno - 1].encode()[node.col_offset : node.end_col_offset].decode()
                where = (path.relative_to(root), node.lineno, node.col_offset, node.end_col_offset)
                uses.append(Use(*where, text, pairs[node.attr]))
    return sorted(uses, key=lambda u: (str(u.path), u.line, u.start))


def run_mutant(copy: Path, use: Use, factor: float) -> tuple[bool, str]:
    """Whether a test fails with ``use`` scaled by ``factor`` in ``copy``; the file is restored afterwards."""
    path = copy / use.path
    original = path.read_bytes()
    lines = original.splitlines(keepends=True)
    row = lines[use.line - 1]
    scaled = f"tuple(v * {factor} for v in {use.text})" if use.pair else f"({use.text} * {factor})"
    lines[use.line - 1] = row[: use.start] + scaled.encode() + row[use.end :]
    path.write_bytes(b"".join(lines))
    try:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(copy / "IsoSimilarityTF"), str(copy)]))
        result = subprocess.run(
            [sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", *TESTS],
            cwd=copy, env=env, capture_output=True, text=True,
        )  # fmt: skip
    finally:
        path.write_bytes(original)
    summary = result.stdout.strip().splitlines()[-1] if result.stdout.strip() else result.stderr.strip()[-200:]
    return result.returncode != 0, summary


def _copy_repository(target: Path) -> Path:
    shutil.copytree(REPOSITORY, target, ignore=shutil.ignore_patterns(".git", ".venv", "results", "__pycache__"))
    return target


def markdown(rows: list[dict], factors: Sequence[float], seconds: float) -> str:
    killed = sum(r["killed"][f] for r in rows for f in factors)
    total = len(rows) * len(factors)
    out = [
        "# Rule mutants: is every use of a look threshold tested at its boundary?",
        "",
        f"Made by `benchmarks/rule_mutants.py` on {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC "
        f"({seconds:.0f} s). Each use of a `LookRules` field in the library, scaled by "
        f"{' and '.join(f'{f:g}' for f in factors)} one at a time; tests: {', '.join(f'`{t}`' for t in TESTS)}.",
        "",
        f"**{killed} of {total} mutants killed.** A survivor is a use no test pins at its boundary, or an "
        "equivalent mutant (a condition guarding a change that the next line makes anyway, or a search's start).",
        "",
        "| use | " + " | ".join(f"x{f:g}" for f in factors) + " |",
        "|---|" + "---|" * len(factors),
    ]
    for r in rows:
        cells = " | ".join("killed" if r["killed"][f] else "**survived**" for f in factors)
        out.append(f"| `{r['where']}` `{r['text']}` | {cells} |")
    return "\n".join(out) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--factors", type=float, nargs="+", default=list(FACTORS))
    parser.add_argument("--jobs", type=int, default=2, help="copies of the repository tested at once")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    defaults = LookRules()
    uses = rule_uses(REPOSITORY, {f.name: isinstance(getattr(defaults, f.name), tuple) for f in fields(LookRules)})
    tasks = [(use, factor) for use in uses for factor in args.factors]
    with tempfile.TemporaryDirectory() as scratch:
        copies = [_copy_repository(Path(scratch) / f"copy{j}") for j in range(max(args.jobs, 1))]
        chunks = [tasks[j :: len(copies)] for j in range(len(copies))]

        def run_chunk(j: int) -> list[tuple[Use, float, bool]]:
            done = []
            for use, factor in chunks[j]:
                killed, summary = run_mutant(copies[j], use, factor)
                print(f"{use.path.name}:{use.line} {use.text} x{factor:g}: {'killed' if killed else 'SURVIVED'} "
                      f"({summary})", file=sys.stderr, flush=True)  # fmt: skip
                done.append((use, factor, killed))
            return done

        with ThreadPoolExecutor(len(copies)) as pool:
            results = [item for chunk in pool.map(run_chunk, range(len(copies))) for item in chunk]
    rows = []
    for use in uses:
        killed = {factor: k for u, factor, k in results if u == use}
        rows.append({"where": f"{use.path.name}:{use.line}", "text": use.text, "killed": killed})
    text = markdown(rows, args.factors, time.perf_counter() - started)
    print(text)
    RESULTS.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
