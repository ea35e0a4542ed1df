"""Many bags at once: one output bag per input under an output folder, one after another or as Ray tasks.

A bag is one task and is never split: the method keeps temporal state within a bag. A task writes
``OUTDIR/.partial/<name>`` and moves it to ``OUTDIR/<name>`` when it is done, so an output folder of that
name is complete and a rerun skips it (``overwrite`` redoes it); what a killed run left in ``.partial`` is
redone. A bag that fails is reported with its error
and does not stop the others. Every task runs with one BLAS and one OpenCV thread, so bags, not threads,
share the cores, and a bag's masks are the same whichever process or machine ran it.

Ray (``ray.init()`` on this machine, or a cluster's address) carries the distribution: it schedules one task
per CPU, restarts nothing on its own (a failed bag is reported, not retried) and needs no code of ours on
the workers beyond an installed moseg_ros. Workers write to ``OUTDIR`` as they see it: on a cluster it must
be a shared path.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from moseg_ros.io.bags import is_bag
from moseg_ros.pipeline import PipelineConfig

SUMMARY_FILE = "summary.json"
LOCAL = "local"
PARTIAL = ".partial"
ONE_THREAD = {name: "1" for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}


@dataclasses.dataclass(frozen=True)
class BagJob:
    """One input bag and the output folder its masks go to."""

    name: str
    bag: Path
    output: Path


def find_bags(inputs: Sequence[Path]) -> list[Path]:
    """The bags named by ``inputs``: each is a bag, or a folder whose children (sorted by name) are bags."""
    bags: list[Path] = []
    for path in map(Path, inputs):
        if not path.exists():
            raise FileNotFoundError(f"bag not found: {path}")
        if is_bag(path):
            bags.append(path)
            continue
        children = sorted(child for child in path.iterdir() if is_bag(child)) if path.is_dir() else []
        if not children:
            raise ValueError(f"{path} is neither a bag (rosbag2 folder, .mcap, .bag) nor a folder of bags")
        bags.extend(children)
    return bags


def plan_jobs(inputs: Sequence[Path], outdir: Path) -> list[BagJob]:
    """One job per bag, its output named after the input (``OUTDIR/<name>``); two inputs of one name are refused."""
    jobs = [BagJob(bag.stem if bag.is_file() else bag.name, bag, outdir / (bag.stem if bag.is_file() else bag.name))
            for bag in find_bags(inputs)]
    names = [job.name for job in jobs]
    if duplicates := sorted({name for name in names if names.count(name) > 1}):
        raise ValueError(f"several input bags are named {duplicates}: their outputs would collide in {outdir}")
    return jobs


def is_complete(output: Path) -> bool:
    """True when an output bag was finished (moved out of .partial after its metadata.yaml was written)."""
    return (output / "metadata.yaml").is_file()


def process_job(job: BagJob, config: PipelineConfig, image_topic: str | None = None) -> dict[str, Any]:
    """Segment one bag into ``job.output`` (through ``.partial/<name>`` beside it) with one thread; never raises.

    Returns:
        The bag's row of the summary: name, input, output, status ("ok", "damaged": processed up to the
        damage, "failed"), frames_in, masks_out, frames_without_mask, seconds, error.
    """
    from threadpoolctl import threadpool_limits

    from moseg_ros.tools.bag_masks import process_bag

    row = _row(job, "failed")
    partial = job.output.parent / PARTIAL / job.output.name  # so the MCAP file inside is named <name>.mcap
    shutil.rmtree(partial, ignore_errors=True)
    partial.parent.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    config = dataclasses.replace(config, opencv_threads=1)
    try:
        with threadpool_limits(1):
            counts = process_bag(job.bag, partial, image_topic=image_topic, config=config)
        partial.rename(job.output)
    except Exception as error:  # a bag's failure, whatever it is, is its row's, not the fleet's
        shutil.rmtree(partial, ignore_errors=True)
        row["error"] = f"{type(error).__name__}: {error}"
        row["seconds"] = time.perf_counter() - start
        return row
    row.update(status="damaged" if counts["input_damage"] else "ok", frames_in=counts["frames_in"],
               masks_out=counts["masks_out"], frames_without_mask=counts["frames_in"] - counts["masks_out"],
               seconds=time.perf_counter() - start, error=counts["input_damage"])
    return row


def _row(job: BagJob, status: str, error: str | None = None) -> dict[str, Any]:
    """A summary row of a bag that produced no frames (yet)."""
    return {"name": job.name, "input": str(job.bag), "output": str(job.output), "status": status,
            "frames_in": 0, "masks_out": 0, "frames_without_mask": 0, "seconds": 0.0, "error": error}


class ProgressBar:
    """A one-line bar over bags on stderr (silent when disabled)."""

    def __init__(self, total: int, enabled: bool = True) -> None:
        self.total, self.done, self.enabled = total, 0, enabled
        self._draw("")

    def advance(self, row: dict[str, Any]) -> None:
        """Count one finished bag and show its name and status."""
        self.done += 1
        self._draw(f" {row['name']}: {row['status']}")
        if self.enabled and self.done == self.total:
            print(file=sys.stderr)

    def _draw(self, last: str) -> None:
        if not self.enabled:
            return
        filled = round(30 * self.done / max(self.total, 1))
        print(f"\r[{'#' * filled}{'.' * (30 - filled)}] {self.done}/{self.total} bags{last}\033[K", end="",
              file=sys.stderr, flush=True)


def run_sequential(jobs: Sequence[BagJob], config: PipelineConfig, image_topic: str | None = None,
                   on_done: Callable[[dict[str, Any]], None] = lambda row: None) -> list[dict[str, Any]]:
    """Process the jobs one after another in this process; one summary row per job, in job order."""
    rows = []
    for job in jobs:
        rows.append(process_job(job, config, image_topic))
        on_done(rows[-1])
    return rows


def _package_root() -> str:
    import moseg_ros

    return str(Path(moseg_ros.__file__).resolve().parents[1])


def start_ray(address: str = LOCAL, workers: int | None = None) -> bool:
    """Start a local Ray (``address`` "local", ``workers`` CPUs or all) or join a cluster; True if we started it.

    Local workers get the driver's moseg_ros first on their path, so they run exactly the code the driver
    runs; a cluster's workers use their installed moseg_ros.
    """
    import logging

    import ray

    if ray.is_initialized():
        return False
    env = dict(ONE_THREAD)
    if address == LOCAL:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [_package_root(), os.environ.get("PYTHONPATH")]))
        ray.init(num_cpus=workers or os.cpu_count(), include_dashboard=False, logging_level=logging.WARNING,
                 log_to_driver=False, runtime_env={"env_vars": env})
    else:
        ray.init(address=address, logging_level=logging.WARNING, log_to_driver=False,
                 runtime_env={"env_vars": env})
    return True


def _warm_worker() -> int:
    """Import what a bag's task needs, and hold the worker a moment so that each warm-up gets its own."""
    import moseg_ros.tools.bag_masks  # noqa: F401 -- the import is the warm-up

    time.sleep(0.5)
    return os.getpid()


