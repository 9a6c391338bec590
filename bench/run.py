"""``make bench``: run every benchmark module and print its tables (no pass/fail on timings).

Each ``bench/bench_*.py`` exposes ``main()`` that prints markdown tables with the thesis's or the
goal figure beside ours. Pass module names (e.g. ``protocol``) to run a subset; a name that is no
benchmark is refused (exit 2). A benchmark that raises (or exits) is reported as failed, the others run on,
the last line names the failed ones and the exit status is 1.

What it prints also goes to a dated file, ``docs/bench/<date>_<commit>.md``, headed by the date, the commit (and
whether the tree had changes), the machine (CPU model and count, OS) and its load before and after: a figure from
a shared machine is read against its load. The file is written as the run goes, so an interrupted run leaves the
tables it finished.
"""

import importlib
import os
import pkgutil
import platform
import subprocess
import sys
import time

import bench

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RECORDS = os.path.join(ROOT, "docs", "bench")


def _git(*args):
    try:
        return subprocess.run(["git"] + list(args), cwd=ROOT, capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def _cpu():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _load():
    try:
        return "%.2f %.2f %.2f" % os.getloadavg()
    except OSError:
        return "unknown"


class _Tee:
    """stdout and the record file at once."""

    def __init__(self, out, f):
        self.out, self.f = out, f

    def write(self, text):
        self.out.write(text)
        self.f.write(text)

    def flush(self):
        self.out.flush()
        self.f.flush()


def header(names):
    commit = _git("rev-parse", "--short", "HEAD") or "unknown"
    dirty = " (with uncommitted changes)" if _git("status", "--porcelain", "--untracked-files=no") else ""
    return ("# make bench, %s\n\n- commit: %s%s\n- machine: %s, %d CPUs, %s %s, Python %s\n- load (1, 5, 15 min) "
            "before: %s\n- benchmarks: %s\n" % (time.strftime("%Y-%m-%d %H:%M:%S %Z"), commit, dirty, _cpu(),
                                                  os.cpu_count() or 0, platform.system(), platform.release(),
                                                  platform.python_version(), _load(), " ".join(names)))


def names():
    """The benchmarks' names (bench/bench_NAME.py)."""
    return sorted(m.name[len("bench_"):] for m in pkgutil.iter_modules(bench.__path__) if m.name.startswith("bench_"))


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    known = names()
    mods = ["bench_" + n for n in known]
    unknown = [a for a in argv if a not in known]
    if unknown:
        print("bench.run: error: no benchmark named %s; the benchmarks: %s"
              % (", ".join(unknown), " ".join(known)), file=sys.stderr)
        return 2
    if argv:
        mods = [m for m in mods if m[len("bench_"):] in argv]
    os.makedirs(RECORDS, exist_ok=True)
    path = os.path.join(RECORDS, "%s_%s.md" % (time.strftime("%Y-%m-%d_%H%M"),
                                               _git("rev-parse", "--short", "HEAD") or "x"))
    print("bench: the tables also go to %s" % os.path.relpath(path, ROOT), flush=True)
    with open(path, "w") as f:
        real = sys.stdout
        sys.stdout = _Tee(real, f)
        try:
            print(header([m[len("bench_"):] for m in mods]), flush=True)
            return _run(mods)
        finally:
            sys.stdout = real


def _run(mods):
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
    print("\n- load (1, 5, 15 min) after: %s" % _load(), flush=True)
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
