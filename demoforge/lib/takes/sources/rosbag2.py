"""ROS 2 bags (``.mcap``, ``.db3``, or the bag folder with ``metadata.yaml``) read with ``rosbags``.

Colour: ``sensor_msgs/msg/Image`` (rgb8, bgr8, rgba8, bgra8, mono8) or ``CompressedImage`` (JPEG/PNG);
depth: ``Image`` registered to the colour image (``16UC1`` millimetres, or ``depth_scale`` metres per
unit from ``source.json``; ``32FC1`` metres), e.g. the RealSense ROS driver's
``/camera/aligned_depth_to_color/image_raw``; intrinsics: ``sensor_msgs/msg/CameraInfo`` of the colour
camera. The topics are found from the bag's topic list (``--rgb-topic``, ``--depth-topic``,
``--info-topic`` choose others). Colour and depth are paired by their header stamps: each colour frame
takes the nearest depth frame within the pairing tolerance (half a frame period unless
``pairing_tolerance_s`` is given); the tolerance and the pairs' offsets are in the take's notes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator

import numpy as np

from demoforge.lib.takes.sources.recording import (
    Recording, RecordingIndex, RecordingSource, place_on_time_axis,
)
from demoforge.lib.takes.types import TakeError

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _open_reader(path: Path):
    from rosbags.rosbag2 import Reader

    try:
        reader = Reader(path)
        reader.open()
    except Exception as e:  # noqa: BLE001 - rosbags raises several kinds for a damaged bag
        raise TakeError(f"{path}: cannot open the ROS 2 bag ({type(e).__name__}: {e}); the file is truncated or "
                        f"corrupt, or not a bag") from None
    return reader


def choose_topics(topics: dict[str, str], options: dict, what: str) -> tuple[str, str, str | None, list[str]]:
    """(colour, depth, camera-info topic, notes) from {topic: msgtype} and the user's choices."""
    images = [t for t, m in topics.items() if m in (IMAGE, COMPRESSED)]
    listing = ", ".join(f"{t} ({m.rsplit('/', 1)[-1]})" for t, m in sorted(topics.items()))
    notes = []

    def pick(key: str, candidates: list[str], score, kind: str) -> str | None:
        given = options.get(key)
        if given:
            if given not in topics:
                raise TakeError(f"{what}: --{key.replace('_', '-')} {given} is not in the bag; its topics: {listing}")
            return given
        if not candidates:
            return None
        best = sorted(candidates, key=lambda t: (-score(t), t))
        if len(best) > 1:
            notes.append(f"{kind} topic {best[0]} chosen from {', '.join(best)} (another with --{key.replace('_', '-')})")
        return best[0]

    depth_like = [t for t in images if "depth" in t.lower()]
    colour_like = [t for t in images if t not in depth_like]
    rgb = pick("rgb_topic", colour_like,
               lambda t: ("color" in t or "rgb" in t) * 4 + ("rect" in t) + (topics[t] == IMAGE), "colour")
    if rgb is None:
        raise TakeError(f"{what}: no colour image topic (sensor_msgs/Image or CompressedImage) in the bag; its "
                        f"topics: {listing}")
    depth = pick("depth_topic", [t for t in depth_like if topics[t] == IMAGE],
                 lambda t: ("aligned" in t) * 4 + ("color" in t) * 2 + ("raw" in t), "depth")
    if depth is None:
        raise TakeError(f"{what}: no depth topic (sensor_msgs/Image, 16UC1 mm or 32FC1 m, aligned to the colour "
                        f"image) in the bag; record it (e.g. the RealSense driver's "
                        f"/camera/aligned_depth_to_color/image_raw) or name it with --depth-topic; its topics: {listing}")
    ns = rgb.rsplit("/", 1)[0]
    info = pick("info_topic", [t for t, m in topics.items() if m == CAMERA_INFO],
                lambda t: (t.startswith(ns)) * 4 + ("color" in t or "rgb" in t) * 2 - ("depth" in t), "camera info")
    return rgb, depth, info, notes


def pair_by_stamp(rgb_ns: np.ndarray, depth_ns: np.ndarray, tolerance_ns: float) -> tuple[np.ndarray, np.ndarray]:
    """For each colour stamp the index of the nearest depth stamp (-1 beyond the tolerance) and |dt| (ns)."""
    if depth_ns.size == 0:
        return np.full(rgb_ns.shape, -1), np.full(rgb_ns.shape, np.inf)
    order = np.argsort(depth_ns)
    d = depth_ns[order]
    pos = np.clip(np.searchsorted(d, rgb_ns), 1, max(len(d) - 1, 1))
    left = np.clip(pos - 1, 0, len(d) - 1)
    right = np.clip(pos, 0, len(d) - 1)
    use_right = np.abs(d[right] - rgb_ns) < np.abs(d[left] - rgb_ns)
    best = np.where(use_right, right, left)
    dt = np.abs(d[best] - rgb_ns).astype(float)
    return np.where(dt <= tolerance_ns, order[best], -1), dt


