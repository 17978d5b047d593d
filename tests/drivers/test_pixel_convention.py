"""One pixel-centre convention (tofd/service/viewer/pixels.py): in what Rerun reads back from tofd's stream and what
a Foxglove client receives, the 3-D nose projected through the logged camera lands on the logged 2-D nose."""

import numpy as np
import pytest

from tests.service.test_track_reporting import INTRINSICS, result
from tofd.algorithm.detector import Detection
from tofd.algorithm.tracking import NoseTracker
from tofd.config import Config
from tofd.service.foxglove import topics as t
from tofd.service.foxglove.publisher import FoxglovePublisher
from tofd.service.foxglove.spec import parse_foxglove_spec
from tofd.service.viewer import blueprint as bp
from tofd.service.viewer.logger import RerunLogger
from tofd.service.viewer.targets import RerunTarget
from tofd_testing.foxglove_client import Client
from tofd_testing.rrd_helpers import read_entities


def nose_at(u: int, v: int, z: float = 0.5) -> Detection:
    """A detection at pixel (u, v) (tofd's convention), its 3-D point on that pixel's ray at depth z."""
    ray = INTRINSICS.pixel_rays(u, v)
    return Detection((u, v), tuple(float(c) for c in ray / ray[2] * z), 0.1, True)


DETECTIONS = [nose_at(20, 30), nose_at(150, 100), nose_at(88, 72)]


def test_rerun_pinhole_and_nose_points_share_the_corner_origin(tmp_path):
    path = tmp_path / "pixels.rrd"
    target = RerunTarget(Config().rerun, "save", INTRINSICS.shape, path=str(path))
    logger = RerunLogger(target.rec, INTRINSICS, point_cloud=False)
    tracker = NoseTracker()
    for k, det in enumerate(DETECTIONS):
        logger(result(k, det, tracker.update(det, k * 0.04)))
    logger.flush()
    target.close()
    tables = read_entities(str(path))
    (pinhole,) = [c.to_record_batch() for c in tables[bp.CAMERA][0]]
    k = np.array(pinhole.column("Pinhole:image_from_camera")[0].as_py()[0]).reshape(3, 3).T  # column-major
    assert k[0, 2] == pytest.approx(INTRINSICS.cx + 0.5) and k[1, 2] == pytest.approx(INTRINSICS.cy + 0.5)
    points = tables[bp.NOSE_2D][1].column("Points2D:positions").to_pylist()
    for det, (point,) in zip(DETECTIONS, points, strict=True):
        projected = k @ np.asarray(det.nose_xyz_m)
        assert point == pytest.approx(list(projected[:2] / projected[2]), abs=1e-4)  # the 3-D nose's pixel
        assert point == [det.nose_px[0] + 0.5, det.nose_px[1] + 0.5]


def test_foxglove_annotations_use_the_corner_origin_and_the_calibration_ros_centres(tmp_path):
    publisher = FoxglovePublisher(parse_foxglove_spec("127.0.0.1:0", Config()))
    try:
        tracker = NoseTracker()
        results = [result(k, det, tracker.update(det, k * 0.04)) for k, det in enumerate(DETECTIONS)]
        publisher(results[0])  # the server listens from the first frame on
        client = Client(publisher.web_url)
        client.subscribe([t.NOSE, t.CALIBRATION])
        client.read(0.5)  # the subscriptions are in
        for r in results:
            publisher(r)
        got = client.read(10, until=lambda got: len(got.get(t.NOSE, [])) == len(DETECTIONS))
        client.close()
    finally:
        publisher.close(1.0)
    calibration = got[t.CALIBRATION][-1][1]
    k = np.array(calibration.K).reshape(3, 3)
    assert k[0, 2] == INTRINSICS.cx and k[1, 2] == INTRINSICS.cy  # ROS CameraInfo's convention: pixel centres
    for det, (_, annotations) in zip(DETECTIONS, got[t.NOSE], strict=True):
        (point,) = annotations.points[0].points
        projected = k @ np.asarray(det.nose_xyz_m)
        # ImageAnnotations put (0, 0) at the top-left pixel's corner: the centre-origin projection plus half a pixel
        assert (point.x, point.y) == pytest.approx(tuple(projected[:2] / projected[2] + 0.5), abs=1e-6)
