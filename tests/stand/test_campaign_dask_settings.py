"""The Dask workers' periodic work (profiler, memory and system monitors, event-loop tick), which takes CPU time
from the process that runs each case: the bench's cluster runs the recommended settings, and a campaign records what
its workers run and warns where it costs (docs/campaigns.md, "Local pool and Dask")."""

import json
import logging

import pytest

from stand import campaign as cm
from stand.scenario import SCENARIO_DIR

SHORT_S = 5.0


def _periodic(dask_worker) -> dict:
    return {name: pc.callback_time for name, pc in dask_worker.periodic_callbacks.items() if pc.is_running()}


@pytest.mark.slow
def test_the_campaign_bench_s_dask_workers_run_without_the_profiler_and_with_slow_monitors():
    import dask
    import distributed

    from stand.benches.campaign import _ClusterProcess

    with _ClusterProcess(workers=1) as cluster, \
            distributed.Client(cluster.address, timeout=30, set_as_default=False) as client:
        (enabled,) = client.run(lambda: dask.config.get("distributed.worker.profile.enabled")).values()
        (periodic,) = client.run(_periodic).values()
    assert enabled is False and "profile" not in periodic
    # Dask's defaults: 100 ms, 500 ms, 20 ms.
    assert (periodic["memory_monitor"], periodic["monitor"], periodic["tick"]) == (1000, 5000, 1000)


@pytest.mark.slow
def test_a_dask_campaign_records_its_workers_periodic_work_and_warns_of_the_profiler(tmp_path, caplog):
    """Workers started with Dask's defaults (as ``dask worker`` starts them): campaign.json says what they run and
    how to start them instead, and the client logs it as a warning; the campaign itself runs as before."""
    import distributed

    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    with caplog.at_level(logging.WARNING, logger="stand.campaign"), \
            distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                     dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:
        result = cm.run_campaign(spec, tmp_path / "camp", 1, scheduler=cluster.scheduler_address, plots=False)
    assert result["status"] == "complete"
    ex = json.loads((tmp_path / "camp" / "campaign.json").read_text())["execution"]
    assert ex["dask_worker_periodic_ms"] == {"profile": 10, "memory_monitor": 100, "monitor": 500, "tick": 20}
    advice = ex["dask_worker_advice"]
    assert "distributed.worker.profile.enabled" in advice
    assert "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False" in advice
    assert "DASK_DISTRIBUTED__ADMIN__TICK__INTERVAL=1s" in advice
    assert any(advice in r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)


def test_workers_on_the_recommended_settings_get_no_advice_and_one_costly_setting_is_named_alone():
    from stand.campaign.dask_executor import WORKER_CONFIG, dask_worker_env, worker_settings

    good = {"memory_monitor": 1000.0, "monitor": 5000.0, "tick": 1000.0, "heartbeat": 1000.0}
    assert worker_settings({"w1": good, "w2": {**good, "tick": 2000.0}}, {"w1": None, "w2": None}) == {
        "dask_worker_periodic_ms": {"profile": None, "memory_monitor": 1000.0, "monitor": 5000.0, "tick": 1000.0},
        "dask_worker_malloc_trim_threshold": []}
    one = worker_settings({"w1": good, "w2": {**good, "profile": 10.0}})
    assert one["dask_worker_periodic_ms"]["profile"] == 10.0
    assert "start them with DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False" in one["dask_worker_advice"]
    assert "TICK" not in one["dask_worker_advice"] and "MONITOR" not in one["dask_worker_advice"]
    assert worker_settings({}) == {"dask_worker_periodic_ms": dict.fromkeys(good.keys() - {"heartbeat"} | {"profile"}),
                                   "dask_worker_malloc_trim_threshold": []}
    # Each variable is what Dask reads back as the setting.
    import dask

    read = dask.config.collect_env(dask_worker_env())
    assert {key: dask.config.get(key, config=read) for key in WORKER_CONFIG} == WORKER_CONFIG


@pytest.mark.slow
def test_the_dask_client_s_own_thread_waits_on_no_dask_call_per_case(tmp_path, monkeypatch):
    """Each case's answer is fetched on the Dask client's event loop and handed to the client's thread through a
    queue: the thread makes as many blocking calls into the event loop (``Client.sync``: ``Future.result``,
    ``Client.run``, ...) for a campaign of 4 cases as for one of 1 (it made one more per case)."""
    import distributed
    from distributed.client import Client

    calls: list[str] = []
    real_sync = Client.sync

    def counted(self, func, *args, **kwargs):
        calls.append(getattr(func, "__name__", repr(func)))
        return real_sync(self, func, *args, **kwargs)

    spec = cm.make_spec("detumble", SCENARIO_DIR / "detumble_dispersions.toml", duration_s=SHORT_S)
    counts = []
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=cm.DASK_HTTP_ADDRESS) as cluster:
        monkeypatch.setattr(Client, "sync", counted)
        for runs in (1, 4):
            calls.clear()
            result = cm.run_campaign(spec, tmp_path / f"camp{runs}", runs, scheduler=cluster.scheduler_address,
                                     plots=False)
            assert result["status"] == "complete" and result["finished"] == runs
            counts.append(list(calls))
    assert len(counts[0]) == len(counts[1]), counts


@pytest.mark.slow
def test_the_campaign_bench_s_dask_workers_run_without_the_nanny_s_malloc_trim_threshold(monkeypatch):
    """Dask's nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536, which maps and unmaps every large buffer of
    every case (docs/campaigns.md): the bench's cluster leaves it unset (NANNY_CONFIG)."""
    import os

    import distributed

    from stand.benches.campaign import _ClusterProcess
    from stand.campaign.dask_executor import MALLOC_TRIM_VARIABLE

    # A nanny sets the variable in its own process too (os.environ.update): an earlier test's LocalCluster in this
    # process leaves it here, where the bench's cluster process would inherit it; a shell has none.
    monkeypatch.delenv(MALLOC_TRIM_VARIABLE, raising=False)

    with _ClusterProcess(workers=1) as cluster, \
            distributed.Client(cluster.address, timeout=30, set_as_default=False) as client:
        (trim,) = client.run(os.environ.get, MALLOC_TRIM_VARIABLE).values()
    assert trim is None


def test_workers_with_the_nanny_s_malloc_trim_threshold_are_recorded_and_told_how_to_unset_it():
    from stand.campaign.dask_executor import NANNY_CONFIG, worker_settings

    good = {"memory_monitor": 1000.0, "monitor": 5000.0, "tick": 1000.0}
    out = worker_settings({"w1": good, "w2": good}, {"w1": "65536", "w2": None})
    assert out["dask_worker_malloc_trim_threshold"] == ["65536"]
    advice = out["dask_worker_advice"]
    assert "MALLOC_TRIM_THRESHOLD_=65536" in advice
    assert "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_ to null" in advice
    assert "PROFILE" not in advice  # the periodic settings are the recommended ones: not named
    # The setting is the one Dask's nanny reads: a None leaves the variable out of the worker's environment.
    import dask
    from distributed.nanny import _get_env_variables

    with dask.config.set(NANNY_CONFIG):
        assert "MALLOC_TRIM_THRESHOLD_" not in _get_env_variables("distributed.nanny.pre-spawn-environ")
    assert _get_env_variables("distributed.nanny.pre-spawn-environ").get("MALLOC_TRIM_THRESHOLD_") == "65536"
