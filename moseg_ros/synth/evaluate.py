"""Score the pipeline's per-object decisions on the synthetic street presets, where the truth is exact.

For every preset and seed the scene is rendered and the pipeline runs over it frame by frame. By default it
gets no instances and finds the objects itself; an object-frame (an object with at least --min-area pixels
in a frame, after the time of the first --skip frames at 10 Hz) counts as flagged when at least --cover of its
pixels lie in the dynamic mask. With --instances (always for object_level) the exact instance maps are its
upstream instances (what `use_instances` gives the node) and an object-frame is flagged when its id is among the
frame's dynamic ids. Moving and static objects are counted apart. Prints a line per preset and seed (each object
as name:flagged/seen, * = moving), the totals per kind of object and overall, and how the published masks
cover the moving objects' pixels over the scored frames (IoU, precision, recall), and how the published instances
follow the movers (eval/identities.py: id switches, object-frames whose instance holds another mover too, and
object-frames split over two or more instances);
--json writes them.
With --rate a camera running at that rate sees the same scenes (the same motion per second, so a 30 Hz camera
sees a third of it per frame), and every frame it takes is scored.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from moseg_ros.eval.identities import InstanceFollow
from moseg_ros.eval.report import write_json
from moseg_ros.config import add_live_argument, add_settings_arguments, pipeline_config
from moseg_ros.pipeline import Pipeline, PipelineConfig
from moseg_ros.synth.scenarios import PRESETS, check_scene, render_sequence
from moseg_ros.synth.street import FRAME_RATE_HZ, KITTI_HEIGHT, KITTI_WIDTH
from moseg_ros.timing import Pacer

# Every preset but map, which is the default's movers at half the camera speed (made for SfM, not a new case).
EVAL_PRESETS = tuple(name for name in PRESETS if name != "map")


def kitti_height(width: int) -> int:
    """The image height that keeps KITTI's aspect ratio at ``width``."""
    return int(round(width * KITTI_HEIGHT / KITTI_WIDTH))


def score_scene(preset: str, seed: int, config: PipelineConfig, *, n_frames: int = 16, width: int = 621,
                min_area: int = 60, skip: int = 3, instances: bool = True,
                cover: float = 0.5, live: float = 0.0, pixels: Counter[str] | None = None,
                withheld: tuple[str, ...] = (), rate_hz: float = FRAME_RATE_HZ) -> dict[str, dict[str, int | bool]]:
    """Per object of one rendered preset: {"moving": truth, "flagged": frames flagged, "seen": frames counted}.

    The height keeps KITTI's aspect ratio. ``instances``: give the pipeline the exact instance maps (flagged =
    id among the dynamic ids); otherwise flagged = at least ``cover`` of the object's pixels in the mask.
    ``live``: a camera's rate (Hz) to run the pipeline at as the node does (0: offline). ``pixels``: when given,
    the scored frames' pixel counts of the dynamic mask against the moving objects' pixels are added to it
    (``tp``, ``fp``, ``fn``). ``withheld``: with ``instances``, the objects whose names start with one of these are
    left out of the instance maps (a segmenter that does not know them) and flagged by ``cover``. ``rate_hz``: the
    camera's rate (``build_scene``); ``n_frames`` and ``skip`` count frames at the presets' 10 Hz, and every frame
    after the time of the first ``skip`` is scored.
    """
    height = kitti_height(width)
    sequence = render_sequence(preset, seed=seed, n_frames=n_frames, width=width, height=height, rate_hz=rate_hz)
    skipped = round(skip * rate_hz / FRAME_RATE_HZ)
    unknown = [obj for obj, name in sequence.object_names.items() if name.startswith(withheld)] if withheld else []
    flagged: Counter[int] = Counter()
    seen: Counter[int] = Counter()
    follow = InstanceFollow()
    pacer = Pacer(live)
    with Pipeline(config, live=live > 0) as pipeline:
        for t, frame in enumerate(sequence.frames):
            pacer.wait()
            given = None
            if instances:
                given = np.where(np.isin(frame.instances, unknown), 0, frame.instances) if unknown else frame.instances
            result = pipeline.process(frame.rgb, frame.stamp_ns, given, next_frame_at=pacer.next_due)
            if t < skipped:
                continue
            if pixels is not None:
                pixels.update(pixel_counts(result.masks.dynamic > 0, np.isin(frame.instances,
                                                                             list(sequence.dynamic_ids))))
            ids, areas = np.unique(frame.instances, return_counts=True)
            covered = np.bincount(frame.instances.ravel(), weights=(result.masks.dynamic > 0).ravel(),
                                  minlength=ids.max() + 1)[ids] / areas
            hit = np.isin(ids, result.dynamic_ids) if instances else covered >= cover
            if unknown:
                hit = np.where(np.isin(ids, unknown), covered >= cover, hit)
            counted = (ids > 0) & (areas >= min_area)
            for obj, flag in zip(ids[counted].tolist(), hit[counted].tolist()):
                seen[obj] += 1
                flagged[obj] += int(flag)
            follow.add(result.masks.instance_labels, frame.instances,
                       ids[counted & np.isin(ids, list(sequence.dynamic_ids))])
    return {sequence.object_names[obj]: {"moving": obj in sequence.dynamic_ids, "flagged": flagged[obj],
                                         "seen": seen[obj], "id_switches": follow.switches[obj],
                                         "shared": follow.shared[obj], "split": follow.split[obj]}
            for obj in sorted(seen)}


