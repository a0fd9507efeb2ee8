"""python -m itg_vision.bench {speed,accuracy,noise,itg-plus} [options]"""

from __future__ import annotations

import sys

NAMES = ("speed", "accuracy", "noise", "itg-plus")
USAGE = ("usage: python -m itg_vision.bench {speed,accuracy,noise,itg-plus} [options]  "
         "(--help after the name for its options)")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0
    if not argv:
        print(f"error: name a benchmark: {', '.join(NAMES)} ({USAGE.removeprefix('usage: ')})",
              file=sys.stderr)
        return 2
    name, rest = argv[0], argv[1:]
    if name == "speed":
        from .speed import main as run
    elif name == "accuracy":
        from .accuracy import main as run
    elif name == "noise":
        from .noise import main as run
    elif name == "itg-plus":
        from .itg_plus import main as run
    else:
        print(f"error: unknown benchmark {name!r} (choose {', '.join(NAMES)})", file=sys.stderr)
        return 2
    return run(rest)


if __name__ == "__main__":
    sys.exit(main())
