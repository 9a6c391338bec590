"""ground/adcs/campaign.py: in-process, local-process and Dask (in-process LocalCluster) paths, errors,
reproducibility."""

import json
import os

import numpy as np
import pytest

from ground.adcs import campaign


def draw(seed, run_dir, n=3, fail_on=None, die_on=None):
    """A run: random numbers from its seed only; writes its own folder; fails, or kills its process, on request."""
    if seed == fail_on:
        raise FloatingPointError("filter diverged at t = 12 s")
    if seed == die_on:
        os._exit(9)                                     # as a worker killed by the OOM killer
    os.makedirs(run_dir, exist_ok=True)
    x = np.random.default_rng(seed).normal(size=n).tolist()
    with open(os.path.join(run_dir, "x.json"), "w") as f:
        json.dump(x, f)
    return {"x": x, "pid": os.getpid()}


def test_in_process_seed_order_and_error_record(tmp_path):
    res = campaign.run_campaign(draw, [5, 6, 7], tmp_path, workers=1, progress=False, fail_on=6)
    assert [r["seed"] for r in res] == [5, 6, 7]
    assert "diverged" in res[1]["error"] and "x" not in res[1]
    assert res[0]["x"] == np.random.default_rng(5).normal(size=3).tolist()
    assert os.path.exists(tmp_path / "run_0002" / "x.json") and not os.path.exists(tmp_path / "run_0001")


def test_local_processes_match_in_process(tmp_path):
    seeds = [11, 12, 13, 14, 15]
    ref = campaign.run_campaign(draw, seeds, tmp_path / "a", workers=1, progress=False, fail_on=13)
    res = campaign.run_campaign(draw, seeds, tmp_path / "b", workers=2, progress=False, fail_on=13)
    assert [r["seed"] for r in res] == seeds
    assert [r.get("x") for r in res] == [r.get("x") for r in ref]     # same result whichever worker ran it
    assert "diverged" in res[2]["error"]
    assert os.getpid() not in {r["pid"] for r in res if "pid" in r}    # ran in worker processes


def test_a_dead_local_worker_ends_the_campaign_with_error_records_not_a_hang(tmp_path):
    """A worker process that dies breaks the pool: the runs not finished become error records saying so (and
    what to do), the finished ones are kept, and the campaign returns."""
    seeds = [1, 2, 3, 4, 5, 6]
    res = campaign.run_campaign(draw, seeds, tmp_path, workers=2, progress=False, die_on=6)
    assert [r["seed"] for r in res] == seeds
    assert res[5]["error"] == campaign.LOST_RUN and "--scheduler" in res[5]["error"]
    kept = [r for r in res if "x" in r]
    assert kept and all(r["x"] == np.random.default_rng(r["seed"]).normal(size=3).tolist() for r in kept)
    assert all("x" in r or r["error"] == campaign.LOST_RUN for r in res)


def test_dask_scheduler_address(tmp_path):
    from distributed import LocalCluster
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cl:
        res = campaign.run_campaign(draw, [3, 4], tmp_path, scheduler=cl.scheduler_address, progress=False,
                                    desc="apkf case 1")
        prefixes = set(cl.scheduler.task_prefixes)
    assert [r["x"] for r in res] == [np.random.default_rng(s).normal(size=3).tolist() for s in (3, 4)]
    assert "apkf_case_1" in prefixes and "_call" not in prefixes      # the dashboard names the campaign
    k = campaign.task_key("sweep t_s", 7)
    assert k.startswith("sweep_t_s-seed7-") and k != campaign.task_key("sweep t_s", 7)


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="--runs must be >= 1, got 0"):
        campaign.check_runs(0)
    with pytest.raises(ValueError, match="--runs"):
        campaign.run_campaign(draw, [], tmp_path)
    with pytest.raises(ValueError, match="--workers must be a whole number from 1 to 64 .* got 0"):
        campaign.run_campaign(draw, [1], tmp_path, workers=0)
    with pytest.raises(ValueError, match="--scheduler ADDRESS.*got 100000"):    # not 100,000 local processes
        campaign.run_campaign(draw, [1], tmp_path, workers=100000)
    with pytest.raises(ValueError, match="--seed must be a whole number from 0 to 2\\^32 - 1, got 4294967296"):
        campaign.check_seed(2 ** 32)                    # the range the other fps commands take
    with pytest.raises(ValueError, match="127.0.0.1:9"):
        campaign.run_campaign(draw, [1], tmp_path, scheduler="tcp://127.0.0.1:9", progress=False)