def warm_up_ray(workers: int) -> int:
    """Start ``workers`` Ray workers and import the pipeline in each (Ray starts workers lazily, and a
    worker's first import of OpenCV and the pipeline costs about a second); returns the distinct workers."""
    import ray

    task = ray.remote(num_cpus=1)(_warm_worker)
    return len(set(ray.get([task.remote() for _ in range(workers)])))


def run_on_ray(jobs: Sequence[BagJob], config: PipelineConfig, image_topic: str | None = None,
               workers: int | None = None,
               on_done: Callable[[dict[str, Any]], None] = lambda row: None) -> list[dict[str, Any]]:
    """Process the jobs as Ray tasks (Ray must be initialized), at most ``workers`` at a time (default: the
    cluster's CPUs); one summary row per job, in job order. A task that dies is a failed row."""
    import ray

    task = ray.remote(num_cpus=1, max_retries=0)(process_job)
    limit = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
    pending: dict[Any, int] = {}
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    queue = list(enumerate(jobs))
    while queue or pending:
        while queue and len(pending) < limit:
            index, job = queue.pop(0)
            pending[task.remote(job, config, image_topic)] = index
        (ready,), _ = ray.wait(list(pending), num_returns=1)
        index = pending.pop(ready)
        try:
            rows[index] = ray.get(ready)
        except Exception as error:  # the worker died (killed, out of memory): Ray's error, this bag's row
            rows[index] = _row(jobs[index], "failed", f"{type(error).__name__}: {error}")
        on_done(rows[index])
    return [row for row in rows if row is not None]


