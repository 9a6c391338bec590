"""``make bench``: run every benchmark module and print its tables (no pass/fail on timings).

Each ``bench/bench_*.py`` exposes ``main()`` that prints markdown tables with the thesis's or the
issue's figure beside ours. Pass module names (e.g. ``protocol``) to run a subset; a name that is no
benchmark is refused (exit 2). A benchmark that raises (or exits) is reported as failed, the others run on,
the last line names the failed ones and the exit status is 1.
"""

import importlib
import pkgutil
import sys
import time

import bench


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    mods = sorted(m.name for m in pkgutil.iter_modules(bench.__path__) if m.name.startswith("bench_"))
    names = [m[len("bench_"):] for m in mods]
    unknown = [a for a in argv if a not in names]
    if unknown:
        print("bench.run: error: no benchmark named %s; the benchmarks: %s"
              % (", ".join(unknown), " ".join(names)), file=sys.stderr)
        return 2
    if argv:
        mods = [m for m in mods if m[len("bench_"):] in argv]
    failed = []
    for name in mods:
        print("\n## %s\n" % name[len("bench_"):], flush=True)
        t0 = time.perf_counter()
        try:
            importlib.import_module("bench." + name).main()
        except (Exception, SystemExit) as exc:  # a broken benchmark must not hide the others
            failed.append(name[len("bench_"):])
            print("benchmark %s failed: %r" % (name, exc), flush=True)
        print("\n(%s took %.1f s)" % (name, time.perf_counter() - t0), flush=True)
    if failed:
        print("\nbenchmarks FAILED: %s (%d of %d)" % (", ".join(failed), len(failed), len(mods)), flush=True)
    return 1 if failed else 0


def standalone(bench_main, argv=None):
    """``python -m bench.bench_X``: a benchmark takes no arguments; one given is refused (exit 2), not ignored
    (``--runs 4`` ran the full 20 seeds)."""
    argv = sys.argv[1:] if argv is None else argv
    if argv:
        print("%s: error: a benchmark takes no arguments, got %s (python -m bench.run NAME ... runs some)"
              % (bench_main.__module__, " ".join(argv)), file=sys.stderr)
        sys.exit(2)
    bench_main()


if __name__ == "__main__":
    sys.exit(main())
