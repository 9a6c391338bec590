"""``python -m bench.against REV NAME [NAME ...]``: the benchmarks NAME run on this tree and on commit REV in the same
sitting, alternately (this, REV, this, REV, ... ``--rounds`` times), so that the machine's load falls on both alike,
then every number of their tables side by side with its ratio (this / REV), every verdict (a cell with no number:
"True", "stopped: ...") by its text, and whether each cell's printed text was the same in every run of both (an
accuracy row of a deterministic benchmark is; a time is not). A ratio, not an absolute time, says whether a change
cost speed on a shared machine: within 5 % is noise here.

REV is checked out with ``git worktree`` under ``build/against/<rev>`` and run with this virtual environment (its
``bench`` and packages from that tree); what ``make`` builds (the C kernels, the PIL images) is not there unless
built in it, so a benchmark that needs them runs its fallback or skips on that side, saying so. Exit 2 for an
unknown commit or benchmark."""

import argparse
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
NUMBER = re.compile(r"-?\d[\d,]*\.?\d*(?:[eE][-+]?\d+)?")


def worktree(rev):
    """The commit's tree under build/against/<short rev> (made once, by ``git worktree add --detach``)."""
    sha = subprocess.run(["git", "rev-parse", "--short", "--verify", rev + "^{commit}"], cwd=ROOT,
                         capture_output=True, text=True)
    if sha.returncode != 0:
        raise ValueError("%s is no commit of this repository" % rev)
    path = os.path.join(ROOT, "build", "against", sha.stdout.strip())
    if not os.path.isdir(path):
        p = subprocess.run(["git", "worktree", "add", "--detach", path, sha.stdout.strip()], cwd=ROOT,
                           capture_output=True, text=True)
        if p.returncode != 0:
            raise ValueError("git worktree add %s: %s" % (rev, p.stderr.strip()))
    return path


def run_one(tree, name):
    """One benchmark's output on ``tree`` (its own bench and packages first on the path)."""
    env = dict(os.environ, PYTHONPATH=tree + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.run([sys.executable, "-m", "bench.bench_" + name], cwd=tree, env=env, capture_output=True,
                       text=True)
    return p.stdout + ("" if p.returncode == 0 else "\n(exit %d: %s)" % (p.returncode, p.stderr.strip()[-300:]))


def table_cells(text):
    """{(table, row label, column): cell text} of every non-empty cell of every Markdown table row in ``text``
    (headers and rulers left out); tables are counted from 1 in the order printed, so a row label two tables share is
    two rows."""
    out, table, inside = {}, 0, False
    for line in text.splitlines():
        if not line.startswith("|"):
            inside = False
            continue
        if not inside:
            table, inside = table + 1, True
            continue                                    # the header
        if set(line) <= set("|-: "):
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        for j, c in enumerate(cells[1:], 1):
            if c:
                out[(table, cells[0], j)] = c
    return out


def table_numbers(text):
    """{(table, row label, column): number} of every Markdown table row in ``text`` (the first number of each cell)."""
    return cell_numbers(table_cells(text))


def cell_numbers(cells):
    """The first number of each cell of ``table_cells``' answer, for the cells that hold one."""
    return {key: float(m.group(0).replace(",", "")) for key, m in ((k, NUMBER.search(c)) for k, c in cells.items())
            if m}


def same_text(ours, theirs, key):
    """True when every run of both printed the cell ``key`` with the same text."""
    texts = set(r.get(key) for r in ours + theirs)
    return len(texts) == 1 and None not in texts


def compare(ours, theirs):
    """Rows of (table, label, column, ours, theirs, ratio) for the numbers both runs printed, averaged over rounds."""
    rows = []
    for key in ours[0]:
        a = [r[key] for r in ours if key in r]
        b = [r[key] for r in theirs if key in r]
        if a and b:
            ma, mb = sum(a) / len(a), sum(b) / len(b)
            rows.append(key + (ma, mb, ma / mb if mb else None))
    return rows


def _cell(text):
    return "(none)" if text is None else text.replace("|", "/")[:40]


def main(argv=None):
    from bench import run
    ap = argparse.ArgumentParser(prog="python -m bench.against", description=__doc__.split("\n\n")[0])
    ap.add_argument("rev", help="the commit to compare with (a hash, a tag, HEAD~1)")
    ap.add_argument("names", nargs="+", help="benchmarks (bench/bench_NAME.py)")
    ap.add_argument("--rounds", type=int, default=2, help="alternations of this tree and REV (default 2)")
    a = ap.parse_args(argv)
    known = run.names()
    bad = [n for n in a.names if n not in known]
    if bad or a.rounds < 1:
        print("bench.against: error: %s" % ("no benchmark named %s; the benchmarks: %s" % (", ".join(bad),
                                                                                          " ".join(known))
                                             if bad else "--rounds must be >= 1"), file=sys.stderr)
        return 2
    try:
        tree = worktree(a.rev)
    except ValueError as exc:
        print("bench.against: error: %s" % exc, file=sys.stderr)
        return 2
    print(run.header(a.names))
    for name in a.names:
        ours, theirs = [], []
        for _ in range(a.rounds):
            ours.append(run_one(ROOT, name))
            theirs.append(run_one(tree, name))
        cells_a, cells_b = [table_cells(t) for t in ours], [table_cells(t) for t in theirs]
        print("\n## %s: this tree against %s (%d rounds, means)\n" % (name, a.rev, a.rounds))
        for t in ours + theirs:
            if "\n(exit " in t:
                print("(a run failed: %s)\n" % t.rsplit("\n(exit ", 1)[1][:300])
        print("| table | row | column | this tree | %s | ratio | same text |\n|---|---|---|---|---|---|---|"
              % a.rev)
        numbers = {r[:3]: r[3:] for r in compare([cell_numbers(c) for c in cells_a],
                                                 [cell_numbers(c) for c in cells_b])}
        for key in dict.fromkeys(k for c in cells_a + cells_b for k in c):     # in the order printed
            same = "yes" if same_text(cells_a, cells_b, key) else "no"
            if key in numbers:
                x, y, r = numbers[key]
                print("| %d | %s | %d | %.4g | %.4g | %s | %s |" % (key[0], key[1][:70], key[2], x, y,
                                                                   "—" if r is None else "%.3f" % r, same))
            else:           # a verdict, not a number: its text from the first run of each
                print("| %d | %s | %d | %s | %s | — | %s |" % (key[0], key[1][:70], key[2],
                                                              _cell(cells_a[0].get(key)), _cell(cells_b[0].get(key)),
                                                              same))
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
