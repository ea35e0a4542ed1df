"""Synthetic street scenes: a scene model and a vectorized ray-casting renderer with exact ground truth.

World frame: x right, y DOWN, z along the street; the ground is y = 0, the camera drives near x = 0 at height h.
Cameras follow OpenCV (x right, y down, z forward); a pose T (4, 4) maps camera to world, X_w = R X_c + c. Camera
and boxes only yaw about the vertical; boxes stand on the ground with their length along their local z.

Every pixel casts X(s) = c + s R K⁻¹ (u, v, 1)ᵀ (s: the pixel's depth); the ground and facades are intersected in
closed form, each box by the slab test within its projected rectangle, the nearest hit wins. Every surface
carries a texture fixed to it, sampled trilinearly from a mipmapped atlas (two ``cv2.remap`` look-ups), so a
static world point keeps its colour from frame to frame. docs/method.md has the details.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
import scipy.fft

__all__ = [
    "KITTI_WIDTH",
    "KITTI_HEIGHT",
    "FRAME_PERIOD_NS",
    "FRAME_RATE_HZ",
    "DEFAULT_START_NS",
    "GT_TOPICS",
    "CAR_COLOURS",
    "Texture",
    "Box",
    "Street",
    "SynthScene",
    "SynthFrame",
    "SynthSequence",
    "StreetRenderer",
    "check_rate",
    "kitti_intrinsics",
    "camera_poses",
    "box_face_layout",
    "box_texel",
    "render_frames",
    "write_frames",
    "write_bag",
    "periodic_noise",
    "paint_ground",
    "paint_facade",
    "paint_sky",
    "paint_car",
    "paint_pedestrian",
    "paint_post",
]

KITTI_WIDTH, KITTI_HEIGHT = 1242, 375
_KITTI_FX, _KITTI_FY, _KITTI_CX, _KITTI_CY = 721.5377, 721.5377, 609.5593, 172.8540
FRAME_PERIOD_NS = 100_000_000  # 10 Hz
FRAME_RATE_HZ = 1e9 / FRAME_PERIOD_NS
DEFAULT_START_NS = 1_700_000_000 * 1_000_000_000
GT_TOPICS = {
    "image": "/camera/image_raw",
    "camera_info": "/camera/camera_info",
    "instances": "/gt/instances",
    "dynamic_mask": "/gt/dynamic_mask",
    "depth": "/gt/depth",
    "pose": "/gt/pose",
}
CAMERA_FRAME, WORLD_FRAME = "camera", "world"

_MAX_LEVEL = 7  # coarsest mip level in the atlas: 4x4 texels for a 512 tile
_MIN_TILE = 2 << _MAX_LEVEL  # the coarsest level of the smallest tile keeps 2x2 texels
_ATLAS_TILE = 1024  # the largest tile; every texture's mip levels share its row bands in the atlas
_NEAR = 0.05  # metres; box geometry nearer than this to the camera plane is clipped for the bounding rectangle


def check_rate(rate_hz: float) -> None:
    """ValueError unless ``rate_hz``, a camera's frame rate, is positive (NaN is not)."""
    if not rate_hz > 0:
        raise ValueError(f"the camera's rate must be positive, got {rate_hz} Hz")


def kitti_intrinsics(width: int = KITTI_WIDTH, height: int = KITTI_HEIGHT) -> np.ndarray:
    """KITTI's left colour camera matrix (3, 3) scaled from 1242x375 to ``width`` x ``height``."""
    if width < 16 or height < 16:
        raise ValueError(f"image size must be at least 16x16, got {width}x{height}")
    sx, sy = width / KITTI_WIDTH, height / KITTI_HEIGHT
    return np.array([[_KITTI_FX * sx, 0.0, _KITTI_CX * sx],
                     [0.0, _KITTI_FY * sy, _KITTI_CY * sy],
                     [0.0, 0.0, 1.0]])


def _yaw_matrix(yaw: float | np.ndarray) -> np.ndarray:
    """Rotation (3, 3), or (N, 3, 3) for N yaws, about the y axis mapping (0, 0, 1) to (sin ψ, 0, cos ψ)."""
    c, s = np.cos(yaw), np.sin(yaw)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.moveaxis(np.array([[c, zero, s], [zero, one, zero], [-s, zero, c]]), (0, 1), (-2, -1))


