"""Orbbec SDK v2 recordings written by the SDK's own writer.

A seed bag is laid out as the SDK's rosbag reader expects (its OrbbecSDK_v2 src/media/ros sources and
3rdparty/rosbag message headers): the bag-file version as property 0, the custom_msg/OB* message types with the
SDK's md5 sums, its extended Image (depth_units, frame number and timestamps, metadata, pixel_bit_size after
`data`), a /cam/disparityParam (without it the SDK's writer cannot write the depth profile) and the stream
profiles. The SDK's PlaybackDevice plays the seed (pyorbbecsdk2's Python binding, independent of tofd's ctypes
backend) and its RecordDevice re-records that playback device: the file tests read is the SDK's own. The seed is
uncompressed: the SDK's roslz4 refuses rosbags' LZ4 chunks ("ROSLZ4_DATA_ERROR: malformed data to decompress").
"""

from __future__ import annotations

import multiprocessing
import struct
import time
from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer

IMAGE_MD5 = "060021388200f6f0f447d0fcd9c64743"
PLACEHOLDER_MD5 = "0123456789abcdef0123456789abcdef"  # the SDK's OBProperty and OBStreamProfileInfo
DEVICE_MD5 = "afef5328bb4abebd1a309e1ea8b26b3a"  # custom_msg/OBDeviceInfo
DISPARITY_MD5 = "abcdef0123456789abcdef0123456789"  # custom_msg/OBDisparityParam
HEADER_DEF = "MSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n"
SEP = "=" * 80 + "\n"
IMAGE_DEF = ("Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\n"
             "uint8[] data\n" + SEP + HEADER_DEF)
PROFILE_DEF = ("std_msgs/Header header\nuint8 streamType\nuint8 format\nfloat32[9] rotationMatrix\n"
               "float32[3] translationMatrix\nuint16 width\nuint16 height\nuint16 fps\nfloat32[4] cameraIntrinsic\n"
               "float32[8] cameraDistortion\nuint8 distortionModel\n")
DEVICE_DEF = ("std_msgs/Header header\nstring name\nstring fullName\nstring asicName\nuint16 vid\nuint16 pid\n"
              "string uid\nstring sn\nstring fwVersion\nstring hwVersion\nstring supportedSdkVersion\n"
              "string connectionType\nuint16 type\nuint8 backendType\nstring ipAddress\nstring localMac\n")
PROPERTY_DEF = "std_msgs/Header header\nuint8 propertyId\nuint8[] data  \nuint32 datasize\n"
DISPARITY_DEF = ("std_msgs/Header header\nfloat64 zpd\nfloat64 zpps\nfloat32 baseline\nfloat64 fx\nuint8 bitSize\n"
                 "float32 unit\nfloat32 minDisparity\nuint8 packMode\nfloat32 dispOffset\nint32 invalidDisp\n"
                 "int32 dispIntPlace\nuint8 isDualCamera\n")
FORMAT_Y16 = 8  # OB_FORMAT_Y16
BROWN_CONRADY_K6 = 4  # OB_DISTORTION_BROWN_CONRADY_K6
BAG_VERSION_PROPERTY = 0  # the SDK's bag-file version, a double (2.x is what SDK 2.4 and later play)
T0_US = 5_000_000
LEAD_IN_US = 200_000  # a first frame pair this long before the others: the SDK's recorder loses the first depth
# image it is played
FPS = 30


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


