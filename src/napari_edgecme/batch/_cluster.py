"""Where the photos of a batch run: a local Dask cluster sized to the machine, or a given one."""

from __future__ import annotations

import os

from ..core._validation import first_line

__all__ = ["INSTALL_HINT", "WORKER_MEMORY", "dask_setup", "local_cluster_size"]

#: Install hint when Dask is missing.
INSTALL_HINT = 'pip install "napari-edgecme[batch]"'
#: Memory a worker should have for one photo (a 12 MP RGB photo peaks at about 1.4 GiB).
WORKER_MEMORY = 2 * 2**30
_BLAS_ONE_THREAD = {name: "1" for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                           "MKL_NUM_THREADS", "EDGECME_FFT_THREADS")}


def local_cluster_size(cores: int | None = None, memory: int | None = None
                       ) -> tuple[int, int, int]:
    """Workers, threads per worker and memory per worker of the default local cluster.

    One single-threaded worker process per core, with numpy's BLAS/OpenMP threads at 1,
    so that photos run side by side without fighting over the cores; fewer workers when
    the memory would give each less than :data:`WORKER_MEMORY`.

    Parameters
    ----------
    cores : int, optional
        Cores this process may use (default: its CPU affinity).
    memory : int, optional
        Bytes of memory (default: the machine's total).

    Returns
    -------
    n_workers, threads_per_worker, memory_limit : int
    """
    if cores is None:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
            os.cpu_count() or 1)
    if memory is None:
        import psutil

        memory = psutil.virtual_memory().total
    n_workers = max(1, min(cores, memory // WORKER_MEMORY))
    return n_workers, 1, int(memory // n_workers)


def dask_setup(worker) -> None:
    """Dask preload hook of the local cluster's workers: Ctrl-C is for the client.

    A terminal sends SIGINT to the whole process group, worker processes included; they
    ignore it, so that the client decides what an interrupt does (running photos finish).
    """
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise ImportError("batch deblurring on several workers needs Dask: "
                          f"{INSTALL_HINT} (or workers=1 / --workers 1 to deblur one photo "
                          "at a time without it)") from None
    return distributed


class Cluster:
    """Context manager: a Dask client (own local cluster, given client, or by address)."""

    def __init__(self, client=None, scheduler: str | None = None, workers: int | None = None):
        self.given = client
        self.scheduler = scheduler
        self.workers = workers
        self._stack = None
        self.description = ""

    def __enter__(self):
        import contextlib
        import logging

        distributed = _import_distributed()
        import dask

        if self.given is not None:
            self.description = f"the given Dask client ({self.given.scheduler.address})"
            return self.given
        self._stack = contextlib.ExitStack()
        if self.scheduler is not None:
            try:
                client = self._stack.enter_context(
                    distributed.Client(self.scheduler, timeout="10s", set_as_default=False))
            except (OSError, TimeoutError, ValueError) as err:
                self._stack.close()
                raise ValueError(f"cannot connect to the Dask scheduler at "
                                 f"{self.scheduler}: {first_line(err)}") from None
            threads = sum(client.nthreads().values())
            self.description = (f"Dask scheduler {self.scheduler} ({len(client.nthreads())} "
                                f"workers, {threads} threads)")
            return client
        n_workers, threads, memory = local_cluster_size()
        if self.workers is not None:
            n_workers, memory = self.workers, memory * n_workers // self.workers
        with self._stack.pop_all() as stack, dask.config.set({
                # a photo that kills its worker twice is reported, not tried forever
                "distributed.scheduler.allowed-failures": 1}):
            cluster = stack.enter_context(distributed.LocalCluster(
                n_workers=n_workers, threads_per_worker=threads, processes=True,
                memory_limit=memory, dashboard_address=None, env=_BLAS_ONE_THREAD,
                # each photo's failure is reported in its row, not as a log message
                silence_logs=logging.CRITICAL, preload=[__name__]))
            client = stack.enter_context(distributed.Client(cluster, set_as_default=False))
            self._stack = stack.pop_all()
        self.description = (f"local Dask cluster: {n_workers} worker processes x {threads} "
                            f"thread, BLAS/OpenMP threads 1, "
                            f"{memory / 2**30:.1f} GiB memory limit each")
        return client

    def __exit__(self, *exc):
        if self._stack is not None:
            self._stack.close()
        return False
