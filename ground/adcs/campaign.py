"""Monte Carlo campaigns over seeds: in-process, on local worker processes, or on a ``dask.distributed`` cluster.

``run_campaign(fn, seeds, out_dir, ...)`` calls ``fn(seed=s, run_dir=out_dir/'run_%04d' % i, **kwargs)`` for each
seed and returns the result dicts in seed order:

- ``workers=1``: in-process (the reference path; also what a debugger wants);
- ``workers=N`` (default ``os.cpu_count()``): N local worker processes (``concurrent.futures.ProcessPoolExecutor``,
  forked on Linux, so a worker starts with the caller's imports instead of paying its own);
- ``scheduler="tcp://host:port"``: a Dask cluster, for a campaign that outgrows one machine (``Client(scheduler)``
  through its ``concurrent.futures`` executor, short connect timeout; an unreachable address is a ValueError naming
  it).

Local runs do not go through Dask: on one machine a ``LocalCluster`` costs its start-up (~1 s: a nanny and a worker
interpreter per process) and a slower run in each worker, and ``bench_adcs`` measured 20 seeds on 2 local Dask
workers at 1.4x the in-process time where two plain processes gave 2x.

A run is a pure function of its seed (``fn`` must draw all its randomness from ``seed``), so it gives the same
result whichever worker runs it. A run that raises is returned as ``{"seed": s, "error": "message"}`` and the
others go on. A local worker process that dies (the out-of-memory killer, a crash) breaks the pool: the runs
not finished become error records (``LOST_RUN``), the finished ones are kept, and the campaign returns. Local
runs are not retried; a Dask cluster retries a dead worker's runs itself. Ctrl-C cancels the outstanding futures, stops
the local workers (a run they were in is lost; those that finished have their folders) and re-raises
KeyboardInterrupt (the caller writes ``complete: false``). On a Dask cluster a run already executing cannot be
stopped: it finishes on its worker and may write its ``run_NNNN`` folder after the interrupted summary, which
does not count it.
"""

import os
import re
import shutil
import sys

from emulator.runtime import SEED_MAX, check_seed  # noqa: F401  (the campaigns' first seed, as every fps command's)
from ground.fileio import run_folder, write_json

CONNECT_TIMEOUT_S = 3.0


MAX_RUNS = 100000     # a campaign's seeds, folders and results are listed up front


def check_runs(n):
    """``n`` as a run count from 1 to MAX_RUNS; ValueError naming the value otherwise."""
    try:
        k = int(n)
    except (TypeError, ValueError, OverflowError):
        raise ValueError("--runs must be an integer >= 1, got %r" % (n,)) from None
    if k != n or k < 1:
        raise ValueError("--runs must be >= 1, got %r" % (n,))
    if k > MAX_RUNS:
        raise ValueError("--runs must be at most %d (a bigger study is several campaigns with other --seed), got "
                         "%r" % (MAX_RUNS, n))
    return k


def seeds_for(seed, runs):
    """The campaign's seeds ``seed`` .. ``seed`` + ``runs`` - 1, each a valid ``--seed``; ValueError naming the
    options when the last would pass 2^32 - 1."""
    n, s = check_runs(runs), check_seed(seed)
    if s + n - 1 > SEED_MAX:
        raise ValueError("--seed %d with --runs %d would run seeds up to %d, past 2^32 - 1: lower --seed or --runs"
                         % (s, n, s + n - 1))
    return [s + i for i in range(n)]


MAX_DURATION_S = 86400.0      # one day: the truth and each run's history are held in memory


def check_duration(duration_s):
    """``--duration`` (s) in [1, MAX_DURATION_S]; ValueError naming it otherwise (NaN included)."""
    if not 1 <= duration_s <= MAX_DURATION_S:
        raise ValueError("--duration must be in [1, %g] s, got %r" % (MAX_DURATION_S, duration_s))
    return duration_s


MAX_LOCAL_WORKERS = 64      # local processes, ~0.1 GB each; a bigger campaign goes on a cluster (--scheduler)


