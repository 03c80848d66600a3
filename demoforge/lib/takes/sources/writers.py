"""A take folder written as a recording, each with its format's own library: what the readers are
tested and benchmarked on (a synthetic take whose ground truth is known), and a way to check a reader
against a take of your own.

- :func:`write_realsense`: the RealSense SDK itself (``pyrealsense2``: a ``software_device`` recorded
  by ``rs.recorder``). SDK 2.59 records to the ROS 2 layout, a ``.db3`` file (it refuses a ``.bag``
  name); it plays back both that and the older ``.bag``, which :func:`write_realsense_bag` writes with
  ``rosbags`` in the SDK's ROS 1 topic layout.
- :func:`write_rosbag2`: ``rosbags``' rosbag2 writer (MCAP or SQLite storage), the RealSense ROS driver's
  topic names.
- :func:`write_record3d`: Record3D's layout (``metadata`` + ``rgbd/N.jpg``, LZFSE ``N.depth``/``N.conf``),
  zipped as ``.r3d`` or as the exported folder.

Each also fills the recording's side folder with the take's pose (camera.json), annotations.json,
take.json and ground_truth/, as if the recording had been calibrated and annotated.
"""

from __future__ import annotations

import json
import os
import shutil
import time
import zipfile
from pathlib import Path
from typing import Iterator

import numpy as np

from demoforge.lib.takes.reader import iter_frames, open_take
from demoforge.lib.takes.sources.recording import sidecar_dir
from demoforge.lib.takes.types import Take


def _frames(take: Take) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    for b in iter_frames(take, batch_size=8):
        yield from zip(b.indices.tolist(), b.rgb, b.depth)


def copy_metadata(take_dir: Path, recording: Path) -> Path:
    """The take's pose, annotations, take.json and ground truth into the recording's side folder."""
    side = sidecar_dir(recording)
    side.mkdir(parents=True, exist_ok=True)
    cam = json.loads((take_dir / "camera.json").read_text())
    if "T_world_camera" in cam:
        (side / "camera.json").write_text(json.dumps({"T_world_camera": cam["T_world_camera"],
                                                      "pose_method": "camera.json"}, indent=2))
    for name in ("annotations.json", "take.json"):
        if (take_dir / name).is_file():
            shutil.copy2(take_dir / name, side / name)
    if (take_dir / "ground_truth").is_dir():
        shutil.copytree(take_dir / "ground_truth", side / "ground_truth", dirs_exist_ok=True)
    return side


def write_record3d(take_dir: str | os.PathLike, out: str | os.PathLike, *, as_zip: bool = True,
                   depth_size: tuple[int, int] | None = None, jpeg_quality: int = 95,
                   camera_path_m: np.ndarray | None = None) -> Path:
    """Record3D's layout from a take folder. ``depth_size`` (w, h): the depth's resolution (default the
    RGB's; a real export's is 256 x 192 for 960 x 720). ``camera_path_m`` (n, 3): camera positions to
    put in the poses (default static)."""
    import cv2
    import lzfse

    take_dir, out = Path(take_dir), Path(out)
    take = open_take(take_dir)
    cam = take.camera
    dw, dh = depth_size or (cam.width, cam.height)
    members: dict[str, bytes] = {}
    n = take.n_frames
    path = np.zeros((n, 3)) if camera_path_m is None else np.asarray(camera_path_m, float)
    meta = {"w": cam.width, "h": cam.height, "K": np.asarray(cam.K).T.reshape(-1).tolist(), "fps": cam.fps,
            "dw": dw, "dh": dh, "initPose": [0, 0, 0, 1, 0, 0, 0],
            "poses": [[0.0, 0.0, 0.0, 1.0, *map(float, path[i])] for i in range(n)],
            "frameTimestamps": [i / cam.fps for i in range(n)]}
    members["metadata"] = json.dumps(meta).encode()
    for i, rgb, depth in _frames(take):
        ok, jpg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
        members[f"rgbd/{i}.jpg"] = jpg.tobytes()
        d = depth if (dw, dh) == (cam.width, cam.height) else cv2.resize(depth, (dw, dh), interpolation=cv2.INTER_NEAREST)
        members[f"rgbd/{i}.depth"] = lzfse.compress(np.ascontiguousarray(d, np.float32).tobytes())
        members[f"rgbd/{i}.conf"] = lzfse.compress(np.full((dh, dw), 2, np.uint8).tobytes())
    if as_zip:
        with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as z:
            for name, data in members.items():
                z.writestr(name, data)
    else:
        for name, data in members.items():
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            (out / name).write_bytes(data)
    copy_metadata(take_dir, out)
    return out