class RosBag2Recording(Recording):
    version = "1"

    def build_index(self) -> RecordingIndex:
        ts = _typestore()
        reader = _open_reader(self.path)
        try:
            topics = {t: info.msgtype or "" for t, info in reader.topics.items()}
            rgb, depth, info_topic, notes = choose_topics(topics, self.options, str(self.path))
            conns = [c for c in reader.connections if c.topic in (rgb, depth, info_topic)]
            stamps: dict[str, list[tuple[int, int]]] = {rgb: [], depth: []}
            info_msg, size, depth_meta = None, {}, {}
            try:
                for conn, bag_ns, raw in reader.messages(connections=conns):
                    msg = ts.deserialize_cdr(raw, conn.msgtype)
                    if conn.topic == info_topic:
                        info_msg = info_msg or msg
                        continue
                    stamps[conn.topic].append((msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, bag_ns))
                    if conn.topic not in size:
                        size[conn.topic] = _image_size(msg)
                        if conn.topic == depth:
                            depth_meta = {"encoding": msg.encoding}
            except Exception as e:  # noqa: BLE001 - a cut or damaged bag fails part-way
                raise TakeError(f"{self.path}: the ROS 2 bag cannot be read to the end ({type(e).__name__}: {e}); "
                                f"the file is truncated or corrupt") from None
        finally:
            reader.close()
        return self._index(rgb, depth, info_topic, stamps, size, info_msg, depth_meta, notes)

    def _index(self, rgb, depth, info_topic, stamps, size, info_msg, depth_meta, notes) -> RecordingIndex:
        what = str(self.path)
        if not stamps[rgb]:
            raise TakeError(f"{what}: the colour topic {rgb} has no messages")
        if depth_meta.get("encoding") not in ("16UC1", "mono16", "32FC1"):
            raise TakeError(f"{what}: depth topic {depth} has encoding {depth_meta.get('encoding')!r}; need 16UC1 "
                            f"(millimetres) or 32FC1 (metres)")
        w, h = size[rgb]
        if size.get(depth) and tuple(size[depth]) != (w, h):
            raise TakeError(f"{what}: depth topic {depth} is {size[depth][0]} x {size[depth][1]} but the colour "
                            f"{rgb} is {w} x {h}; record depth aligned to the colour image "
                            f"(aligned_depth_to_color) or choose it with --depth-topic")
        if info_msg is None:
            raise TakeError(f"{what}: no sensor_msgs/CameraInfo topic for the colour camera; record it (e.g. "
                            f"{rgb.rsplit('/', 1)[0]}/camera_info) or name it with --info-topic")
        K = np.asarray(info_msg.k, float).reshape(3, 3)
        if (int(info_msg.width), int(info_msg.height)) not in ((w, h), (0, 0)):
            raise TakeError(f"{what}: camera info {info_topic} is for {info_msg.width} x {info_msg.height} but the "
                            f"colour images are {w} x {h}; choose the colour camera's info with --info-topic")
        rgb_st = np.array(stamps[rgb], np.int64)
        dep_st = np.array(stamps[depth], np.int64).reshape(-1, 2)
        times = (rgb_st[:, 0] - rgb_st[:, 0].min()) / 1e9
        period = float(np.median(np.diff(np.sort(rgb_st[:, 0])))) if len(rgb_st) > 1 else 1e9 / 30
        tol = float(self.options.get("pairing_tolerance_s") or period / 2e9) * 1e9
        match, dt = pair_by_stamp(rgb_st[:, 0], dep_st[:, 0], tol)
        keys = [[int(rgb_st[j, 1]), int(dep_st[match[j], 1]) if match[j] >= 0 else None] for j in range(len(rgb_st))]
        fps, stamps_s, keys, status, message = place_on_time_axis(times, keys, None, what)
        for i, k in enumerate(keys):
            if k is not None and k[1] is None:
                status[i], message[i] = "missing_depth", f"no depth frame within {tol / 1e6:.1f} ms of the colour frame"
        paired = dt[match >= 0]
        notes.append(f"colour {rgb} and depth {depth} paired by header stamp within {tol / 1e6:.1f} ms: "
                     f"{paired.size} of {len(rgb_st)} colour frames paired, offset median "
                     f"{np.median(paired) / 1e6 if paired.size else float('nan'):.2f} ms, max "
                     f"{paired.max() / 1e6 if paired.size else float('nan'):.2f} ms")
        info = {"format": "rosbag2", "rgb_topic": rgb, "depth_topic": depth, "info_topic": info_topic,
                "depth_encoding": depth_meta["encoding"], "pairing_tolerance_s": tol / 1e9,
                "depth_integer_scale": (None if depth_meta["encoding"] == "32FC1"
                                        else float(self.options.get("depth_scale") or 0.001))}
        return RecordingIndex(width=w, height=h, K=K.tolist(), fps=fps, timestamps_s=stamps_s, keys=keys,
                              status=status, message=message, notes=notes, info=info)

    def decode(self, index: RecordingIndex, wanted: list[int]
               ) -> Iterator[tuple[int, np.ndarray | None, np.ndarray | None, str]]:
        ts = _typestore()
        info = index.info
        need = {}  # bag time -> (frame, part)
        for i in wanted:
            rgb_t, dep_t = index.keys[i]
            need[(info["rgb_topic"], rgb_t)] = i
            if dep_t is not None:
                need[(info["depth_topic"], dep_t)] = i
        got: dict[int, dict[str, Any]] = {i: {} for i in wanted}
        lo = min(t for _, t in need)
        hi = max(t for _, t in need)
        reader = _open_reader(self.path)
        ptr = 0
        scale = float(self.options.get("depth_scale") or 0.001)
        try:
            conns = [c for c in reader.connections if c.topic in (info["rgb_topic"], info["depth_topic"])]
            for conn, bag_ns, raw in reader.messages(connections=conns, start=lo, stop=hi + 1):
                i = need.get((conn.topic, bag_ns))
                if i is None:
                    continue
                part = "rgb" if conn.topic == info["rgb_topic"] else "depth"
                got[i][part] = ts.deserialize_cdr(raw, conn.msgtype)
                while ptr < len(wanted) and _complete(got[wanted[ptr]], index.keys[wanted[ptr]]):
                    yield _frame(wanted[ptr], got.pop(wanted[ptr]), scale)
                    ptr += 1
        finally:
            reader.close()
        for i in wanted[ptr:]:
            part = got.pop(i, {})
            yield (_frame(i, part, scale) if "rgb" in part else (i, None, None, "colour message not found in the bag"))