def check_workers(n):
    """``--workers`` (local processes) in 1..MAX_LOCAL_WORKERS, default the machine's cores; ValueError naming
    it otherwise."""
    if n is None:
        return max(1, min(os.cpu_count() or 1, MAX_LOCAL_WORKERS))
    if isinstance(n, bool) or int(n) != n or not 1 <= n <= MAX_LOCAL_WORKERS:
        raise ValueError("--workers must be a whole number from 1 to %d local processes (a bigger campaign runs on "
                         "a Dask cluster: --scheduler ADDRESS), got %r" % (MAX_LOCAL_WORKERS, n))
    return int(n)


def run_dir_for(out_dir, i):
    return os.path.join(str(out_dir), "run_%04d" % i)


RUN_DIR = re.compile(r"run_[0-9]{4}$")


def campaign_folder(path, figures, summary):
    """Make the campaign folder ``path``, or reuse it without what an earlier campaign left there: its
    ``figures`` (``ground.fileio.run_folder``) and its ``run_NNNN`` folders. Every run in the folder is then this
    campaign's, so an interrupted campaign collects only its own, and no run beyond ``--runs`` stays beside the
    new summary. ``summary`` (this campaign's, ``complete`` false) is written first, so a folder interrupted
    while the old runs go says so. Returns ``path``."""
    run_folder(path, figures)
    write_json(os.path.join(str(path), "summary.json"), summary)
    for name in os.listdir(str(path)):
        p = os.path.join(str(path), name)
        if RUN_DIR.match(name) and os.path.isdir(p) and not os.path.islink(p):
            shutil.rmtree(p)
    return path


def finished_results(out_dir, n):
    """The ``result.json`` of runs 0 .. n-1 in ``out_dir``, None where there is none: what an interrupted
    campaign collects from its folder (``campaign_folder`` left no earlier campaign's runs there)."""
    import json
    out = []
    for i in range(n):
        p = os.path.join(run_dir_for(out_dir, i), "result.json")
        r = None
        if os.path.exists(p):
            with open(p) as f:
                r = json.load(f)
        out.append(r)
    return out


def _call(fn, seed, run_dir, kwargs):
    """One run; an exception becomes an error record (the message, not a traceback)."""
    try:
        res = fn(seed=seed, run_dir=run_dir, **kwargs)
    except KeyboardInterrupt:
        raise
    except Exception as exc:         # noqa: BLE001 - any failure of one run must not end the campaign
        return {"seed": seed, "error": "%s: %s" % (type(exc).__name__, exc)}
    if not isinstance(res, dict):
        return {"seed": seed, "error": "run returned %s, not a dict" % type(res).__name__}
    res.setdefault("seed", seed)
    return res


def _ignore_sigint():
    """A local worker's initializer: a terminal's Ctrl-C goes to the whole process group, and only the caller
    acts on it (cancels the runs, stops the workers), instead of every worker also printing a KeyboardInterrupt
    traceback; and the worker dies with the caller, however the caller dies (``die_with_parent``)."""
    import signal
    from emulator.runtime import die_with_parent
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()


def _bar(total, progress, desc):
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit="run", file=sys.stderr, disable=not progress, leave=False)


def _connect(scheduler):
    from distributed import Client
    try:
        return Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise ValueError("scheduler %r is unreachable within %.0f s (%s)"
                         % (scheduler, CONNECT_TIMEOUT_S, exc)) from None
    except Exception as exc:  # noqa: BLE001 - bad address formats raise assorted types
        raise ValueError("scheduler %r: cannot connect (%s: %s)" % (scheduler, type(exc).__name__, exc)) from None


def check_scheduler(scheduler):
    """Connect to ``scheduler`` once and close: an unreachable address is a ValueError naming it, before the
    command writes its folder (None: a local campaign, nothing to check)."""
    if scheduler is not None:
        _connect(scheduler).close()


