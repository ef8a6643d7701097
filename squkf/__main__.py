"""squkf's command line: ``python -m squkf precompile`` compiles every kernel into numba's cache.

It prints :func:`squkf.precompile`'s summary and exits 0, or 1 when there is
no cache to keep the kernels in (they were compiled in memory only, see
:ref:`first use <first-use>`).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from .first_use import precompile


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; the exit status."""
    parser = argparse.ArgumentParser(prog="python -m squkf", description="squkf's command line.")
    commands = parser.add_subparsers(dest="command", required=True)
    commands.add_parser(
        "precompile",
        help="compile every kernel into numba's cache (for a container image or CI)",
        description="Compile every kernel any public route can call into numba's cache.",
    )
    parser.parse_args(argv)
    done = precompile()
    print(done)
    if done.cache_dir is None:
        print(
            "squkf: the kernels were compiled in memory only (no writable cache location); "
            "set NUMBA_CACHE_DIR to a writable directory and run again",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