def pixel_counts(mask: np.ndarray, truth: np.ndarray) -> dict[str, int]:
    """True positive, false positive and false negative pixels (``tp``, ``fp``, ``fn``) of a (H, W) bool
    ``mask`` against the (H, W) bool ``truth``."""
    return {"tp": int(np.count_nonzero(mask & truth)), "fp": int(np.count_nonzero(mask & ~truth)),
            "fn": int(np.count_nonzero(~mask & truth))}


def pixel_scores(pixels: Counter[str]) -> dict[str, float]:
    """Pooled ``pixel_iou``, ``pixel_precision`` and ``pixel_recall`` of summed ``pixel_counts`` (NaN where a
    denominator is 0)."""
    tp, fp, fn = pixels["tp"], pixels["fp"], pixels["fn"]
    return {"pixel_iou": _share(tp, tp + fp + fn), "pixel_precision": _share(tp, tp + fp),
            "pixel_recall": _share(tp, tp + fn)}


def _share(part: int, whole: int) -> float:
    return part / whole if whole else float("nan")


def totals(scenes: list[dict[str, dict[str, int | bool]]]) -> dict[str, int]:
    """Object-frames flagged and counted, moving and static, and the moving objects' id switches, shared and split
    object-frames (eval/identities.py), over scored scenes."""
    out = Counter()
    for scene in scenes:
        for obj in scene.values():
            kind = "moving" if obj["moving"] else "static"
            out[f"{kind}_flagged"] += int(obj["flagged"])
            out[f"{kind}_seen"] += int(obj["seen"])
            out["moving_id_switches"] += int(obj["id_switches"])  # followed for the moving objects only
            out["moving_shared"] += int(obj["shared"])
            out["moving_split"] += int(obj["split"])
    counts = {key: out[key] for key in ("moving_flagged", "moving_seen", "static_flagged", "static_seen",
                                        "moving_id_switches", "moving_shared", "moving_split")}
    return {**counts, "moving_flagged_fraction": out["moving_flagged"] / max(out["moving_seen"], 1),
            "static_flagged_fraction": out["static_flagged"] / max(out["static_seen"], 1)}