def _header(stamp_us: int) -> bytes:
    return struct.pack("<III", 0, stamp_us // 1_000_000, stamp_us % 1_000_000 * 1000) + _string("")


def image_bytes(plane: np.ndarray, number: int, stamp_us: int) -> bytes:
    h, w = plane.shape
    data = np.ascontiguousarray(plane.astype("<u2")).tobytes()
    return (_header(stamp_us) + struct.pack("<II", h, w) + _string("mono16") + struct.pack("<BI", 0, w * 2)
            + struct.pack("<I", len(data)) + data + struct.pack("<fQQQQ", 0.0, number, stamp_us, stamp_us, 0)
            + struct.pack("<II", 0, 0) + struct.pack("<B", 16))


def profile_bytes(stream_type: int, intrinsics: tuple[float, float, float, float], size: tuple[int, int],
                  distortion: tuple[float, ...], model: int, fps: int = FPS) -> bytes:
    identity = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    return (_header(T0_US) + struct.pack("<BB", stream_type, FORMAT_Y16) + struct.pack("<12f", *identity)
            + struct.pack("<HHH", size[0], size[1], fps) + struct.pack("<4f", *intrinsics)
            + struct.pack("<8f", *distortion) + struct.pack("<B", model))


def device_bytes(name: str, serial: str, firmware: str) -> bytes:
    return (_header(T0_US) + _string(name) + _string(name) + _string("MX6600") + struct.pack("<HH", 0x2BC5, 0x066B)
            + _string("1-2") + _string(serial) + _string(firmware) + _string("0.1") + _string("2.0.0")
            + _string("USB3.1") + struct.pack("<HB", 1, 0) + _string("") + _string(""))


def property_bytes(property_id: int, value: bytes) -> bytes:
    return _header(T0_US) + struct.pack("<II", property_id, len(value)) + value + struct.pack("<I", len(value))


def disparity_bytes() -> bytes:
    """A time-of-flight camera's disparity parameters: all zero but the bit size and unit."""
    return _header(T0_US) + struct.pack("<ddfdBffBfiiB", 0.0, 0.0, 0.0, 0.0, 16, 1.0, 0.0, 0, 0.0, 0, 0, 0)


def write_seed_bag(path: Path, depth: list[np.ndarray], infrared: list[np.ndarray],
                   k: tuple[float, float, float, float], distortion_sdk_order: tuple[float, ...],
                   model: int = BROWN_CONRADY_K6, properties: dict[int, bytes] | None = None, first_number: int = 7,
                   profiles: bool = True, lead_in: bool = False) -> Path:
    """A bag as the SDK reads it: depth (Y16) and IR (Y16) frames at 30 fps from device time 5 s, numbered from
    first_number, intrinsics [fx, fy, cx, cy], distortion [k1..k6, p1, p2] of `model`, the given properties
    (id -> value bytes); with lead_in, a copy of the first pair numbered first_number - 1 LEAD_IN_US before."""
    h, w = depth[0].shape
    writer = Writer(path)
    with writer:
        def connection(topic: str, msgtype: str, msgdef: str, md5: str):  # noqa: ANN202
            return writer.add_connection(topic, msgtype, msgdef=msgdef, md5sum=md5)

        t0_ns = T0_US * 1000
        prop = connection("/cam/property", "custom_msg/msg/OBProperty", PROPERTY_DEF, PLACEHOLDER_MD5)
        for pid, value in {BAG_VERSION_PROPERTY: struct.pack("<d", 2.1), **(properties or {})}.items():
            writer.write(prop, t0_ns, property_bytes(pid, value))
        depth_c = connection("/cam/sensor_3/frameType_3", "sensor_msgs/msg/Image", IMAGE_DEF, IMAGE_MD5)
        ir_c = connection("/cam/sensor_1/frameType_1", "sensor_msgs/msg/Image", IMAGE_DEF, IMAGE_MD5)
        if lead_in:
            stamp = T0_US - LEAD_IN_US
            writer.write(depth_c, stamp * 1000, image_bytes(depth[0], first_number - 1, stamp))
            writer.write(ir_c, stamp * 1000 + 1000, image_bytes(infrared[0], first_number - 1, stamp))
        for n, (d, ir) in enumerate(zip(depth, infrared, strict=True)):
            stamp = T0_US + round(n * 1e6 / FPS)
            writer.write(depth_c, stamp * 1000, image_bytes(d, first_number + n, stamp))
            writer.write(ir_c, stamp * 1000 + 1000, image_bytes(ir, first_number + n, stamp))
        dev = connection("/cam/deviceInfo", "custom_msg/msg/OBDeviceInfo", DEVICE_DEF, DEVICE_MD5)
        writer.write(dev, t0_ns, device_bytes("Femto Bolt", "CL8F12300AB", "1.0.9"))
        disparity = connection("/cam/disparityParam", "custom_msg/msg/OBDisparityParam", DISPARITY_DEF, DISPARITY_MD5)
        writer.write(disparity, t0_ns, disparity_bytes())
        if profiles:
            for stream in (3, 1):
                c = connection(f"/cam/streamProfileType_{stream}", "custom_msg/msg/OBStreamProfileInfo", PROFILE_DEF,
                               PLACEHOLDER_MD5)
                writer.write(c, t0_ns, profile_bytes(stream, k, (w, h), distortion_sdk_order, model))
    return path


SDK_ATTEMPTS = 2  # the SDK's native code now and then crashes (SIGSEGV) while a recording is played and recorded


def sdk_rerecord(seed: Path, out: Path, compressed: bool = True, timeout_s: float = 60.0) -> Path:
    """`out`: the SDK's RecordDevice recording the SDK's PlaybackDevice as it plays `seed` to its end, in a child
    process: a crash of the SDK's native code ends that child, not the test process (under pytest-xdist a crashed
    worker can leave the whole run waiting), and a crashed child is tried again, SDK_ATTEMPTS in all; a Python
    error in the child (a timeout, no file written) is not."""
    spawn = multiprocessing.get_context("spawn")
    for _ in range(SDK_ATTEMPTS):
        child = spawn.Process(target=_sdk_rerecord, args=(str(seed), str(out), compressed, timeout_s))
        child.start()
        child.join(timeout_s + 60.0)
        if child.is_alive():
            child.kill()
            child.join()
            raise TimeoutError(f"the SDK's recording of {seed} did not end within {timeout_s + 60.0:g} s")
        if child.exitcode == 0:
            return out
        if child.exitcode > 0:
            raise RuntimeError(f"the SDK's recording of {seed} failed (exit {child.exitcode}; its error is above)")
        out.unlink(missing_ok=True)  # killed by a signal: whatever it wrote is incomplete
    raise RuntimeError(f"the SDK crashed in each of {SDK_ATTEMPTS} recordings of {seed} (last signal: "
                       f"{-child.exitcode})")


def _sdk_rerecord(seed_path: str, out_path: str, compressed: bool, timeout_s: float) -> None:
    """sdk_rerecord's child: the SDK's recording of the seed bag."""
    import pyorbbecsdk as ob

    seed, out = Path(seed_path), Path(out_path)
    ob.Context.set_logger_to_file(ob.OBLogLevel.NONE, "")  # the SDK's default logs into ./Log of the cwd
    ob.Context.set_logger_to_console(ob.OBLogLevel.ERROR)
    player = ob.PlaybackDevice(str(seed))
    recorder = ob.RecordDevice(player, str(out), compressed)
    pipeline = ob.Pipeline(player)
    config = ob.Config()
    sensors = player.get_sensor_list()
    for i in range(sensors.get_count()):
        config.enable_stream(sensors.get_type_by_index(i))
    pipeline.start(config)
    deadline = time.monotonic() + timeout_s
    started = False
    while time.monotonic() < deadline:
        frames = pipeline.wait_for_frames(100)
        started = started or frames is not None
        if started and player.get_playback_status() == ob.OBPlaybackStatus.STOPPED:
            break
    else:
        raise TimeoutError(f"the SDK did not play {seed} to its end within {timeout_s} s")
    pipeline.stop()
    del recorder  # the SDK writes the stream profiles and closes the bag when its recorder goes
    if not out.exists():
        raise RuntimeError(f"the SDK's RecordDevice wrote no {out} (an {out.name}_error means it failed)")


def write_orbbec_bag(path: Path, depth: list[np.ndarray], infrared: list[np.ndarray],
                     k: tuple[float, float, float, float], distortion_sdk_order: tuple[float, ...],
                     model: int = BROWN_CONRADY_K6, properties: dict[int, bytes] | None = None,
                     compressed: bool = True, first_number: int = 7) -> Path:
    """`path`: an Orbbec SDK v2 .bag written by the SDK's RecordDevice (LZ4 chunks when compressed) of the frames
    and lens write_seed_bag describes, numbered from first_number, after a lead-in frame pair numbered
    first_number - 1 whose depth image the SDK's recorder may lose (then tofd counts its IR image as unpaired)."""
    seed = write_seed_bag(path.with_name(path.stem + ".seed.bag"), depth, infrared, k, distortion_sdk_order, model,
                          properties, first_number, lead_in=True)
    return sdk_rerecord(seed, path, compressed)
