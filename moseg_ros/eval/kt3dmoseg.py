"""KT3DMoSeg trajectory-level benchmark: misclassification rate of every clip's labelled trajectories.

Protocol (Xu, Cheong, Li, CVPR 2018): each clip's sparse trajectories (``ySparse``, ``visibleSparse``) are
clustered by motion; the error is the fraction of trajectories whose cluster is wrong under the best one-to-one
matching of clusters to the labels (``GtLabel``); the number of motions is given (or estimated with
--estimate-k). The method is core.trajectory_segment.segment_trajectories with one fixed setting for every clip
(TrajectoryConfig's defaults). DIR holds the clips' .mat files (any name; a file is a clip when it holds a
``Data`` struct, so SeqList.mat is passed over), directly or under DIR/Data/.

Measured on the 22 clips (views F,H, 2 processes): K given 6.30 % mean over seeds 0-4 (median 0.84 %), 6.82 %
over seeds 0-9, 8.1 s per pass over the clips; K estimated (cluster-conductance rule,
TrajectoryConfig.max_conductance) 7.49 % over seeds 0-4 (median 3.80 %), 8.18 % over seeds 0-9, 7.1 s per pass.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import statistics
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import scipy.io

from moseg_ros.core import clustering
from moseg_ros.core import trajectory_segment as segment
from moseg_ros.eval.report import write_json

VIEW_NAMES = {"f": "fundamental", "h": "homography", "a": "affine", "fundamental": "fundamental",
              "homography": "homography", "affine": "affine"}


@dataclass(frozen=True)
class Clip:
    """One clip's evaluated trajectories: tracks (N, F, 2), visible (N, F), labels (N,) in 1..K."""

    name: str
    tracks: np.ndarray
    visible: np.ndarray
    labels: np.ndarray


def default_dir() -> Path:
    """../shared/data/kt3dmoseg relative to the current directory."""
    return Path.cwd().parent / "shared" / "data" / "kt3dmoseg"


def is_clip_file(path: Path) -> bool:
    """Whether a .mat file holds a ``Data`` struct, the variable every KT3DMoSeg clip file stores.

    Only the file's variable directory is read (scipy.io.whosmat), so checking a folder stays cheap; a file
    that is not a MATLAB v5 file at all (v7.3/HDF5, truncated, another format) is not a clip.
    """
    try:
        return ("Data", "struct") in {(name, kind) for name, _, kind in scipy.io.whosmat(str(path))}
    except (ValueError, OSError, NotImplementedError, scipy.io.matlab.MatReadError):
        return False


def find_clips(root: Path) -> list[Path]:
    """Clip files (*.mat with a Data struct) in root/Data/ (the dataset's layout) or, failing that, in root."""
    for folder in (root / "Data", root):
        files = sorted((p for p in folder.glob("*.mat") if is_clip_file(p)), key=lambda p: p.name.lower())
        if files:
            return files
    return []


def no_clips_message(root: Path) -> str:
    """What the tools print for a folder without clip files."""
    return f"no KT3DMoSeg clip files (*.mat with a Data struct) under {root}"


def load_clip(path: Path) -> Clip:
    """Read a KT3DMoSeg .mat (see the data's PROVENANCE.md): homogeneous (3, N, F) points -> (N, F, 2). Raises
    ValueError naming the file when it cannot be read or lacks the clip's fields or shapes."""
    try:
        data = scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False)["Data"]
        y = np.asarray(data.ySparse, dtype=np.float64)
        visible = np.asarray(data.visibleSparse).astype(bool)
        labels = np.atleast_1d(np.asarray(data.GtLabel)).astype(np.int64)
    except Exception as error:  # scipy raises OSError, ValueError, TypeError... on damaged files; fields may lack
        raise ValueError(f"{path}: not a readable KT3DMoSeg clip ({type(error).__name__}: {error})") from None
    if y.ndim != 3 or y.shape[0] != 3 or visible.shape != y.shape[1:] or labels.shape != y.shape[1:2]:
        raise ValueError(f"{path}: unexpected shapes ySparse {y.shape}, visibleSparse {visible.shape}, "
                         f"GtLabel {labels.shape}")
    return Clip(path.stem.removesuffix("_Tracks"), np.transpose(y[:2], (1, 2, 0)), visible, labels)