def _complete(parts: dict, key: list) -> bool:
    return "rgb" in parts and ("depth" in parts or key[1] is None)


def _image_size(msg: Any) -> tuple[int, int] | None:
    if hasattr(msg, "width"):
        return int(msg.width), int(msg.height)
    rgb = _decode_colour(msg)
    return None if rgb is None else (rgb.shape[1], rgb.shape[0])


def _decode_colour(msg: Any) -> np.ndarray | None:
    import cv2

    if not hasattr(msg, "encoding"):  # CompressedImage
        bgr = cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_COLOR)
        return None if bgr is None else cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    enc = msg.encoding.lower()
    ch = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono8": 1}.get(enc)
    if ch is None:
        return None
    data = np.asarray(msg.data, np.uint8)
    img = np.lib.stride_tricks.as_strided(data, (msg.height, msg.width, ch), (msg.step, ch, 1))
    conv = {"bgr8": cv2.COLOR_BGR2RGB, "rgba8": cv2.COLOR_RGBA2RGB, "bgra8": cv2.COLOR_BGRA2RGB,
            "mono8": cv2.COLOR_GRAY2RGB}.get(enc)
    return np.ascontiguousarray(img) if conv is None else cv2.cvtColor(np.ascontiguousarray(img), conv)


def _decode_depth(msg: Any, scale: float) -> np.ndarray | None:
    enc = msg.encoding
    dtype = {"16UC1": np.uint16, "mono16": np.uint16, "32FC1": np.float32}.get(enc)
    if dtype is None:
        return None
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    data = np.asarray(msg.data, np.uint8)
    rows = [np.frombuffer(data[r * msg.step:r * msg.step + msg.width * dt.itemsize].tobytes(), dt)
            for r in range(msg.height)] if msg.step != msg.width * dt.itemsize else None
    img = np.stack(rows) if rows is not None else np.frombuffer(data.tobytes(), dt).reshape(msg.height, msg.width)
    return img.astype(np.float32) * np.float32(scale) if dtype == np.uint16 else img.astype(np.float32)


def _frame(i: int, parts: dict, scale: float) -> tuple[int, np.ndarray | None, np.ndarray | None, str]:
    rgb = _decode_colour(parts["rgb"])
    if rgb is None:
        enc = getattr(parts["rgb"], "encoding", getattr(parts["rgb"], "format", "?"))
        return i, None, None, f"colour frame in an encoding demoforge does not read ({enc!r})"
    depth = _decode_depth(parts["depth"], scale) if "depth" in parts else None
    return i, rgb, depth, "" if depth is not None or "depth" not in parts else "depth frame cannot be decoded"


class RosBag2Source(RecordingSource):
    """A ROS 2 bag: ``.mcap`` or ``.db3`` file, or the bag's folder (``metadata.yaml``)."""

    name = "rosbag2"
    description = "ROS 2 bag (.mcap, .db3 or the bag folder): Image/CompressedImage colour, aligned depth, CameraInfo"
    recording_cls = RosBag2Recording

    @classmethod
    def claims(cls, path: Path) -> bool:
        if path.is_file():
            return path.suffix.lower() in (".mcap", ".db3")
        return path.is_dir() and (path / "metadata.yaml").is_file()
