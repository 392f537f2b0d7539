"""One timed reduction of bench/dask_reduction.py in a fresh process:
``python bench/_dask_child.py serial|pool|dask SESSION`` prints, as JSON, its wall time, the CPU
time of the processes doing the work, this process's CPU time besides (Dask: the client and the
LocalCluster's scheduler), frames and the tables' digest. (Not run from the ``-c`` string it
once was: a spawned pool's processes import their functions from this file.)"""

import hashlib
import json
import multiprocessing
import os
import resource
import sys
import time

from acquisition.reduction.image import ImageReducer
from acquisition.tables.partial import merge_all


def digest(red):
    h = hashlib.sha256()
    for a in (red.table.count, red.table.mean, red.table.std_error, red.merl.count,
              red.merl.mean, red.merl.variance):
        h.update(a.tobytes())
    return h.hexdigest()


def serial(session):
    t, cpu = time.perf_counter(), time.process_time()
    reducer = ImageReducer.open(session)
    red = reducer.reduction(reducer.partial(reducer.frames))
    return time.perf_counter() - t, time.process_time() - cpu, 0.0, red


def warm_worker(session, ready):
    """A pool process's start: its share of the cores for numba's threads (as a Dask worker of
    ``gonio reduce --workers 2``: :func:`~acquisition.reduction.distributed.worker_threads`),
    numba's kernels loaded by reducing one frame, then wait until every process
    is warm (so each one warms itself, not a sibling twice)."""
    import numba

    numba.set_num_threads(max(1, (os.cpu_count() or 1) // 2))
    warm = ImageReducer.open(session)
    warm.partial(warm.frames[:1])
    ready.wait()


def pool(session):
    # spawn, not fork: numba's GNU OpenMP thread pool (the linearization's) is not fork-safe
    ctx = multiprocessing.get_context("spawn")
    ready = ctx.Barrier(2)
    with ctx.Pool(2, warm_worker, (session, ready)) as p:
        p.map(time.sleep, [0.0, 0.0])  # returns once both processes are warm
        before = {pid: cpu for pid, cpu in p.map(process_cpu, [0.2, 0.2])}
        t, cpu = time.perf_counter(), time.process_time()
        reducer = ImageReducer.open(session)
        parts = p.map(reducer.partial, [reducer.frames[0::2], reducer.frames[1::2]])
        red = reducer.reduction(merge_all(parts))
        wall, own = time.perf_counter() - t, time.process_time() - cpu
        after = {pid: c for pid, c in p.map(process_cpu, [0.2, 0.2])}
    if len(before) != 2 or set(after) != set(before):
        raise RuntimeError(f"the pool's processes changed: {sorted(before)} → {sorted(after)}")
    return wall, own + sum(after[k] - before[k] for k in before), 0.0, red


def process_cpu(delay):
    """(pid, CPU seconds) of the pool process that takes this task (each takes one: ``delay``)."""
    time.sleep(delay)
    return os.getpid(), time.process_time()


def workers_cpu(client):
    return sum(u.ru_utime + u.ru_stime
               for u in client.run(resource.getrusage, resource.RUSAGE_SELF).values())


def on_cluster(session):
    import dask
    from distributed import Client, LocalCluster, wait

    from acquisition.reduction.distributed import (
        LOCAL_CLUSTER,
        LOCAL_CONFIG,
        image_frame,
        reduce_on_cluster,
        take_running,
        worker_threads,
    )

    with dask.config.set(LOCAL_CONFIG), \
            LocalCluster(n_workers=2, **LOCAL_CLUSTER, **worker_threads(2)) as c, \
            Client(c) as client:  # as `gonio reduce --workers 2`
        warm = ImageReducer.open(session)
        wait([client.submit(image_frame, warm, warm.frames[0], "warm", workers=[w], pure=False)
              for w in client.scheduler_info()["workers"]])
        client.run(take_running, "warm")  # the warm-up's sums dropped
        before = workers_cpu(client)
        t, cpu = time.perf_counter(), time.process_time()
        (red,) = reduce_on_cluster(client, [session])
        wall, client_cpu = time.perf_counter() - t, time.process_time() - cpu
        return wall, workers_cpu(client) - before, client_cpu, red


if __name__ == "__main__":
    how, session = sys.argv[1], sys.argv[2]
    warm = ImageReducer.open(session)
    warm.partial(warm.frames[:1])  # numba's kernels loaded here (a forked pool inherits them)
    wall, cpu, client_cpu, red = {"serial": serial, "pool": pool, "dask": on_cluster}[how](session)
    print(json.dumps({"wall_s": wall, "cpu_s": cpu, "client_cpu_s": client_cpu,
                      "frames": red.frames, "digest": digest(red)}))
