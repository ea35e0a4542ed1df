"""Writing rosbag2 bags (``BagWriter``) with rosbags: CDR messages and ros2msg schemas of ROS 2 Jazzy.

The bag opens in rosbags, the mcap library, Foxglove and ``ros2 bag``. MCAP output is chunk-compressed with zstd
(chunks of about 1 MiB, written as they fill), so a run that is killed leaves every complete chunk readable.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from moseg_ros.io.image import (
    array_to_image_fields,
)
from moseg_ros.io.bags import IMAGE_TYPE, ns_to_stamp_fields


_STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
_COMPRESSIONS = (None, "zstd")


def _rotation_quaternion_xyzw(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a 3x3 rotation; ValueError if it is not a rotation."""
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-5) or np.linalg.det(rotation) < 0:
        raise ValueError(f"pose rotation is not a proper rotation matrix:\n{rotation}")
    return Rotation.from_matrix(rotation).as_quat()


class BagWriter:
    """Write a rosbag2 folder; connections are created on the first write to each topic.

    Use as a context manager (or call :meth:`close`): metadata.yaml is written on close, also when the
    ``with`` body raised, so whatever was written stays readable. ``typestore`` (ROS 2 Jazzy) builds
    messages for :meth:`write`; ``counts`` holds messages written per topic.
    """

    def __init__(self, path: str | Path, *, storage: str = "mcap", compression: str | None = "zstd") -> None:
        path = Path(path)
        if storage not in _STORAGES:
            raise ValueError(f"unknown bag storage {storage!r}; use one of {sorted(_STORAGES)}")
        if compression not in _COMPRESSIONS:
            raise ValueError(f"unknown bag compression {compression!r}; use one of {_COMPRESSIONS}")
        if path.exists():
            raise FileExistsError(f"output bag already exists (not overwriting): {path}")
        if not path.parent.is_dir():
            raise FileNotFoundError(f"parent folder of the output bag does not exist: {path.parent}")
        self.path = path
        self.storage = storage
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self.counts: dict[str, int] = {}
        self._connections: dict[str, Any] = {}
        # Metadata version 9 is what Jazzy's rosbag2 writes.
        self._writer = Writer(path, version=9, storage_plugin=_STORAGES[storage])
        if compression is not None and storage == "mcap":
            # Storage-level compression is MCAP's own chunk compression (as ros2 bag's mcap plugin writes it):
            # each chunk stands alone, unlike file compression, which a killed run leaves unreadable.
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Finish the bag (summary, metadata.yaml); further writes raise."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def _connection(self, topic: str, msgtype: str) -> Any:
        if self._writer is None:
            raise ValueError(f"bag {self.path} is closed")
        connection = self._connections.get(topic)
        if connection is None:
            if msgtype not in self.typestore.types:
                raise ValueError(f"unknown message type {msgtype!r} for topic {topic!r} (not in ROS 2 Jazzy)")
            connection = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
            self._connections[topic] = connection
            self.counts[topic] = 0
        elif connection.msgtype != msgtype:
            raise ValueError(f"topic {topic!r} already holds {connection.msgtype}, cannot write {msgtype}")
        return connection

    def write_serialized(self, topic: str, msgtype: str, data: bytes | memoryview, log_time_ns: int) -> None:
        """Write an already CDR-serialized message (e.g. from rclpy's serialize_message or a raw subscription)."""
        self._writer.write(self._connection(topic, msgtype), int(log_time_ns), data)
        self.counts[topic] += 1

    def write(self, topic: str, msgtype: str, msg: Any, log_time_ns: int) -> None:
        """Serialize a typestore message ``msg`` of type ``msgtype`` (e.g. "std_msgs/msg/String") and write it."""
        connection = self._connection(topic, msgtype)
        self._writer.write(connection, int(log_time_ns), self.typestore.serialize_cdr(msg, msgtype))
        self.counts[topic] += 1

    def header(self, stamp_ns: int, frame_id: str) -> Any:
        """A std_msgs/Header of this typestore."""
        sec, nanosec = ns_to_stamp_fields(stamp_ns)
        types = self.typestore.types
        return types["std_msgs/msg/Header"](
            stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id)

    def write_image(self, topic: str, stamp_ns: int, frame_id: str, array: np.ndarray, encoding: str, *,
                    log_time_ns: int | None = None) -> None:
        """Write a sensor_msgs/Image of ``array`` (H, W) or (H, W, C), which must fit ``encoding``.

        The log time defaults to the stamp (as for every write_* helper).
        """
        msg = self.typestore.types[IMAGE_TYPE](header=self.header(stamp_ns, frame_id),
                                               **array_to_image_fields(array, encoding))
        self.write(topic, IMAGE_TYPE, msg, stamp_ns if log_time_ns is None else log_time_ns)

    def write_camera_info(self, topic: str, stamp_ns: int, frame_id: str, K: np.ndarray, width: int, height: int,
                          *, D: np.ndarray | None = None, P: np.ndarray | None = None,
                          log_time_ns: int | None = None) -> None:
        """Write a sensor_msgs/CameraInfo: K (3, 3), D (plumb_bob, 5 zeros by default), P (3, 4), default [K | 0]."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"K must be 3x3, got shape {K.shape}")
        P = np.hstack([K, np.zeros((3, 1))]) if P is None else np.asarray(P, dtype=np.float64)
        if P.shape != (3, 4):
            raise ValueError(f"P must be 3x4, got shape {P.shape}")
        D = np.zeros(5) if D is None else np.asarray(D, dtype=np.float64).reshape(-1)
        if width <= 0 or height <= 0:
            raise ValueError(f"camera_info size must be positive, got {width}x{height}")
        types = self.typestore.types
        msg = types["sensor_msgs/msg/CameraInfo"](
            header=self.header(stamp_ns, frame_id), height=int(height), width=int(width),
            distortion_model="plumb_bob" if D.size in (5, 0) else "rational_polynomial",
            d=D, k=K.reshape(-1), r=np.eye(3).reshape(-1), p=P.reshape(-1), binning_x=0, binning_y=0,
            roi=types["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
        self.write(topic, "sensor_msgs/msg/CameraInfo", msg, stamp_ns if log_time_ns is None else log_time_ns)

    def write_pose(self, topic: str, stamp_ns: int, frame_id: str, T: np.ndarray, *,
                   log_time_ns: int | None = None) -> None:
        """Write a geometry_msgs/PoseStamped of a 4x4 camera-to-world transform T (frame_id = the world frame)."""
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"pose must be a 4x4 matrix, got shape {T.shape}")
        x, y, z, w = _rotation_quaternion_xyzw(T[:3, :3])
        types = self.typestore.types
        pose = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
            orientation=types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w)))
        msg = types["geometry_msgs/msg/PoseStamped"](header=self.header(stamp_ns, frame_id), pose=pose)
        self.write(topic, "geometry_msgs/msg/PoseStamped", msg, stamp_ns if log_time_ns is None else log_time_ns)
