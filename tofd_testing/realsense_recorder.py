"""Records frames with librealsense's own recorder (pyrealsense2: a software_device with a depth sensor streaming
Z16 depth and Y8 infrared, rs.recorder writing the file): run as a script, in the Python environment of the
pyrealsense2 version to test (2.59 writes a ROS 2 .db3, 2.56 a ROS 1 .bag).

    python realsense_recorder.py FRAMES.npz OUT

FRAMES.npz (no pickles): depth (N, H, W) uint16, infrared (N, H, W) uint8, intrinsics [fx, fy, ppx, ppy],
coeffs [k1, k2, p1, p2, k3] (Brown-Conrady), depth_units [metres per unit], timestamps_ms (N,), first_number [n].
"""

import ctypes
import sys
import time

import numpy as np


def load_libusb() -> None:
    """pyrealsense2's wheel links libusb-1.0.so.0 without bundling it: load the libusb-package copy first."""
    try:
        import libusb_package
    except ImportError:
        return
    path = libusb_package.get_library_path()
    if path is not None:
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)


def main(frames_path: str, out: str) -> None:
    load_libusb()
    import pyrealsense2 as rs

    data = np.load(frames_path, allow_pickle=False)
    depth, infrared = data["depth"], data["infrared"]
    n, h, w = depth.shape
    fx, fy, ppx, ppy = (float(v) for v in data["intrinsics"])
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = w, h
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = fx, fy, ppx, ppy
    intrinsics.model = rs.distortion.brown_conrady
    intrinsics.coeffs = [float(c) for c in data["coeffs"]]

    device = rs.software_device()
    device.register_info(rs.camera_info.name, "Software RealSense")
    device.register_info(rs.camera_info.serial_number, "0123456789")
    device.register_info(rs.camera_info.firmware_version, "5.16.0.1")
    sensor = device.add_sensor("Stereo Module")
    streams = []
    for kind, index, bpp, fmt in ((rs.stream.depth, 0, 2, rs.format.z16), (rs.stream.infrared, 1, 1, rs.format.y8)):
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid = kind, index, index
        vs.width, vs.height, vs.fps, vs.bpp, vs.fmt = w, h, 30, bpp, fmt
        vs.intrinsics = intrinsics
        streams.append(sensor.add_video_stream(vs))
    sensor.add_read_only_option(rs.option.depth_units, float(data["depth_units"][0]))
    recorder = rs.recorder(out, device)
    sensor.open(streams)
    sensor.start(rs.syncer())
    first = int(data["first_number"][0])
    for i in range(n):
        for profile, plane, bpp in ((streams[0], depth[i], 2), (streams[1], infrared[i], 1)):
            frame = rs.software_video_frame()
            frame.pixels = np.ascontiguousarray(plane)
            frame.bpp, frame.stride = bpp, w * bpp
            frame.timestamp = float(data["timestamps_ms"][i])
            frame.domain = rs.timestamp_domain.hardware_clock
            frame.frame_number = first + i
            frame.profile = profile.as_video_stream_profile()
            sensor.on_video_frame(frame)
        time.sleep(0.02)  # the recorder writes from its own thread
    sensor.stop()
    sensor.close()
    del recorder  # closes the file


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