def parse_views(text: str) -> tuple[str, ...]:
    """'F,H' or 'fundamental,homography' -> ('fundamental', 'homography')."""
    try:
        views = tuple(VIEW_NAMES[v.strip().lower()] for v in text.split(",") if v.strip())
    except KeyError as err:
        raise argparse.ArgumentTypeError(f"unknown view {err.args[0]!r}; use F, H, A or their full names") from err
    if not views or len(set(views)) != len(views):
        raise argparse.ArgumentTypeError(f"views must be distinct and non-empty, got {text!r}")
    return views


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg eval kt3dmoseg`."""
    parser.add_argument("dir", nargs="?", type=Path, default=None,
                        help="data folder (default: ../shared/data/kt3dmoseg from the current directory)")
    parser.add_argument("--views", type=parse_views, default=("fundamental", "homography"),
                        help="models fused by co-regularization: F, H, A (default F,H)")
    parser.add_argument("--seed", type=int, default=0, help="first random seed (default 0)")
    parser.add_argument("--seeds", type=int, default=1, help="number of seeds, seed..seed+N-1; errors are "
                        "averaged over them (default 1)")
    parser.add_argument("--estimate-k", action="store_true", help="estimate the number of motions")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                        help="worker processes (default min(2, CPUs))")
    parser.add_argument("--json", type=Path, default=None, help="write the results as JSON to this path")


def _evaluate(clip: Clip, views: tuple[str, ...], seed: int, estimate_k: bool) -> tuple[float, int, float]:
    """(error %, number of clusters used, seconds) of one clip and seed."""
    start = time.perf_counter()
    n_motions = None if estimate_k else int(clip.labels.max())
    from threadpoolctl import threadpool_limits  # imported here: only the benchmark run needs it

    # Small dense problems: multi-threaded BLAS was about 20x slower here than one thread per process.
    with threadpool_limits(1):
        pred = segment.segment_trajectories(clip.tracks, clip.visible, views=views, n_motions=n_motions,
                                            rng=np.random.default_rng(seed))
    return (100.0 * clustering.misclassification_rate(pred, clip.labels), int(len(np.unique(pred))),
            time.perf_counter() - start)


def run(args: argparse.Namespace) -> int:
    """Run the benchmark, print the per-clip table and the summary; 0 on success, 2 without data."""
    root = args.dir if args.dir is not None else default_dir()
    files = find_clips(root)
    if not files:
        print(no_clips_message(root))
        return 2
    if args.seeds < 1 or args.jobs < 1:
        print("--seeds and --jobs must be >= 1")
        return 2
    try:
        clips = [load_clip(f) for f in files]
    except ValueError as error:
        print(f"moseg eval kt3dmoseg: error: {error}", file=sys.stderr)
        return 2
    seeds = list(range(args.seed, args.seed + args.seeds))
    jobs = [(clip, args.views, seed, args.estimate_k) for seed in seeds for clip in clips]
    start = time.perf_counter()
    if args.jobs == 1:
        results = [_evaluate(*job) for job in jobs]
    else:
        methods = multiprocessing.get_all_start_methods()
        context = multiprocessing.get_context("fork" if "fork" in methods else None)
        with ProcessPoolExecutor(args.jobs, mp_context=context) as pool:
            results = list(pool.map(_evaluate, *zip(*jobs)))
    total = time.perf_counter() - start
    res = np.array(results, dtype=np.float64).reshape(len(seeds), len(clips), 3)

    rows = []
    header = f"{'clip':<16}{'points':>7}{'frames':>7}{'motions':>8}{'K used':>7}{'error %':>9}{'±sd':>7}{'seconds':>9}"
    print(header)
    print("-" * len(header))
    for i, clip in enumerate(clips):
        err = res[:, i, 0]
        row = {"clip": clip.name, "points": int(len(clip.labels)), "frames": int(clip.visible.shape[1]),
               "motions": int(clip.labels.max()), "clusters": float(res[:, i, 1].mean()),
               "error_pct": float(err.mean()), "error_pct_sd": float(err.std()), "seconds": float(res[:, i, 2].mean())}
        rows.append(row)
        print(f"{row['clip']:<16}{row['points']:>7}{row['frames']:>7}{row['motions']:>8}{row['clusters']:>7.1f}"
              f"{row['error_pct']:>9.2f}{row['error_pct_sd']:>7.2f}{row['seconds']:>9.2f}")
    per_seed_mean = res[:, :, 0].mean(axis=1)
    mean_err = float(per_seed_mean.mean())
    median_err = float(statistics.median(r["error_pct"] for r in rows))
    print("-" * len(header))
    print(f"views {','.join(args.views)}; K {'estimated' if args.estimate_k else 'given'}; seeds {seeds[0]}.."
          f"{seeds[-1]}; jobs {args.jobs}")
    print(f"mean error {mean_err:.2f} % (sd over seeds {per_seed_mean.std():.2f}); median {median_err:.2f} %; "
          f"worst {max(r['error_pct'] for r in rows):.2f} %")
    print(f"total {total:.1f} s ({total / len(seeds):.1f} s per pass over {len(clips)} clips)")
    if args.json is not None:
        report = {"mean_error_pct": mean_err, "median_error_pct": median_err, "total_seconds": total,
                  "seconds_per_pass": total / len(seeds), "mean_error_pct_per_seed": per_seed_mean.tolist(),
                  "views": list(args.views), "estimate_k": bool(args.estimate_k), "seeds": seeds,
                  "jobs": args.jobs, "config": asdict(segment.TrajectoryConfig()), "rows": rows}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json(args.json, report)
    return 0
