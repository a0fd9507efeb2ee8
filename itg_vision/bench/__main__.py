"""python -m itg_vision.bench {speed,accuracy,noise,itg-plus} [options]"""

from __future__ import annotations

import importlib
import sys

from ..errors import exit_status

#: benchmark name -> its module in this package
MODULES = {"speed": "speed", "accuracy": "accuracy", "noise": "noise", "itg-plus": "itg_plus"}
NAMES = tuple(MODULES)
#: what each measures, for --help
ABOUT = {"speed": "cost of one decision (rule bases, compiled and in C, against PyBullet's IK) "
                  "and of the stereo loop per iteration",
         "accuracy": "the eye's centroid (px) and 3-D (mm) errors against the truth, and their "
                     "first-order prediction",
         "noise": "tracking under pixel noise, LED dropout, rig and model errors, every "
                  "controller side by side (results.csv, report.md, plots)",
         "itg-plus": "ITG+ against issue 13's targets (targets.md)"}
USAGE = (f"usage: python -m itg_vision.bench {{{','.join(NAMES)}}} [options]  "
         "(--help after the name for its options)")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("-h", "--help"):
        print(USAGE + "\n\n" + "\n".join(f"  {name:<9} {ABOUT[name]}" for name in NAMES))
        return 0
    if not argv:
        print(f"error: name a benchmark: {', '.join(NAMES)} ({USAGE.removeprefix('usage: ')})",
              file=sys.stderr)
        return 2
    name, rest = argv[0], argv[1:]
    if name not in MODULES:
        print(f"error: unknown benchmark {name!r} (choose {', '.join(NAMES)})", file=sys.stderr)
        return 2
    return importlib.import_module(f".{MODULES[name]}", __package__).main(rest)


if __name__ == "__main__":
    sys.exit(exit_status(main()))
