"""Monte Carlo campaigns over seeds, on ``dask.distributed``.

``run_campaign(fn, seeds, out_dir, ...)`` calls ``fn(seed=s, run_dir=out_dir/'run_%04d' % i, **kwargs)`` for each
seed and returns the result dicts in seed order:

- ``workers=1``: in-process, no Dask (the reference path; also what a debugger wants);
- ``workers=N`` (default ``os.cpu_count()``): a ``LocalCluster`` of N single-threaded worker processes;
- ``scheduler="tcp://host:port"``: an existing Dask cluster (``Client(scheduler)``, short connect timeout;
  an unreachable address is a ValueError naming it).

A run is a pure function of its seed (``fn`` must draw all its randomness from ``seed``), so it gives the same
result whichever worker runs it. A run that raises is returned as ``{"seed": s, "error": "message"}`` and the
others go on. Ctrl-C cancels the outstanding futures and re-raises KeyboardInterrupt (the caller writes
``complete: false``).
"""

import contextlib
import logging
import os
import sys

from emulator.runtime import check_seed  # noqa: F401  (the campaigns' first seed, as every fps command's)

CONNECT_TIMEOUT_S = 3.0


def check_runs(n):
    """``n`` as a run count >= 1; ValueError naming the value otherwise."""
    try:
        k = int(n)
    except (TypeError, ValueError):
        raise ValueError("--runs must be an integer >= 1, got %r" % (n,)) from None
    if k != n or k < 1:
        raise ValueError("--runs must be >= 1, got %r" % (n,))
    return k


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


def stamp(path):
    """The modification time (ns) of ``path``, a file the campaign has just written: runs written before it
    belong to an earlier campaign in the same folder (``written_since``)."""
    return os.stat(path).st_mtime_ns


def written_since(path, since_ns):
    """True if ``path`` exists and was written at or after ``since_ns`` (``stamp``): an interrupted campaign
    counts only its own runs, never those an earlier campaign left in a reused folder."""
    try:
        t = os.stat(path).st_mtime_ns
    except OSError:
        return False
    return since_ns is None or t >= since_ns


def finished_results(out_dir, n, since_ns=None):
    """The ``result.json`` of runs 0 .. n-1 in ``out_dir`` that this campaign wrote (``written_since``), None
    where there is none: what an interrupted campaign collects from its folder."""
    import json
    out = []
    for i in range(n):
        p = os.path.join(run_dir_for(out_dir, i), "result.json")
        r = None
        if written_since(p, since_ns):
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


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored while the local workers start: they inherit it (an ignored signal survives exec), so a
    terminal's Ctrl-C, which goes to the whole process group, reaches only this process, which cancels the runs
    and closes the cluster, instead of every worker also dying with a KeyboardInterrupt traceback on stderr.
    A Ctrl-C in that second is lost. Main thread only (signal's rule)."""
    import signal
    import threading
    old = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or old is None:
        yield
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


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


def run_campaign(fn, seeds, out_dir, *, workers=None, scheduler=None, progress=True, desc="runs", **kwargs):
    """Run ``fn`` once per seed (see the module docstring); returns the list of result dicts in seed order."""
    seeds = [int(s) for s in seeds]
    check_runs(len(seeds))
    dirs = [run_dir_for(out_dir, i) for i in range(len(seeds))]
    os.makedirs(str(out_dir), exist_ok=True)
    if scheduler is None:
        workers = check_workers(workers)
        if workers == 1:
            out = []
            with _bar(len(seeds), progress, desc) as bar:
                for s, d in zip(seeds, dirs):
                    out.append(_call(fn, s, d, kwargs))
                    bar.update(1)
            return out
    if scheduler is not None:
        client, cluster = _connect(scheduler), None
    else:
        from distributed import Client, LocalCluster
        with _sigint_ignored():
            # CRITICAL, not ERROR: a worker whose heartbeat races the cluster's close (Ctrl-C) logs an ERROR
            # with a traceback. A run's own failure still reaches the user, as that run's error record.
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=None, silence_logs=logging.CRITICAL)
        client = Client(cluster)
    futures = []
    try:
        futures = [client.submit(_call, fn, s, d, kwargs, pure=False, key="%s-%04d-%d" % (desc, i, s))
                   for i, (s, d) in enumerate(zip(seeds, dirs))]
        index = {f.key: i for i, f in enumerate(futures)}
        out = [None] * len(seeds)
        from distributed import as_completed
        with _bar(len(seeds), progress, desc) as bar:
            for f in as_completed(futures):
                i = index[f.key]
                try:
                    out[i] = f.result()
                except KeyboardInterrupt:
                    raise
                except Exception as exc:  # noqa: BLE001 - a lost worker etc.: that run is an error record
                    out[i] = {"seed": seeds[i], "error": "%s: %s" % (type(exc).__name__, exc)}
                bar.update(1)
        return out
    except KeyboardInterrupt:
        for f in futures:
            f.cancel()
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
