"""Independent tasks on the CPU's cores: a few threads sharing torch's intra-op threads.

PyTorch parallelizes each operation over ``torch.get_num_threads()`` threads. Work made of many
small operations (a network on one image, a Wiener filter, an SSIM, a colour conversion in NumPy)
then leaves the cores idle between operations and in the Python around them. Running independent
tasks on several threads at once, each with its share of the intra-op threads (one each on a
2-core machine), keeps them busy: the operations release the interpreter lock while they compute.
At most :data:`MAX_WORKERS` tasks run at once, which bounds the memory they hold together. A task's
arithmetic depends on the threads it is given, not on which task runs beside it, so the results
are those of the tasks run one by one with that many threads.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterator, Sequence, TypeVar

import torch

T = TypeVar("T")


#: Tasks run at once at most (each holds its own images and intermediate results).
MAX_WORKERS = 4


def default_workers(device: str | torch.device) -> int:
    """Tasks run at once: torch's intra-op threads on a CPU (at most :data:`MAX_WORKERS`), one on a GPU."""
    if torch.device(device).type != "cpu":
        return 1
    return max(1, min(MAX_WORKERS, torch.get_num_threads()))


def run_tasks(tasks: Sequence[Callable[[], T]], workers: int = 1) -> Iterator[T]:
    """Run ``tasks`` (callables without arguments) and yield their results in the order of ``tasks``,
    each task in inference mode (no autograd: these are evaluations).

    ``workers > 1``: on that many threads, torch's intra-op threads divided among them meanwhile
    (``threads // workers`` each, at least one; restored after). ``workers == 1``: one after another
    in this thread. An exception of a task is raised here, once the tasks already started have ended.
    """

    def run(task: Callable[[], T]) -> T:
        with torch.inference_mode():
            return task()

    if workers <= 1 or len(tasks) <= 1:
        for task in tasks:
            yield run(task)
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(max(1, threads // workers))
    try:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(run, task) for task in tasks]
            for future in futures:
                yield future.result()
    finally:
        torch.set_num_threads(threads)
