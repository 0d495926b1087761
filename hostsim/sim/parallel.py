"""Run independent simulations on the available cores, results in input order.

Every task carries its own seed, so the results do not depend on the number of workers
or on which worker ran what. A tqdm progress bar is shown on a terminal only.
"""
import os
import sys
from concurrent.futures import ProcessPoolExecutor


def default_jobs():
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def _progress(total, desc):
    try:
        from tqdm import tqdm
    except ImportError:      # progress is a nicety, never a dependency of the results
        return None
    return tqdm(total=total, desc=desc, disable=not sys.stderr.isatty(), leave=False)


def run_tasks(fn, tasks, jobs=None, desc=None, warm=None):
    """[fn(t) for t in tasks], on ``jobs`` processes (1: in this process).

    warm: a callable run once before forking (e.g. to generate the model cache that every
    worker would otherwise race to create).
    """
    jobs = default_jobs() if jobs is None else max(1, int(jobs))
    tasks = list(tasks)
    if warm is not None:
        warm()
    bar = _progress(len(tasks), desc)
    results = [None] * len(tasks)
    try:
        if jobs == 1 or len(tasks) <= 1:
            for i, t in enumerate(tasks):
                results[i] = fn(t)
                if bar is not None:
                    bar.update(1)
            return results
        with ProcessPoolExecutor(max_workers=min(jobs, len(tasks))) as pool:
            futures = {pool.submit(fn, t): i for i, t in enumerate(tasks)}
            from concurrent.futures import as_completed
            for fut in as_completed(futures):
                results[futures[fut]] = fut.result()
                if bar is not None:
                    bar.update(1)
        return results
    finally:
        if bar is not None:
            bar.close()