def process_fleet(inputs: Sequence[Path], outdir: Path, config: PipelineConfig = PipelineConfig(), *,
                  image_topic: str | None = None, ray_address: str | None = None, workers: int | None = None,
                  overwrite: bool = False, progress: bool = False) -> dict[str, Any]:
    """Segment every bag of ``inputs`` into ``outdir/<name>``; write and return the summary.

    Args:
        inputs: bags, or folders of bags.
        outdir: output folder (created); holds one output bag per input and ``summary.json``.
        config: the pipeline settings, the same for every bag.
        image_topic: the image topic of every bag (default: each bag's one camera topic).
        ray_address: None runs the bags one after another here; "local" starts Ray on this machine;
            "auto" or "ray://host:port" joins a cluster.
        workers: at most this many bags at a time on Ray (default: every CPU Ray has).
        overwrite: redo bags whose output is complete (skipped otherwise).
        progress: draw a bar over bags on stderr.

    Returns:
        {"bags": [one row per input bag], "totals": {...}, "mode", "workers", "startup_seconds" (starting or
        joining Ray), "seconds" (processing, after the start-up)}.
    """
    outdir = Path(outdir)
    jobs = plan_jobs(inputs, outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    todo, rows = [], {}
    for job in jobs:
        if is_complete(job.output) and not overwrite:
            rows[job.name] = _row(job, "skipped")
            continue
        if job.output.exists():
            shutil.rmtree(job.output)
        todo.append(job)
    bar = ProgressBar(len(jobs), progress)
    for row in rows.values():
        bar.advance(row)
    startup = time.perf_counter()
    if ray_address is None:
        start = time.perf_counter()
        done = run_sequential(todo, config, image_topic, bar.advance)
    else:
        import ray

        started = start_ray(ray_address, workers) if todo else False
        start = time.perf_counter()
        try:
            done = run_on_ray(todo, config, image_topic, workers, bar.advance)
        finally:
            if started:
                ray.shutdown()
    rows.update((row["name"], row) for row in done)
    summary = {"mode": "sequential" if ray_address is None else f"ray ({ray_address})", "workers": workers,
               "startup_seconds": start - startup, "seconds": time.perf_counter() - start,
               "bags": [rows[job.name] for job in jobs],
               "totals": _totals([rows[job.name] for job in jobs])}
    (outdir / SUMMARY_FILE).write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def _totals(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    totals: dict[str, Any] = {status: sum(row["status"] == status for row in rows)
                              for status in ("ok", "damaged", "failed", "skipped")}
    for key in ("frames_in", "masks_out", "frames_without_mask"):
        totals[key] = sum(row[key] for row in rows)
    return totals


def summary_table(summary: dict[str, Any]) -> str:
    """The summary as a fixed-width table, one line per bag and a total."""
    lines = [f"{'bag':24} {'status':8} {'frames':>7} {'masks':>7} {'no mask':>7} {'seconds':>8}  error"]
    for row in summary["bags"]:
        lines.append(f"{row['name'][:24]:24} {row['status']:8} {row['frames_in']:7d} {row['masks_out']:7d} "
                     f"{row['frames_without_mask']:7d} {row['seconds']:8.1f}  {row['error'] or ''}")
    totals = summary["totals"]
    lines.append(f"{'total':24} {len(summary['bags']):4d} bag {totals['frames_in']:7d} {totals['masks_out']:7d} "
                 f"{totals['frames_without_mask']:7d} {summary['seconds']:8.1f}  "
                 f"{totals['ok']} ok, {totals['damaged']} damaged, {totals['failed']} failed, "
                 f"{totals['skipped']} skipped ({summary['mode']})")
    return "\n".join(lines)