def camera_poses(n_frames: int, *, speed: float, height: float, yaw_amplitude: float, yaw_period: float,
                 yaw_phase: float, x0: float = 0.0) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) of a camera driving along +z with a sinusoidal yaw.

    ψ_t = A sin(2π t / P + φ); the centre advances ``speed`` metres per frame along the heading,
    c_{t+1} = c_t + speed (sin ψ_t, 0, cos ψ_t), starting at (x0, -height, 0).
    """
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    t = np.arange(n_frames)
    yaw = yaw_amplitude * np.sin(2.0 * np.pi * t / yaw_period + yaw_phase)
    steps = speed * np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], axis=1)
    centres = np.vstack([np.zeros((1, 3)), np.cumsum(steps[:-1], axis=0)]) + np.array([x0, -height, 0.0])
    poses = np.tile(np.eye(4), (n_frames, 1, 1))
    poses[:, :3, :3] = _yaw_matrix(yaw)
    poses[:, :3, 3] = centres
    return poses


@dataclass(frozen=True, eq=False)
class Texture:
    """A tileable texture: ``image`` (T, T, 3) uint8 RGB with T a power of two, ``texel`` metres per texel.

    Surface coordinates (a, b) in metres map to texel (column a / texel, row b / texel), wrapped mod T.
    """

    image: np.ndarray
    texel: float

    def __post_init__(self) -> None:
        size = self.image.shape[0]
        if self.image.shape != (size, size, 3) or self.image.dtype != np.uint8:
            raise ValueError(f"texture must be a square (T, T, 3) uint8 image, got {self.image.shape} "
                             f"{self.image.dtype}")
        if size & (size - 1) or size < _MIN_TILE or size > _ATLAS_TILE:
            raise ValueError(f"texture size must be a power of two in [{_MIN_TILE}, {_ATLAS_TILE}], got {size}")
        if not self.texel > 0:
            raise ValueError(f"texel size must be positive, got {self.texel}")

    @property
    def size(self) -> int:
        """Side of the square texture image in texels."""
        return int(self.image.shape[0])


@dataclass(eq=False)
class Box:
    """An oriented box standing on the ground; its texture is painted in :func:`box_face_layout` order.

    size: (3,) width (local x), height (local y), length (local z) in metres.
    centres: (N, 3) world centre per frame; yaws: (N,) heading per frame (radians about world y).
    """

    id: int
    name: str
    size: np.ndarray
    centres: np.ndarray
    yaws: np.ndarray
    texture: Texture

    def __post_init__(self) -> None:
        self.size = np.asarray(self.size, dtype=np.float64)
        self.centres = np.asarray(self.centres, dtype=np.float64)
        self.yaws = np.asarray(self.yaws, dtype=np.float64)
        if self.id < 1:
            raise ValueError(f"box ids must be >= 1 (0 is the static world), got {self.id} for {self.name!r}")
        if self.size.shape != (3,) or np.any(self.size <= 0):
            raise ValueError(f"box {self.name!r}: size must be 3 positive numbers, got {self.size}")
        if self.centres.ndim != 2 or self.centres.shape[1] != 3 or self.yaws.shape != self.centres.shape[:1]:
            raise ValueError(f"box {self.name!r}: centres must be (N, 3) and yaws (N,), got "
                             f"{self.centres.shape} and {self.yaws.shape}")
        w, h, l = self.size
        span = self.texture.size * self.texture.texel
        if span < max(l, 2 * w + 0.1) or span < 2 * h + w + 0.2:
            raise ValueError(f"box {self.name!r}: its {span:.2f} m texture cannot hold the faces of a "
                             f"{w}x{h}x{l} m box (see box_face_layout and box_texel)")

    def moving(self) -> np.ndarray:
        """(N,) bool: the box's world pose changes between frame t and a neighbouring frame."""
        if len(self.yaws) < 2:
            return np.zeros(len(self.yaws), dtype=bool)
        step = np.any(np.diff(self.centres, axis=0) != 0, axis=1) | (np.diff(self.yaws) != 0)
        return np.concatenate([step, [False]]) | np.concatenate([[False], step])

    def pose(self, t: int) -> np.ndarray:
        """Box-to-world transform (4, 4) at frame t."""
        T = np.eye(4)
        T[:3, :3] = _yaw_matrix(float(self.yaws[t]))
        T[:3, 3] = self.centres[t]
        return T

    def rotations(self) -> np.ndarray:
        """Box-to-world rotations (N, 3, 3) of every frame."""
        return _yaw_matrix(self.yaws)

    def corners(self) -> np.ndarray:
        """World coordinates (N, 8, 3) of the corners of every frame, in _CORNER_SIGNS order."""
        return np.einsum("nij,kj->nki", self.rotations(), _CORNER_SIGNS * self.size / 2) + self.centres[:, None, :]


def box_face_layout(size: np.ndarray) -> dict[str, tuple[float, float]]:
    """Where each face of a box of ``size`` (w, h, l) lives in its texture: face -> (u0, v0) in metres.

    Sides (±x) span u ∈ [0, l], v ∈ [0, h] (v = 0 at the top, as y points down); the roof and bottom (±y)
    u ∈ [0, l], v ∈ [h + 0.1, h + 0.1 + w]; the front (+z) u ∈ [0, w] and the back (-z) u ∈ [w + 0.1, 2w + 0.1],
    both at v ∈ [h + w + 0.2, 2h + w + 0.2]. The texture must span max(l, 2w + 0.1) by 2h + w + 0.2 metres.
    """
    w, h, _ = (float(x) for x in size)
    return {"side": (0.0, 0.0), "top": (0.0, h + 0.1), "front": (0.0, h + w + 0.2), "back": (w + 0.1, h + w + 0.2)}


def box_texel(size: np.ndarray, tile: int, finest: float = 0.01) -> float:
    """Texel size (metres) that fits :func:`box_face_layout` of ``size`` into a ``tile`` texture."""
    w, h, l = (float(x) for x in size)
    return max(finest, (max(l, 2 * w + 0.1) + 0.05) / tile, (2 * h + w + 0.25) / tile)


_CORNER_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
# The 12 edges of a box as corner index pairs (corners in _CORNER_SIGNS order differ in one sign bit).
_BOX_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]).T


@dataclass(eq=False)
class Street:
    """A straight street: ground y = 0, facades x = x_left and x = x_right.

    Facade blocks of ``block_length`` metres start at z = ``z_start``; block i stands ``block_heights[i]`` metres
    tall (0 = a side street: no facade on either side). Facades exist only for z in the blocks' range.
    """

    x_left: float
    x_right: float
    block_length: float
    block_heights: np.ndarray
    z_start: float
    ground: Texture
    ground_x0: float  # world x of the ground texture's column 0
    facade_left: Texture
    facade_right: Texture
    sky: Texture

    def __post_init__(self) -> None:
        self.block_heights = np.asarray(self.block_heights, dtype=np.float32)
        if not self.x_left < 0 < self.x_right:
            raise ValueError(f"facades must lie on both sides of x = 0, got x_left={self.x_left}, "
                             f"x_right={self.x_right}")
        if self.block_heights.ndim != 1 or self.block_heights.size == 0 or self.block_length <= 0:
            raise ValueError("street needs a positive block_length and a non-empty 1-D block_heights")
        for side, texture in (("left", self.facade_left), ("right", self.facade_right)):
            # The renderer maps a facade's height straight to texture rows, without wrapping.
            if self.block_heights.max() > texture.size * texture.texel:
                raise ValueError(f"buildings up to {self.block_heights.max():.1f} m exceed the {side} facade "
                                 f"texture's height of {texture.size * texture.texel:.2f} m")