def _local_pool(workers):
    """N worker processes: forked on Linux (a worker starts with the caller's imports), spawned elsewhere."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    method = "fork" if sys.platform.startswith("linux") else "spawn"
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(method), initializer=_ignore_sigint)


LOST_RUN = ("BrokenProcessPool: a local worker process died (killed, e.g. by the out-of-memory killer, or crashed) "
            "before this run ended; local runs are not retried: run the seed again, or on a Dask cluster "
            "(--scheduler), which retries a dead worker's runs")


def run_campaign(fn, seeds, out_dir, *, workers=None, scheduler=None, progress=True, desc="runs", dirs=None,
                 **kwargs):
    """Run ``fn`` once per seed (see the module docstring); returns the list of result dicts in seed order.
    ``dirs``: each run's folder (default ``run_dir_for(out_dir, i)``; a resumed campaign passes those of the runs
    it still needs)."""
    seeds = [int(s) for s in seeds]
    check_runs(len(seeds))
    dirs = [run_dir_for(out_dir, i) for i in range(len(seeds))] if dirs is None else list(dirs)
    if len(dirs) != len(seeds):
        raise ValueError("run_campaign: %d folders for %d seeds" % (len(dirs), len(seeds)))
    os.makedirs(str(out_dir), exist_ok=True)
    out = [None] * len(seeds)
    with _bar(len(seeds), progress, desc) as bar:
        if scheduler is not None:
            client = _connect(scheduler)
            try:
                _drain(client.get_executor(pure=False), range(len(seeds)), out, fn, seeds, dirs, kwargs, bar, desc)
            finally:
                client.close()
            return out
        workers = check_workers(workers)
        if workers == 1:
            for i, (s, d) in enumerate(zip(seeds, dirs)):
                out[i] = _call(fn, s, d, kwargs)
                bar.update(1)
            return out
        for i in _drain(_local_pool(workers), range(len(seeds)), out, fn, seeds, dirs, kwargs, bar, desc,
                        local=True):
            out[i] = {"seed": seeds[i], "error": LOST_RUN}
            bar.update(1)
    return out


def task_key(name, seed):
    """A Dask task's key: the campaign's name and the run's seed, then a unique token (the dashboard groups the
    tasks by the name, e.g. ``apkf_case_1``, instead of the wrapper's ``_call``)."""
    import uuid
    return "%s-seed%d-%s" % (re.sub(r"[^0-9A-Za-z]+", "_", name).strip("_") or "run", seed, uuid.uuid4().hex)


def _drain(pool, todo, out, fn, seeds, dirs, kwargs, bar, name, local=False):
    """Submit runs ``todo`` to ``pool``, put their results in ``out`` as they come and shut the pool down
    (``name``: the campaign's, in a Dask pool's task keys, ``task_key``).
    Returns, in submission order, the runs a local pool lost when one of its worker processes died (the
    pool breaks and fails every run not finished). Ctrl-C cancels the rest, stops a local pool's workers (a
    run they were in is lost; those that finished have their folders) and re-raises."""
    import multiprocessing
    from concurrent.futures import as_completed
    from concurrent.futures.process import BrokenProcessPool
    before = set(multiprocessing.active_children())
    children, lost = [], []
    try:
        futures = {}
        for i in todo:
            kw = {} if local else {"key": task_key(name, seeds[i])}     # Dask: the task's name on the dashboard
            futures[pool.submit(_call, fn, seeds[i], dirs[i], kwargs, **kw)] = i
        if local:                        # the pool started its processes on these submits
            children = [p for p in multiprocessing.active_children() if p not in before]
        for f in as_completed(futures):
            i = futures[f]
            try:
                out[i] = f.result()
            except KeyboardInterrupt:
                raise
            except BrokenProcessPool:
                lost.append(i)
                continue
            except Exception as exc:     # noqa: BLE001 - a lost cluster worker etc.: that run is an error record
                out[i] = {"seed": seeds[i], "error": "%s: %s" % (type(exc).__name__, exc)}
            bar.update(1)
        pool.shutdown(wait=True)
        return sorted(lost)
    except BaseException:
        if local:
            pool.shutdown(wait=False, cancel_futures=True)    # not f.cancel(): the pool sets errors on them
        else:
            pool.shutdown(wait=False)                         # cancels those not yet running on the cluster
        for p in children:      # runs in progress are abandoned, not waited for (a bps case takes ~20 s)
            p.terminate()
        for p in children:
            p.join()
        raise