def by_object(scenes: list[dict[str, dict[str, int | bool]]]) -> dict[str, dict[str, int | bool]]:
    """Object-frames flagged and counted per kind of object over scored scenes (a name without its number:
    "parked_car_1" and "parked_car_2" are both "parked_car"), in the order the kinds first appear."""
    out: dict[str, dict[str, int | bool]] = {}
    for scene in scenes:
        for name, obj in scene.items():
            kind = re.sub(r"_\d+$", "", name)
            entry = out.setdefault(kind, {"moving": obj["moving"], "flagged": 0, "seen": 0})
            entry["flagged"] += int(obj["flagged"])
            entry["seen"] += int(obj["seen"])
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `moseg synth-eval`."""
    parser.add_argument("--presets", default=",".join(EVAL_PRESETS),
                        help=f"comma-separated presets (default: {', '.join(EVAL_PRESETS)})")
    parser.add_argument("--seeds", type=int, default=2, help="seeds 0..N-1 of every preset (default 2)")
    parser.add_argument("--frames", type=int, default=16, help="frames at the presets' 10 Hz (default 16)")
    parser.add_argument("--rate", type=float, default=FRAME_RATE_HZ, metavar="HZ",
                        help="the camera's frame rate: the same scenes and motion per second seen at this rate "
                             "(default 10, the presets' own)")
    parser.add_argument("--width", type=int, default=621, help="image width; the height keeps KITTI's aspect ratio")
    parser.add_argument("--instances", action="store_true",
                        help="give the pipeline the exact instance maps (always so for object_level)")
    parser.add_argument("--withhold", action="append", default=[], metavar="NAME",
                        help="with --instances: leave the objects whose names start with NAME (car_crossing, "
                             "pedestrian, ...) out of the given instance maps, as a segmenter that does not know "
                             "them; they are flagged by --cover (repeatable)")
    parser.add_argument("--cover", type=float, default=0.5,
                        help="without --instances: share of an object's pixels in the mask that flags it")
    add_settings_arguments(parser)  # e.g. --set flow_preset=fast, --set ground_contact=false
    add_live_argument(parser)
    parser.add_argument("--min-area", type=int, default=60, help="smallest object counted (pixels)")
    parser.add_argument("--skip", type=int, default=3, help="first frames at 10 Hz not counted (no evidence yet)")
    parser.add_argument("--json", type=Path, help="write the per-scene rows and the totals here")


def run(args: argparse.Namespace) -> int:
    """Score every preset and seed; print and optionally write the results."""
    presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    unknown = [p for p in presets if p not in PRESETS]
    if unknown or not presets or args.seeds < 1:
        print(f"moseg synth-eval: presets must be among {', '.join(PRESETS)} and --seeds >= 1")
        return 2
    try:
        for preset in presets:
            check_scene(preset, args.frames, args.width, kitti_height(args.width), args.rate)
    except ValueError as error:
        print(f"moseg synth-eval: error: {error}", file=sys.stderr)
        return 2
    config = pipeline_config(args)
    if args.withhold and not (args.instances or config.method == "object_level"):
        print("moseg synth-eval: error: --withhold leaves objects out of the instance maps; give --instances",
              file=sys.stderr)
        return 2
    rows, scenes, pixels = [], [], Counter()
    for preset in presets:
        for seed in range(args.seeds):
            scene = score_scene(preset, seed, config, n_frames=args.frames, width=args.width,
                                min_area=args.min_area, skip=args.skip, cover=args.cover,
                                instances=args.instances or config.method == "object_level", live=args.live,
                                pixels=pixels, withheld=tuple(args.withhold), rate_hz=args.rate)
            scenes.append(scene)
            rows.append({"preset": preset, "seed": seed, "objects": scene})
            print(f"{preset:10s} {seed:2d}  " + " ".join(
                f"{name}{'*' if o['moving'] else ''}:{o['flagged']}/{o['seen']}" for name, o in scene.items()))
    total = {**totals(scenes), **pixel_scores(pixels)}
    kinds = by_object(scenes)
    print("by object: " + ", ".join(f"{kind}{'*' if o['moving'] else ''} {o['flagged']}/{o['seen']}"
                                    for kind, o in kinds.items()))
    contact = config.settings_of("object_level").ground_contact
    print(f"moving object-frames flagged {total['moving_flagged']}/{total['moving_seen']} "
          f"({100 * total['moving_flagged_fraction']:.1f} %), static object-frames flagged "
          f"{total['static_flagged']}/{total['static_seen']} ({100 * total['static_flagged_fraction']:.1f} %) "
          f"(method {config.method}, flow {config.dis_preset()}, ground contact {contact}, camera at "
          f"{args.rate:g} Hz)")
    print(f"moving pixels: IoU {total['pixel_iou']:.3f}, precision {total['pixel_precision']:.3f}, "
          f"recall {total['pixel_recall']:.3f} (the published masks over the scored frames)")
    print(f"instances: {total['moving_id_switches']} id switches of the movers' instances, {total['moving_shared']} "
          f"moving object-frames whose instance holds another mover, {total['moving_split']} split over two or more "
          f"instances")
    if args.json:
        write_json(args.json, {"totals": total, "by_object": kinds, "scenes": rows, "live_hz": args.live,
                               "rate_hz": args.rate})
    return 0