@dataclass(eq=False)
class SynthScene:
    """Everything needed to render a sequence: camera (K, size, poses, stamps), street and boxes."""

    name: str
    K: np.ndarray
    width: int
    height: int
    poses: np.ndarray
    stamps_ns: np.ndarray
    street: Street
    boxes: list[Box] = field(default_factory=list)

    def __post_init__(self) -> None:
        n = len(self.poses)
        if self.poses.shape != (n, 4, 4) or n == 0:
            raise ValueError(f"poses must be (N, 4, 4) with N >= 1, got {self.poses.shape}")
        if self.K.shape != (3, 3) or self.width < 16 or self.height < 16:
            raise ValueError(f"need K (3, 3) and an image of at least 16x16, got {self.K.shape}, "
                             f"{self.width}x{self.height}")
        # The renderer splits rays into per-row and per-column parts, which needs a level camera (yaw only).
        e_y = np.array([0.0, 1.0, 0.0])
        level = np.allclose(self.poses[:, :3, 1], e_y, atol=1e-9) and np.allclose(self.poses[:, 1, :3], e_y, atol=1e-9)
        if not level:
            raise ValueError("camera poses may only yaw about the vertical (world y) axis; pitch and roll are "
                             "not supported by the renderer")
        if len(self.stamps_ns) != n:
            raise ValueError(f"{len(self.stamps_ns)} stamps for {n} poses")
        ids = [b.id for b in self.boxes]
        if len(set(ids)) != len(ids):
            raise ValueError(f"box ids must be unique, got {ids}")
        for box in self.boxes:
            if len(box.yaws) != n:
                raise ValueError(f"box {box.name!r} has {len(box.yaws)} poses for {n} frames")

    @property
    def n_frames(self) -> int:
        """Number of frames (camera poses) of the scene."""
        return len(self.poses)

    def dynamic_ids(self) -> set[int]:
        """Ids of boxes that move in at least one frame."""
        return {b.id for b in self.boxes if b.moving().any()}

    def object_names(self) -> dict[int, str]:
        """Box id -> name (e.g. "car_ahead", "parked_car_1")."""
        return {b.id: b.name for b in self.boxes}

    def at_rate(self, rate_hz: float) -> SynthScene:
        """The same scene seen by a camera that runs at ``rate_hz``: the same motion per second over the same
        time, frames ``1 / rate_hz`` apart from the first one's stamp up to the last one's.

        The camera's centre and yaw and every box's centre and yaw are interpolated linearly in time between
        the scene's frames: exact for the boxes, which move at constant velocity, and for the camera's centre,
        which ``camera_poses`` steps straight from frame to frame; its yaw follows the chords of its sinusoid.
        At the scene's own rate the poses come back unchanged (to rounding). ValueError for a rate that is not positive.
        """
        check_rate(rate_hz)
        stamps = self.stamps_ns.astype(np.int64)
        step = 1e9 / rate_hz
        count = int((stamps[-1] - stamps[0]) / step + 1e-6) + 1
        new_stamps = stamps[0] + np.rint(step * np.arange(count)).astype(np.int64)
        times, new_times = (stamps - stamps[0]).astype(np.float64), (new_stamps - stamps[0]).astype(np.float64)

        def along(values: np.ndarray) -> np.ndarray:
            """(N, ...) values per frame -> (M, ...) at the new stamps, linear in time."""
            flat = values.reshape(len(values), -1)
            return np.stack([np.interp(new_times, times, column) for column in flat.T], axis=1).reshape(
                (len(new_times),) + values.shape[1:])

        yaws = np.unwrap(np.arctan2(self.poses[:, 0, 2], self.poses[:, 2, 2]))
        poses = np.tile(np.eye(4), (len(new_times), 1, 1))
        poses[:, :3, :3] = _yaw_matrix(along(yaws))
        poses[:, :3, 3] = along(self.poses[:, :3, 3])
        boxes = [replace(box, centres=along(box.centres), yaws=along(box.yaws)) for box in self.boxes]
        return replace(self, poses=poses, stamps_ns=new_stamps, boxes=boxes)


@dataclass
class SynthFrame:
    """One rendered frame with exact ground truth.

    rgb (H, W, 3) uint8; instances (H, W) int32 (0 = ground, facades, sky; box ids >= 1); dynamic (H, W) bool
    (pixels of boxes moving in this frame); depth (H, W) float32 camera z in metres (+inf for sky);
    pose (4, 4) camera-to-world; stamp_ns the frame's time.
    """

    rgb: np.ndarray
    instances: np.ndarray
    dynamic: np.ndarray
    depth: np.ndarray
    pose: np.ndarray
    stamp_ns: int


@dataclass
class SynthSequence:
    """A rendered sequence: K (3, 3), image size, frames, ids of moving boxes and every box's name."""

    K: np.ndarray
    width: int
    height: int
    frames: list[SynthFrame]
    dynamic_ids: set[int]
    object_names: dict[int, str]


# ----------------------------------------------------------------------------------------------------------
# Procedural textures (tileable: every pattern is periodic in the tile, so wrapping never shows a seam)


@functools.lru_cache(maxsize=16)
def _noise_gain(size: int, exponent: float, shortest_period: float, longest_period: float | None) -> np.ndarray:
    """Amplitude (size, size // 2 + 1) of :func:`periodic_noise`'s half spectrum (read only, cached)."""
    freq = np.hypot(np.fft.fftfreq(size)[:, None], np.fft.rfftfreq(size)[None, :]).astype(np.float32)
    band = freq <= 1.0 / shortest_period
    if longest_period is not None:
        band &= freq >= 1.0 / longest_period
    band[0, 0] = False
    gain = np.zeros_like(freq)
    gain[band] = freq[band] ** -exponent
    gain.flags.writeable = False
    return gain


def periodic_noise(rng: np.random.Generator, size: int, exponent: float, shortest_period: float = 2.0,
                   longest_period: float | None = None) -> np.ndarray:
    """Tileable band-limited noise (size, size) float32 with zero mean and unit standard deviation.

    A random complex spectrum shaped by |f|^-exponent for periods between ``shortest_period`` and
    ``longest_period`` texels, brought back by the inverse real FFT: periodic by construction of the DFT.
    """
    gain = _noise_gain(size, exponent, shortest_period, longest_period)
    spectrum = rng.standard_normal((2, *gain.shape), dtype=np.float32)
    noise = scipy.fft.irfft2((spectrum[0] + 1j * spectrum[1]) * gain, s=(size, size))
    return ((noise - noise.mean()) / max(float(noise.std()), 1e-12)).astype(np.float32)


def _grid(size: int, texel: float) -> tuple[np.ndarray, np.ndarray]:
    """Texel-centre coordinates in metres: u (1, size) along columns and v (size, 1) along rows."""
    coords = (np.arange(size, dtype=np.float32) + 0.5) * np.float32(texel)
    return coords[None, :], coords[:, None]


def _to_image(rgb: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(rgb), 0, 255).astype(np.uint8)


def _fill(rgb: np.ndarray, mask: np.ndarray, colour: np.ndarray | float) -> None:
    """Paint ``colour`` (a constant, an RGB triple or an image) into ``rgb`` (T, T, 3) where ``mask`` (T, T)."""
    colour = np.asarray(colour, dtype=np.float32)
    mask = np.broadcast_to(mask, rgb.shape[:2])
    rgb[mask] = np.broadcast_to(colour, rgb.shape)[mask] if colour.ndim == 3 else colour


