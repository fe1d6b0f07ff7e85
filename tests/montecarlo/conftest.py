"""Real Dask clusters for the Monte Carlo tests: worker processes on 127.0.0.1, stopped by the
fixtures themselves."""

import pytest


def _cluster(n_workers: int):
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address="127.0.0.1:0")
    client = Client(cluster)
    client.wait_for_workers(n_workers, timeout=60)
    return cluster, client


@pytest.fixture(scope="module")
def clients():
    """``{1: client of a 1-worker cluster, 2: client of a 2-worker cluster}``."""
    made = {n: _cluster(n) for n in (1, 2)}
    try:
        yield {n: client for n, (_, client) in made.items()}
    finally:
        for cluster, client in made.values():
            client.close()
            cluster.close()