def write_rosbag2(take_dir: str | os.PathLike, out: str | os.PathLike, *, storage: str = "mcap",
                  depth_encoding: str = "16UC1", depth: bool = True, namespace: str = "/camera",
                  jpeg: bool = False) -> Path:
    """A ROS 2 bag folder (``out``) with colour (rgb8 Image; ``jpeg``: a JPEG CompressedImage on
    ``.../image_raw/compressed``), depth aligned to it (``16UC1`` mm or ``32FC1`` m) and CameraInfo,
    stamped at i / fps; ``depth=False`` leaves the depth topic out."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    take_dir, out = Path(take_dir), Path(out)
    take = open_take(take_dir)
    cam = take.camera
    ts = get_typestore(Stores.ROS2_HUMBLE)
    Image, Info = ts.types["sensor_msgs/msg/Image"], ts.types["sensor_msgs/msg/CameraInfo"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    Roi = ts.types["sensor_msgs/msg/RegionOfInterest"]
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    t0 = 1_700_000_000 * 10**9
    with Writer(out, version=9, storage_plugin=plugin) as w:
        Compressed = ts.types["sensor_msgs/msg/CompressedImage"]
        c_rgb = (w.add_connection(f"{namespace}/color/image_raw/compressed", Compressed.__msgtype__, typestore=ts)
                 if jpeg else w.add_connection(f"{namespace}/color/image_raw", Image.__msgtype__, typestore=ts))
        c_info = w.add_connection(f"{namespace}/color/camera_info", Info.__msgtype__, typestore=ts)
        c_dep = (w.add_connection(f"{namespace}/aligned_depth_to_color/image_raw", Image.__msgtype__, typestore=ts)
                 if depth else None)
        for i, rgb, d in _frames(take):
            t = t0 + int(round(i * 1e9 / cam.fps))
            hdr = Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="camera_color_optical_frame")
            if jpeg:
                import cv2

                buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])[1]
                w.write(c_rgb, t, ts.serialize_cdr(Compressed(header=hdr, format="jpeg", data=buf.reshape(-1)),
                                                   Compressed.__msgtype__))
            else:
                img = Image(header=hdr, height=cam.height, width=cam.width, encoding="rgb8", is_bigendian=0,
                            step=cam.width * 3, data=np.ascontiguousarray(rgb).reshape(-1))
                w.write(c_rgb, t, ts.serialize_cdr(img, Image.__msgtype__))
            if c_dep is not None:
                if depth_encoding == "16UC1":
                    raw, step = np.clip(np.rint(d * 1000), 0, 65535).astype("<u2"), cam.width * 2
                else:
                    raw, step = d.astype("<f4"), cam.width * 4
                dimg = Image(header=hdr, height=cam.height, width=cam.width, encoding=depth_encoding, is_bigendian=0,
                             step=step, data=raw.view(np.uint8).reshape(-1))
                w.write(c_dep, t + 1000, ts.serialize_cdr(dimg, Image.__msgtype__))
            if i == 0:
                K = np.asarray(cam.K, float)
                P = np.hstack([K, np.zeros((3, 1))])
                info = Info(header=hdr, height=cam.height, width=cam.width, distortion_model="plumb_bob",
                            d=np.zeros(5), k=K.reshape(-1), r=np.eye(3).reshape(-1), p=P.reshape(-1),
                            binning_x=0, binning_y=0, roi=Roi(x_offset=0, y_offset=0, height=0, width=0,
                                                              do_rectify=False))
                w.write(c_info, t, ts.serialize_cdr(info, Info.__msgtype__))
    copy_metadata(take_dir, out)
    return out


def write_realsense(take_dir: str | os.PathLike | None, out: str | os.PathLike, *, depth_units: float = 0.0001,
                    drop: tuple[int, ...] = (), depth_size: tuple[int, int] | None = None,
                    frames: Iterator[tuple[int, np.ndarray, np.ndarray]] | None = None, camera=None,
                    pace_s: float = 0.0) -> Path:
    """A RealSense recording written by the SDK (``rs.recorder`` on a ``software_device``: colour rgb8
    and z16 depth in ``depth_units`` metres; hardware-clock timestamps). ``out`` must end in .db3 (what
    SDK 2.59 records). ``drop``: frame indices left out (dropped by the camera). ``depth_size`` (w, h):
    depth at another resolution (intrinsics scaled), so that reading it needs the SDK's ``align``;
    default: the colour's, registered to it. ``frames`` (index, RGB, depth m) and ``camera``
    (CameraInfo) instead of a take folder: a long recording without the folder on disk. ``pace_s``:
    seconds between frames (the recorder's writer drops frames it is handed faster than it writes;
    1 / fps, as a camera does, for recordings longer than a few dozen frames)."""
    import pyrealsense2 as rs

    out = Path(out)
    if frames is None:
        take_dir = Path(take_dir)
        take = open_take(take_dir)
        cam, frames = take.camera, _frames(take)
    else:
        cam = camera
    dev = rs.software_device()
    ds, cs = dev.add_sensor("Depth"), dev.add_sensor("Color")
    intr = rs.intrinsics()
    intr.width, intr.height = cam.width, cam.height
    intr.fx, intr.fy, intr.ppx, intr.ppy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2], cam.K[1, 2]
    intr.model, intr.coeffs = rs.distortion.none, [0.0] * 5

    dw, dh = depth_size or (cam.width, cam.height)
    dintr = rs.intrinsics()
    dintr.width, dintr.height, dintr.model, dintr.coeffs = dw, dh, rs.distortion.none, [0.0] * 5
    sx, sy = dw / cam.width, dh / cam.height
    dintr.fx, dintr.fy = cam.K[0, 0] * sx, cam.K[1, 1] * sy
    dintr.ppx, dintr.ppy = (cam.K[0, 2] + 0.5) * sx - 0.5, (cam.K[1, 2] + 0.5) * sy - 0.5

    def stream(kind, uid, bpp, fmt, size, intrinsics):
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid, vs.width, vs.height = kind, 0, uid, size[0], size[1]
        vs.fps, vs.bpp, vs.fmt, vs.intrinsics = int(round(cam.fps)), bpp, fmt, intrinsics
        return vs

    dp = ds.add_video_stream(stream(rs.stream.depth, 0, 2, rs.format.z16, (dw, dh), dintr))
    ds.add_read_only_option(rs.option.depth_units, depth_units)
    cp = cs.add_video_stream(stream(rs.stream.color, 1, 3, rs.format.rgb8, (cam.width, cam.height), intr))
    same_place = rs.extrinsics()  # depth already registered to colour: identity (the default is all zeros)
    same_place.rotation, same_place.translation = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], [0.0, 0.0, 0.0]
    dp.register_extrinsics_to(cp, same_place)
    recorder = rs.recorder(str(out), dev)
    ds.open(dp)
    cs.open(cp)
    queue = rs.frame_queue(64)
    ds.start(queue)
    cs.start(queue)
    time.sleep(0.1)  # the recorder drops frames sent before it has started writing

    def send(sensor, profile, pixels, bpp, i):
        f = rs.software_video_frame()
        f.pixels, f.bpp, f.stride = pixels, bpp, bpp * pixels.shape[1]
        f.timestamp, f.domain, f.frame_number = i * 1000.0 / cam.fps, rs.timestamp_domain.hardware_clock, i
        f.profile = profile.as_video_stream_profile()
        sensor.on_video_frame(f)

    start = time.monotonic()
    for i, rgb, d in frames:
        if i in drop:
            continue
        if pace_s:
            time.sleep(max(0.0, start + i * pace_s - time.monotonic()))
        if (dw, dh) != (cam.width, cam.height):
            import cv2

            d = cv2.resize(d, (dw, dh), interpolation=cv2.INTER_NEAREST)
        units = np.clip(np.rint(d / depth_units), 0, 65535).astype(np.uint16)
        send(ds, dp, np.ascontiguousarray(units), 2, i)
        send(cs, cp, np.ascontiguousarray(rgb), 3, i)
        while queue.poll_for_frame():
            pass
    time.sleep(0.05)
    for s in (ds, cs):
        s.stop()
        s.close()
    del recorder, ds, cs, dp, cp, queue, dev
    _wait_until_written(out)  # the SDK closes the file from its own threads
    if take_dir is not None:
        copy_metadata(Path(take_dir), out)
    return out


def _wait_until_written(path: Path, quiet_s: float = 0.3, limit_s: float = 20.0) -> None:
    import gc

    gc.collect()
    last, still, t0 = None, time.monotonic(), time.monotonic()
    while time.monotonic() - t0 < limit_s:
        st = path.stat()
        now = (st.st_size, st.st_mtime_ns)
        if now != last:
            last, still = now, time.monotonic()
        elif time.monotonic() - still >= quiet_s:
            return
        time.sleep(0.05)


def write_realsense_bag(take_dir: str | os.PathLike, out: str | os.PathLike, *, depth_units: float = 0.0001) -> Path:
    """A RealSense ``.bag`` in the SDK's ROS 1 layout (file version 2, what the RealSense Viewer wrote
    before SDK 2.57), written with ``rosbags`` since SDK 2.59's recorder writes only ``.db3``:
    ``/file_version``, ``/device_0/info``, per sensor its ``info``, ``property`` (Depth Units),
    ``<stream>/info`` (``realsense_msgs/StreamInfo``), ``info/camera_info``, ``tf/0`` (identity: depth
    registered to colour), and per frame ``image/data`` (mono16 depth, rgb8 colour; header seq = the
    frame counter, stamp = hardware time) with its ``image/metadata``."""
    from rosbags.rosbag1 import Writer as Bag1Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    take_dir, out = Path(take_dir), Path(out)
    take = open_take(take_dir)
    cam = take.camera
    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg("uint32 fps\nstring encoding\nbool is_recommended", "realsense_msgs/msg/StreamInfo"))
    T, KV = ts.types, "diagnostic_msgs/msg/KeyValue"
    t0 = 10**9

    def header(t: int, seq: int = 0):
        return T["std_msgs/msg/Header"](seq=seq, stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9),
                                        frame_id="0")

    with Bag1Writer(out) as w:
        conns: dict = {}

        def put(topic: str, msgtype: str, msg, t: int = t0) -> None:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, msgtype, typestore=ts)
            w.write(conns[topic], t, ts.serialize_ros1(msg, msgtype))

        put("/file_version", "std_msgs/msg/UInt32", T["std_msgs/msg/UInt32"](data=2))
        for k, v in {"Name": "Intel RealSense D435", "Serial Number": "000000000000", "Product Id": "0B07"}.items():
            put("/device_0/info", KV, T[KV](key=k, value=v))
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        vec, quat = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0), T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
        streams = (("Stereo Module", "Depth_0", "mono16"), ("RGB Camera", "Color_0", "rgb8"))
        for s, (name, stream, enc) in enumerate(streams):
            base = f"/device_0/sensor_{s}"
            put(f"{base}/info", KV, T[KV](key="Name", value=name))
            if s == 0:
                put(f"{base}/property", KV, T[KV](key="Depth Units", value=f"{depth_units:.6f}"))
            put(f"{base}/{stream}/info", "realsense_msgs/msg/StreamInfo",
                T["realsense_msgs/msg/StreamInfo"](fps=int(round(cam.fps)), encoding=enc, is_recommended=True))
            put(f"{base}/{stream}/info/camera_info", "sensor_msgs/msg/CameraInfo", T["sensor_msgs/msg/CameraInfo"](
                header=header(0), height=cam.height, width=cam.width, distortion_model="Brown Conrady", D=np.zeros(5),
                K=np.asarray(cam.K, float).reshape(-1), R=np.zeros(9), P=np.zeros(12), binning_x=0, binning_y=0, roi=roi))
            put(f"{base}/{stream}/tf/0", "geometry_msgs/msg/Transform", T["geometry_msgs/msg/Transform"](translation=vec, rotation=quat))
        Image = T["sensor_msgs/msg/Image"]
        for i, rgb, d in _frames(take):
            t = t0 + int(round(i * 1e9 / cam.fps))
            units = np.clip(np.rint(d / depth_units), 0, 65535).astype("<u2")
            put("/device_0/sensor_0/Depth_0/image/data", "sensor_msgs/msg/Image", Image(
                header=header(t, i), height=cam.height, width=cam.width, encoding="mono16", is_bigendian=0,
                step=cam.width * 2, data=units.view(np.uint8).reshape(-1)), t)
            put("/device_0/sensor_1/Color_0/image/data", "sensor_msgs/msg/Image", Image(
                header=header(t, i), height=cam.height, width=cam.width, encoding="rgb8", is_bigendian=0,
                step=cam.width * 3, data=np.ascontiguousarray(rgb).reshape(-1)), t)
            for s, (_, stream, _) in enumerate(streams):
                for k, v in {"Frame Counter": str(i), "Frame Timestamp": str(int(i * 1e6 / cam.fps)),
                             "timestamp_domain": "Hardware Clock"}.items():
                    put(f"/device_0/sensor_{s}/{stream}/image/metadata", KV, T[KV](key=k, value=v), t)
    copy_metadata(take_dir, out)
    return out