def _speckle(rng: np.random.Generator, size: int, amount: float) -> np.ndarray:
    """Fine pink noise (size, size, 1) of standard deviation ``amount``: the detail trackers lock on to."""
    return (amount * periodic_noise(rng, size, 0.75, 2.0))[..., None]


def paint_ground(rng: np.random.Generator, size: int, texel: float, x0: float, x_left: float,
                 x_right: float) -> Texture:
    """Asphalt with lane markings and paved sidewalks; column a ↔ world x = x0 + a·texel, row b ↔ z = b·texel.

    Lane markings (world x): a dashed centre line at -1.75 and a solid line at +1.75; the 2 m next to each
    facade is paved with square slabs. The tile's z period (size·texel) holds a whole number of slabs and dashes.
    """
    u, v = _grid(size, texel)
    x = u + np.float32(x0)
    period = size * texel
    detail = _speckle(rng, size, 24.0)
    patches = 10.0 * periodic_noise(rng, size, 1.5, 16.0)[..., None]
    rgb = 96.0 + detail + patches + np.array([0.0, 1.0, 4.0], dtype=np.float32)
    wear = np.clip(patches / 40.0, -0.25, 0.25)
    paint = 200.0 * (1.0 + wear) + 0.3 * detail
    _fill(rgb, (np.mod(v, period / 2) < 3.0) & (np.abs(x + 1.75) < 0.07), paint)
    _fill(rgb, np.abs(x - 1.75) < 0.07, paint)
    slab = period / round(period / 0.4)
    n_slabs = round(period / slab)
    ix, iz = np.floor(x / slab), np.mod(np.floor(v / slab), n_slabs)
    slab_tone = 140.0 + 18.0 * np.sin(12.9898 * ix + 78.233 * iz)  # a fixed pseudo-random tone per slab
    grout = (np.mod(x, slab) < 0.02) | (np.mod(v, slab) < 0.02)
    paving = (np.where(grout, 80.0, slab_tone)[..., None] + 0.5 * detail) * np.array([1.0, 0.97, 0.92])
    _fill(rgb, (x < x_left + 2.0) | (x > x_right - 2.0), paving)
    return Texture(_to_image(rgb), texel)


FACADE_COLOURS = np.array([[178, 120, 96], [205, 190, 160], [150, 150, 158], [190, 165, 120], [120, 90, 80],
                           [215, 205, 190], [160, 175, 150]], dtype=np.float32)


def paint_facade(rng: np.random.Generator, size: int, texel: float, block_length: float) -> Texture:
    """Building fronts: column a ↔ z = a·texel, row b ↔ height above ground (size - b)·texel.

    Each ``block_length`` of the tile is one building with its own wall colour (bricks on every other one),
    a shop floor with wide windows and a door, and upper floors (3 m) of framed windows.
    """
    u, v = _grid(size, texel)
    height = np.float32(size * texel) - v
    period = size * texel
    n_blocks = max(1, round(period / block_length))
    block = np.minimum((u / (period / n_blocks)).astype(int), n_blocks - 1)
    along = u - block * np.float32(period / n_blocks)
    walls = FACADE_COLOURS[rng.permutation(len(FACADE_COLOURS))[np.arange(n_blocks) % len(FACADE_COLOURS)]]
    detail = _speckle(rng, size, 14.0)
    blotches = periodic_noise(rng, size, 1.3, 3.0)[..., None]
    rgb = walls[block[0]][None, :, :] * (1.0 + 0.06 * blotches) + detail
    course = np.floor(height / 0.15)
    mortar = (block % 2 == 0) & ((np.mod(height, 0.15) < 0.025)
                                 | (np.mod(along + 0.125 * np.mod(course, 2), 0.25) < 0.025))
    rgb[mortar] *= 0.72
    bay = block_length / 4
    centre = np.abs(np.mod(along, bay) - bay / 2)
    floor_h = np.mod(height - 3.5, 3.0)
    upper = (height > 3.5) & (centre < 0.6) & (floor_h > 0.9) & (floor_h < 2.5)
    frame = (height > 3.5) & (centre < 0.7) & (floor_h > 0.8) & (floor_h < 2.6) & ~upper
    shop = (height > 0.5) & (height < 3.0) & (centre < 1.0)
    door = (height < 2.4) & (np.abs(along - bay * 1.5) < 0.5)
    glass_tone = 60.0 + 25.0 * blotches + 40.0 * np.clip((floor_h[..., None] - 0.9) / 1.6, 0, 1)
    _fill(rgb, upper | shop, glass_tone * np.array([0.8, 0.9, 1.1]) + 0.7 * detail)
    _fill(rgb, frame, 225.0 + 0.3 * detail)
    _fill(rgb, door, np.array([70.0, 50.0, 40.0]) + detail)
    return Texture(_to_image(rgb), texel)


def paint_sky(size: int) -> Texture:
    """A vertical gradient from hazy horizon (row 0) to blue zenith; sampled by the sine of the elevation."""
    elevation = np.clip(np.arange(size, dtype=np.float32) / (size - 1), 0, 1)[:, None, None]
    horizon, zenith = np.array([214.0, 222.0, 232.0]), np.array([105.0, 150.0, 215.0])
    rgb = horizon + (zenith - horizon) * np.sqrt(elevation)
    return Texture(_to_image(np.broadcast_to(rgb, (size, size, 3))), 1.0)


def _face_coordinates(size: np.ndarray, tile: int,
                      texel: float) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per face of :func:`box_face_layout`: (mask (T, T), a (1, T), b (T, 1)), a, b face coordinates in metres."""
    w, h, l = (float(x) for x in size)
    u, v = _grid(tile, texel)
    extent = {"side": (l, h), "top": (l, w), "front": (w, h), "back": (w, h)}
    out = {}
    for face, (u0, v0) in box_face_layout(size).items():
        a, b = u - u0, v - v0
        out[face] = ((a >= 0) & (a < extent[face][0]) & (b >= 0) & (b < extent[face][1]), a, b)
    return out


CAR_COLOURS = np.array([[180, 30, 30], [30, 60, 160], [230, 230, 225], [75, 75, 80], [200, 160, 40],
                        [90, 130, 90], [150, 150, 160], [120, 40, 110]], dtype=np.float32)


def paint_car(rng: np.random.Generator, size: np.ndarray, tile: int = 512,
              colour: np.ndarray | None = None) -> Texture:
    """A car-like box texture: coloured body with windows, wheels, lights and fine detail (see box_face_layout).

    ``colour`` is the body's RGB; None draws one of CAR_COLOURS.
    """
    texel = box_texel(size, tile)
    w, h, l = (float(x) for x in size)
    body = CAR_COLOURS[rng.integers(len(CAR_COLOURS))] if colour is None else np.asarray(colour, np.float32)
    detail = _speckle(rng, tile, 12.0)
    glass = np.array([55.0, 65.0, 80.0], dtype=np.float32) + 2.5 * detail
    rgb = body * 0.85 + detail
    faces = _face_coordinates(size, tile, texel)
    mask, a, b = faces["side"]
    window = mask & (b > 0.08 * h) & (b < 0.42 * h) & (a > 0.22 * l) & (a < 0.8 * l)
    pillar = window & (np.abs(a - 0.52 * l) < 0.05)
    door_line = mask & (b > 0.42 * h) & (b < h - 0.3) & ((np.abs(a - 0.52 * l) < 0.012) | (np.abs(a - 0.3 * l) < 0.012))
    wheel_r = np.minimum(np.hypot(a - 0.18 * l, b - (h - 0.33)), np.hypot(a - 0.8 * l, b - (h - 0.33)))
    _fill(rgb, mask, body + detail)
    _fill(rgb, window & ~pillar, glass)
    _fill(rgb, door_line | pillar, body * 0.4)
    _fill(rgb, mask & (wheel_r < 0.33), 30.0 + detail)
    _fill(rgb, mask & (wheel_r < 0.15), 150.0 + detail)
    mask, a, b = faces["top"]
    _fill(rgb, mask, body * 1.1 + detail)
    _fill(rgb, mask & (a > 0.25 * l) & (a < 0.75 * l), body * 0.95 + detail)
    for face, lamp in (("front", (250.0, 250.0, 220.0)), ("back", (220.0, 30.0, 30.0))):
        mask, a, b = faces[face]
        _fill(rgb, mask, body * 0.75 + detail)
        _fill(rgb, mask & (b > 0.08 * h) & (b < 0.42 * h) & (a > 0.1 * w) & (a < 0.9 * w), glass)
        _fill(rgb, mask & (b > 0.5 * h) & (b < 0.62 * h) & ((a < 0.22 * w) | (a > 0.78 * w)), lamp)
        _fill(rgb, mask & (b > 0.7 * h) & (b < 0.8 * h) & (np.abs(a - 0.5 * w) < 0.26), 235.0 - detail)
    return Texture(_to_image(rgb), texel)


def paint_pedestrian(rng: np.random.Generator, size: np.ndarray, tile: int = 512) -> Texture:
    """A person-sized box: hair and face, a striped shirt and trousers (see box_face_layout)."""
    texel = box_texel(size, tile)
    h = float(size[1])
    shirt = rng.uniform(40, 220, size=3).astype(np.float32)
    trousers = rng.uniform(20, 90, size=3).astype(np.float32)
    detail = _speckle(rng, tile, 14.0)
    rgb = trousers + detail
    faces = _face_coordinates(size, tile, texel)
    for face in ("side", "front", "back"):
        mask, _, b = faces[face]
        stripes = np.where(np.mod(b, 0.12) < 0.05, 1.1, 0.8)
        _fill(rgb, mask & (b < 0.5 * h), shirt * stripes + detail)
        _fill(rgb, mask & (b < 0.14 * h), np.array([205.0, 160.0, 130.0]) + detail)
        _fill(rgb, mask & (b < 0.05 * h), np.array([50.0, 35.0, 25.0]) + detail)
    return Texture(_to_image(rgb), texel)


def paint_post(rng: np.random.Generator, size: np.ndarray, tile: int = 512) -> Texture:
    """A pole, bollard or bin: banded metal with fine noise (see box_face_layout)."""
    texel = box_texel(size, tile)
    base = rng.uniform(60, 200, size=3).astype(np.float32)
    bands = np.where(np.mod(_grid(tile, texel)[1], 0.5) < 0.25, 1.0, 0.6).astype(np.float32)[..., None]
    return Texture(_to_image(base * bands + _speckle(rng, tile, 20.0)), texel)


# ----------------------------------------------------------------------------------------------------------
# Renderer


def _mip_row(level: int | np.ndarray) -> int | np.ndarray:
    """First atlas row of mip ``level``: Σ_{k<l} (T_max / 2^k + 1) = 2 T_max (1 - 2^-l) + l."""
    return 2 * _ATLAS_TILE - (2 * _ATLAS_TILE) * 2.0 ** -np.asarray(level) + level


class _Atlas:
    """All textures with their mipmaps in one image, laid out so that one multiply finds any level.

    Level l of every texture lives in the row band starting at :func:`_mip_row` (l); texture i starts at column
    C_i 2^-l, with C_i a multiple of 2^MAX and 2^MAX spare columns between textures. A point at level-0
    atlas column C_i + a and tile row b (texels, a, b ∈ [0, T_i)) is therefore at column (C_i + a) 2^-l and
    row _mip_row(l) + b 2^-l at level l. Each level carries one extra wrapped row and column, so a bilinear
    look-up just below T_i 2^-l reads the tile's first texel as its neighbour.
    """

    def __init__(self, textures: Sequence[Texture]) -> None:
        self.columns: dict[int, int] = {}
        unique: list[Texture] = []
        for texture in textures:
            if id(texture) not in self.columns:
                self.columns[id(texture)] = sum(t.size + (1 << _MAX_LEVEL) for t in unique)
                unique.append(texture)
        width = sum(t.size + (1 << _MAX_LEVEL) for t in unique)
        # RGBA although alpha is unused: OpenCV's remap runs faster on 4 channels than on 3.
        self.image = np.zeros((int(_mip_row(_MAX_LEVEL + 1)), width, 4), dtype=np.uint8)
        if max(self.image.shape[:2]) >= 32767:
            raise ValueError(f"texture atlas {self.image.shape[:2]} exceeds OpenCV's remap limit; use fewer "
                             "or smaller textures")
        for texture in unique:
            level_image = cv2.cvtColor(texture.image, cv2.COLOR_RGB2RGBA)
            for level in range(_MAX_LEVEL + 1):
                row, col, n = int(_mip_row(level)), self.columns[id(texture)] >> level, level_image.shape[0]
                self.image[row:row + n + 1, col:col + n + 1] = np.pad(level_image, ((0, 1), (0, 1), (0, 0)),
                                                                       mode="wrap")
                level_image = cv2.resize(level_image, (n // 2, n // 2), interpolation=cv2.INTER_AREA)

    def column(self, texture: Texture) -> float:
        """Level-0 atlas column C_i of a texture."""
        return float(self.columns[id(texture)])

    def shade(self, surface: _Surface) -> np.ndarray:
        """Trilinear texture look-up: bilinear in the two mip levels around each pixel's level, blended.

        Level l: atlas column a 2^-l, row _mip_row(l) + b 2^-l (see _Atlas); level l + 1 halves both offsets
        and starts T_max 2^-l + 1 rows further down. ``surface`` is consumed (its arrays are reused).
        """
        level = np.clip(surface.level, 0, _MAX_LEVEL, out=surface.level)
        low = np.floor(level)
        frac = level - low
        scale = np.exp2(-low)
        x = surface.a * scale
        b = surface.b
        b *= scale
        row = scale * np.float32(-2 * _ATLAS_TILE)
        row += low
        row += np.float32(2 * _ATLAS_TILE)
        y = b + row
        fine = cv2.remap(self.image, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        x *= 0.5
        b *= 0.5
        scale *= np.float32(_ATLAS_TILE)
        row += scale
        row += 1.0
        np.add(b, row, out=y)
        coarse = cv2.remap(self.image, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        # Blending 3 channels is cheaper than dropping alpha after blending 4.
        return cv2.blendLinear(cv2.cvtColor(fine, cv2.COLOR_RGBA2RGB), cv2.cvtColor(coarse, cv2.COLOR_RGBA2RGB),
                               1.0 - frac, frac)


@dataclass
class _Surface:
    """Per-pixel shading inputs of the nearest hit so far, all (H, W) float32 except ids (int32).

    depth: camera z (inf = sky); a: level-0 atlas column (texture column C_i + texel column in [0, T_i));
    b: texel row in [0, T_i); level: mip level (any real; clipped when shading); ids: box id, 0 = static.
    """

    depth: np.ndarray
    a: np.ndarray
    b: np.ndarray
    level: np.ndarray
    ids: np.ndarray


def _wrap(x: np.ndarray, period: float) -> np.ndarray:
    """x mod period, in place (floor division keeps the result in [0, period) also for negative x)."""
    q = np.floor(x * np.float32(1.0 / period))
    q *= np.float32(period)
    x -= q
    return x


def _full(values: np.ndarray, shape: tuple[int, int], axis: int) -> np.ndarray:
    """A contiguous float32 image (H, W) repeating per-row (axis 0) or per-column (axis 1) ``values``."""
    out = np.empty(shape, dtype=np.float32)
    out[...] = values[:, None] if axis == 0 else values[None, :]
    return out


class StreetRenderer:
    """Renders frames of a :class:`SynthScene`; textures are packed and ray tables built once.

    Camera and boxes only yaw about the vertical, so every ray direction splits into a per-row part (its
    vertical component d_y = (v - c_y) / f_y, the same in camera, world and box frames) and a per-column
    part (its horizontal components, a rotation of ((u - c_x) / f_x, 1)). Plane and slab intersections then
    cost one value per row or per column, and only their combinations are full images.
    """

    def __init__(self, scene: SynthScene, *, mip_bias: float = 0.5) -> None:
        self.scene = scene
        street = scene.street
        self.atlas = _Atlas([street.ground, street.facade_left, street.facade_right, street.sky]
                            + [b.texture for b in scene.boxes])
        K = scene.K
        self.fx = float(K[0, 0])
        self.xn = (np.arange(scene.width) - K[0, 2]) / K[0, 0]  # (W,)
        self.dy = (np.arange(scene.height) - K[1, 2]) / K[1, 1]  # (H,)
        self.shape = (scene.height, scene.width)
        # Footprint of a pixel on a surface at depth s (module docstring): s |d|^½ / (f texel |d·n|^½) with
        # d = K⁻¹ (u, v, 1); the ½ log2 |d| term is fixed per pixel, the mip bias trades blur for aliasing.
        norm2 = 1.0 + self.xn[None, :] ** 2 + self.dy[:, None] ** 2
        self.level_base = (0.25 * np.log2(norm2) + mip_bias).astype(np.float32)
        self._moving = np.zeros((max([b.id for b in scene.boxes], default=0) + 1, scene.n_frames), dtype=bool)
        for box in scene.boxes:
            self._moving[box.id] = box.moving()
        # Box tables, indexed [frame, box] or [box]: rotations (N, B, 3, 3), centres (N, B, 3), corners
        # (N, B, 8, 3) in world coordinates, half sizes (B, 3), texture atlas columns and texels, ids.
        boxes, n = scene.boxes, scene.n_frames
        self._rotations = np.stack([b.rotations() for b in boxes], axis=1) if boxes else np.zeros((n, 0, 3, 3))
        self._centres = np.stack([b.centres for b in boxes], axis=1) if boxes else np.zeros((n, 0, 3))
        self._corners = np.stack([b.corners() for b in boxes], axis=1) if boxes else np.zeros((n, 0, 8, 3))
        self._half = np.array([b.size / 2 for b in boxes]).reshape(-1, 3)
        self._column = np.array([self.atlas.column(b.texture) for b in boxes])
        self._texel = np.array([b.texture.texel for b in boxes])
        self._ids = np.array([b.id for b in boxes], dtype=np.int32)
        elevation = np.clip(-self.dy / np.sqrt(1.0 + self.dy ** 2), 0.0, 1.0)
        self._sky_b = elevation * (street.sky.size - 1)

    def _footprint_level(self, depth: np.ndarray, texel: float | np.ndarray, cos_axis: np.ndarray) -> np.ndarray:
        """log2(depth / (f texel)) - ½ log2 |d·n|: the per-row or per-column part of the mip level."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.log2(depth / (self.fx * texel)) - 0.5 * np.log2(np.abs(cos_axis))

    # -- geometry -------------------------------------------------------------------------------------

    def _static(self, R: np.ndarray, centre: np.ndarray) -> _Surface:
        """Ground, facades and sky for every pixel."""
        st = self.scene.street
        g, sky, fl, fr = st.ground, st.sky, st.facade_left, st.facade_right
        ox, oy, oz = (float(x) for x in centre)
        dx = R[0, 0] * self.xn + R[0, 2]
        dz = R[2, 0] * self.xn + R[2, 2]
        dy = self.dy
        with np.errstate(divide="ignore", invalid="ignore"):
            # Per row: the ground y = 0 at s = -o_y / d_y where the ray points down, else sky.
            down = dy > 0
            s_ground = np.where(down, -oy / dy, np.inf)
            gain = np.where(down, s_ground / g.texel, 0.0)
            a_offset = np.where(down, (ox - st.ground_x0) / g.texel, 0.0)
            b_offset = np.where(down, oz / g.texel, self._sky_b)
            row_column = np.where(down, self.atlas.column(g), self.atlas.column(sky))
            row_level = np.where(down, self._footprint_level(s_ground, g.texel, dy), -np.inf)
            # Per column: the facade x = x_left or x_right at s = (x_f - o_x) / d_x, over y ∈ [-h_block, 0).
            right = dx > 0
            f_texel = np.where(right, fr.texel, fl.texel)
            f_size = np.where(right, fr.size, fl.size)
            s_facade = np.where(right, st.x_right - ox, st.x_left - ox) / dx
            z_facade = oz + s_facade * dz
            block = np.floor((z_facade - st.z_start) / st.block_length)
            inside = np.isfinite(block) & (block >= 0) & (block < len(st.block_heights))
            block_height = np.where(inside, st.block_heights[np.where(inside, block, 0).astype(np.intp)], 0.0)
            # Facade rows: o_y + s d_y ∈ [-h_block, 0) <=> d_y ∈ [(-h_block - o_y) / s, -o_y / s).
            lo = ((-block_height - oy) / s_facade).astype(np.float32)
            hi = (-oy / s_facade).astype(np.float32)
            col_a = np.mod(z_facade / f_texel, f_size) + np.where(right, self.atlas.column(fr), self.atlas.column(fl))
            col_level = self._footprint_level(s_facade, f_texel, dx)
        f32 = np.float32
        facade = ((dy.astype(f32)[:, None] >= lo[None, :]) & (dy.astype(f32)[:, None] < hi[None, :])).view(np.uint8)
        shape = self.shape
        depth = cv2.copyTo(_full(s_facade, shape, 1), facade, _full(s_ground, shape, 0))
        # Ground texel coordinates (x - x0, z) / texel = gain (d_x, d_z) + offsets; sky rows have gain 0.
        gain = gain.astype(f32)[:, None]
        a = _wrap(gain * dx.astype(f32) + a_offset.astype(f32)[:, None], g.size)
        a += row_column.astype(f32)[:, None]
        a = cv2.copyTo(_full(col_a, shape, 1), facade, a)
        b = _wrap(gain * dz.astype(f32) + b_offset.astype(f32)[:, None], g.size)
        # Facade texel row: y / texel + T, in [0, T) because facades are at most one tile tall.
        b_facade = dy.astype(f32)[:, None] * (s_facade / f_texel).astype(f32) + (oy / f_texel + f_size).astype(f32)
        b = cv2.copyTo(b_facade, facade, b)
        level = cv2.copyTo(_full(col_level, shape, 1), facade, _full(row_level, shape, 0))
        level += self.level_base
        return _Surface(depth=depth, a=a, b=b, level=level, ids=np.zeros(shape, dtype=np.int32))

    def _box_rects(self, t: int, R: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel rectangles of all boxes at frame t: (B, 4) int rows [r0, r1) and columns [c0, c1), their
        nearest camera depth (B,) and whether each box can be seen at all (B,) bool.

        Corners behind the near plane are replaced by the points where the box's edges cross it, so each
        rectangle bounds the visible part of its (convex) box exactly.
        """
        cam = (self._corners[t] - centre) @ R  # (B, 8, 3) camera coordinates R^T (X - c)
        i, j = _BOX_EDGES
        ci, cj = cam[:, i], cam[:, j]  # (B, 12, 3) edge end points
        with np.errstate(divide="ignore", invalid="ignore"):
            cut = ((_NEAR - ci[..., 2]) / (cj[..., 2] - ci[..., 2]))[..., None]
            points = np.concatenate([cam, ci + cut * (cj - ci)], axis=1)  # (B, 20, 3); edge points may be nan
        front = cam[..., 2] > _NEAR
        valid = np.concatenate([front, front[:, i] != front[:, j]], axis=1)
        z = np.where(valid, points[..., 2], np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (points @ self.scene.K.T)[..., :2] / points[..., 2:3]
        low = np.floor(np.where(valid[..., None], uv, np.inf).min(axis=1))
        high = np.ceil(np.where(valid[..., None], uv, -np.inf).max(axis=1)) + 1
        H, W = self.shape
        seen = valid.any(axis=1)
        rects = np.zeros((len(cam), 4), dtype=np.int64)
        rects[seen] = np.stack([np.clip(low[seen, 1], 0, H), np.clip(high[seen, 1], 0, H),
                                np.clip(low[seen, 0], 0, W), np.clip(high[seen, 0], 0, W)], axis=1)
        seen &= (rects[:, 0] < rects[:, 1]) & (rects[:, 2] < rects[:, 3])
        return rects, z.min(axis=1), seen

    def _boxes(self, t: int, surface: _Surface, R: np.ndarray, centre: np.ndarray) -> None:
        """Draw every box seen at frame t into ``surface`` (nearest hit wins, per pixel)."""
        rects, nearest, seen = self._box_rects(t, R, centre)
        for n in np.flatnonzero(seen):
            r0, r1, c0, c1 = (int(x) for x in rects[n])
            if nearest[n] < surface.depth[r0:r1, c0:c1].max():  # else hidden behind what is already drawn
                self._box(n, t, (slice(r0, r1), slice(c0, c1)), surface, R, centre)

    def _box(self, n: int, t: int, view: tuple[slice, slice], surface: _Surface, R: np.ndarray,
             centre: np.ndarray) -> None:
        """Slab-test box n against the rays of its rectangle ``view`` and write nearer hits into ``surface``.

        In box coordinates a ray is o + s d with d = R_y(ψ_cam - ψ_box) (x_n, y_n, 1); the slab of axis k is
        entered at min((±half_k - o_k) / d_k) and left at the max, and the box is hit where the latest entry
        precedes the earliest exit (Kay and Kajiya 1986). The y slab depends on the row only and the x and z
        slabs on the column only: they are computed per row and per column, and combined as outer max / min.
        """
        rotation = self._rotations[t, n]
        rel = rotation.T @ R  # camera-to-box rotation, a yaw
        o = rotation.T @ (centre - self._centres[t, n])  # camera centre in box coordinates
        half = self._half[n]
        xn, dy = self.xn[view[1]], self.dy[view[0]]
        d_x = rel[0, 0] * xn + rel[0, 2]
        d_z = rel[2, 0] * xn + rel[2, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x1, x2 = (-half[0] - o[0]) / d_x, (half[0] - o[0]) / d_x
            y1, y2 = (-half[1] - o[1]) / dy, (half[1] - o[1]) / dy
            z1, z2 = (-half[2] - o[2]) / d_z, (half[2] - o[2]) / d_z
        enter_x, enter_z = np.minimum(x1, x2), np.minimum(z1, z2)
        enter_xz = np.maximum(enter_x, enter_z).astype(np.float32)
        leave_xz = np.minimum(np.maximum(x1, x2), np.maximum(z1, z2)).astype(np.float32)
        enter_y, leave_y = np.minimum(y1, y2).astype(np.float32), np.maximum(y1, y2).astype(np.float32)
        t_in = np.maximum(enter_y[:, None], enter_xz)
        depth = surface.depth[view]
        hit = (t_in <= np.minimum(leave_y[:, None], leave_xz)) & (t_in > 0) & (t_in < depth)
        if not hit.any():
            return
        # The slab entered last names the face; face coordinates in metres follow box_face_layout.
        y_face = enter_y[:, None] >= enter_xz
        x_face = enter_x >= enter_z
        w, h, l = 2.0 * half
        qx = t_in * d_x.astype(np.float32) + np.float32(o[0] + w / 2)
        qy = t_in * dy[:, None].astype(np.float32) + np.float32(o[1] + h / 2)
        qz = t_in * d_z.astype(np.float32) + np.float32(o[2] + l / 2)
        # Sides (z, y); roof (z, x + h + 0.1); front (x, y + h + w + 0.2), back (x + w + 0.1, same).
        a = np.where(y_face | x_face, qz, qx + np.where(qz > l / 2, np.float32(0.0), np.float32(w + 0.1)))
        b = np.where(y_face, qx + np.float32(h + 0.1), qy + np.where(x_face, np.float32(0.0), np.float32(h + w + 0.2)))
        texel = np.float32(self._texel[n])
        a /= texel
        a += np.float32(self._column[n])
        b /= texel
        cos_axis = np.where(y_face, dy[:, None], np.where(x_face, d_x, d_z)).astype(np.float32)
        level = self._footprint_level(t_in, texel, cos_axis).astype(np.float32)
        level += self.level_base[view]
        mask = hit.view(np.uint8)
        cv2.copyTo(t_in, mask, depth)
        cv2.copyTo(a, mask, surface.a[view])
        cv2.copyTo(b, mask, surface.b[view])
        cv2.copyTo(level, mask, surface.level[view])
        cv2.copyTo(np.full(hit.shape, self._ids[n], dtype=np.int32), mask, surface.ids[view])

    def render(self, t: int) -> SynthFrame:
        """Render frame ``t`` with its ground truth."""
        scene = self.scene
        if not 0 <= t < scene.n_frames:
            raise ValueError(f"frame index {t} outside [0, {scene.n_frames})")
        pose = scene.poses[t]
        R, centre = pose[:3, :3], pose[:3, 3]
        surface = self._static(R, centre)
        self._boxes(t, surface, R, centre)
        depth, ids = surface.depth, surface.ids
        rgb = self.atlas.shade(surface)
        return SynthFrame(rgb=rgb, instances=ids, dynamic=self._moving[:, t][ids], depth=depth,
                          pose=pose.copy(), stamp_ns=int(scene.stamps_ns[t]))


def render_frames(scene: SynthScene) -> Iterator[SynthFrame]:
    """Render the scene's frames one by one (memory stays bounded by one frame)."""
    renderer = StreetRenderer(scene)
    for t in range(scene.n_frames):
        yield renderer.render(t)


# ----------------------------------------------------------------------------------------------------------
# Bags


def write_frames(frames: Iterable[SynthFrame], K: np.ndarray, width: int, height: int, path: str | Path, *,
                 start_ns: int | None = None) -> dict[str, int]:
    """Write frames to a rosbag2 MCAP folder at ``path`` (see :func:`write_bag`); returns messages per topic."""
    from moseg_ros.io.bag_writer import BagWriter

    offset = None
    with BagWriter(path, storage="mcap") as writer:
        for frame in frames:
            if frame.rgb.shape != (height, width, 3):
                raise ValueError(f"frame of shape {frame.rgb.shape} in a {width}x{height} sequence")
            if offset is None:
                offset = 0 if start_ns is None else int(start_ns) - frame.stamp_ns
            stamp = frame.stamp_ns + offset
            writer.write_image(GT_TOPICS["image"], stamp, CAMERA_FRAME, frame.rgb, "rgb8")
            writer.write_camera_info(GT_TOPICS["camera_info"], stamp, CAMERA_FRAME, K, width, height)
            writer.write_image(GT_TOPICS["instances"], stamp, CAMERA_FRAME, frame.instances, "32SC1")
            writer.write_image(GT_TOPICS["dynamic_mask"], stamp, CAMERA_FRAME,
                               frame.dynamic.astype(np.uint8) * np.uint8(255), "mono8")
            writer.write_image(GT_TOPICS["depth"], stamp, CAMERA_FRAME, frame.depth, "32FC1")
            writer.write_pose(GT_TOPICS["pose"], stamp, WORLD_FRAME, frame.pose)
        return dict(writer.counts)


def write_bag(sequence: SynthSequence, path: str | Path, *, start_ns: int | None = None) -> dict[str, int]:
    """Write a sequence as a rosbag2 MCAP folder; returns the number of messages per topic.

    Topics (all stamps of a frame identical, frame_id "camera" except the pose's "world"):
    /camera/image_raw (rgb8), /camera/camera_info, /gt/instances (32SC1), /gt/dynamic_mask (mono8,
    255 = moving), /gt/depth (32FC1, metres, +inf = sky), /gt/pose (geometry_msgs/PoseStamped, camera-to-world).
    ``start_ns`` shifts all stamps so that the first frame has it; None keeps the frames' stamps.
    """
    return write_frames(sequence.frames, sequence.K, sequence.width, sequence.height, path, start_ns=start_ns)
