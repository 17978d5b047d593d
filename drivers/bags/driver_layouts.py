"""The topics common ROS camera drivers publish a TOF frame on, and which of them a bag holds.

Each layout names a driver's default range, amplitude and CameraInfo topics and how its range is encoded. A bag
is matched by its topics: the exact default names first, then the same names under another namespace (ROS 2
drivers are often launched with one), so `tofd import`/`replay` need no topic options for these drivers. An image
recorded through image_transport (`<image>/compressedDepth`, `<image>/compressed`) counts as that image.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from tofd.drivers.bags.images import IMAGE_TYPES
from tofd.drivers.bags.scan import BagError, Topic
from tofd.drivers.frame import AmplitudeKind

CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"


@dataclass(frozen=True, slots=True)
class Layout:
    """A driver's default namespace, its topics under it, and its range encoding."""

    driver: str
    namespace: str  # e.g. "/camera"; the topics below are relative to it
    range_topic: str
    amplitude_topic: str | None  # None: the driver publishes none
    camera_info_topic: str | None
    range_unit: Literal["device", "mm"]  # 16-bit range: SwissRanger device units or millimetres (REP 118)
    depth: Literal["radial", "z"]  # radial range or z-depth along the optical axis
    amplitude: str  # what its amplitude image is

    @property
    def relative_topics(self) -> dict[str, str | None]:
        """Role ("range", "amplitude", "camera_info") -> topic relative to the namespace (None: not published)."""
        return {"range": self.range_topic, "amplitude": self.amplitude_topic, "camera_info": self.camera_info_topic}

    @property
    def topics(self) -> dict[str, str | None]:
        """Role -> the driver's default topic (None: not published)."""
        return {role: None if t is None else f"{self.namespace}/{t}" for role, t in self.relative_topics.items()}


LAYOUTS: tuple[Layout, ...] = (
    Layout("swissranger_camera", "/SwissRanger", "distance/image_raw16", "intensity/image_raw16", "camera_info",
           "device", "radial", "amplitude"),
    Layout("orbbec_camera", "/camera", "depth/image_raw", "ir/image_raw", "depth/camera_info", "mm", "z",
           "infrared"),
    Layout("azure_kinect_ros_driver", "", "depth/image_raw", "ir/image_raw", "depth/camera_info", "mm", "z",
           "infrared"),
    Layout("realsense2_camera", "/camera/camera", "depth/image_rect_raw", "infra1/image_rect_raw",
           "depth/camera_info", "mm", "z", "infrared"),
    Layout("royale", "/royale_cam0", "depth_image", "gray_image", "camera_info", "mm", "z",
           "gray value (active brightness)"),
    Layout("arena_camera", "/arena_camera_node", "images", None, None, "mm", "z", "intensity"),
)
"""Known drivers; the first whose topics a bag holds is taken (orbbec_camera and azure_kinect_ros_driver publish
the same relative names and encodings, so which of the two a renamed bag is taken for changes nothing)."""


AMPLITUDE_KINDS: dict[str, AmplitudeKind] = {"amplitude": "amplitude", "infrared": "ir",
                                             "gray value (active brightness)": "active_brightness",
                                             "intensity": "active_brightness"}
"""What each layout's amplitude image is, as tofd.drivers.frame.SensorInfo names it (named topics: "amplitude")."""


TRANSPORTS = ("", "/compressedDepth", "/compressed")
"""image_transport's topics of an image topic: the raw one, then its compressedDepth and compressed plugins'."""


def image_topic(base: str, topics: dict[str, Topic]) -> str | None:
    """The bag's topic carrying image topic `base`: itself, else its compressedDepth or compressed subtopic (the
    first of these the bag holds as an image), or None."""
    return next((base + t for t in TRANSPORTS if base + t in topics and topics[base + t].msgtype in IMAGE_TYPES),
                None)


def detect_layout(topics: dict[str, Topic]) -> tuple[Layout, dict[str, str | None]] | None:
    """The first layout whose range image the bag holds under the driver's namespace, else the first under
    exactly one other namespace, with the bag's topic of each role (None: not in the bag); or None. An image
    may be on image_transport's compressedDepth or compressed subtopic instead of its own."""
    for exact in (True, False):
        for layout in LAYOUTS:
            if exact:
                namespaces = {layout.namespace} if image_topic(f"{layout.namespace}/{layout.range_topic}",
                                                               topics) else set()
            else:
                namespaces = {t[:-len(f"/{layout.range_topic}{transport}")] for t in topics
                              for transport in TRANSPORTS if t.endswith(f"/{layout.range_topic}{transport}")
                              and topics[t].msgtype in IMAGE_TYPES}
            if len(namespaces) != 1:
                continue
            namespace = namespaces.pop()
            names: dict[str, str | None] = {}
            for role, rel in layout.relative_topics.items():
                name = None if rel is None else f"{namespace}/{rel}"
                if name is None or role != "camera_info":
                    names[role] = None if name is None else image_topic(name, topics)
                else:
                    names[role] = name if name in topics else None
            info = names["camera_info"]
            if info is None or topics[info].msgtype == CAMERA_INFO_TYPE:
                return layout, names
    return None


def describe_topics(topics: dict[str, Topic]) -> str:
    """"topic (type), ..." of a bag, sorted, or "none"."""
    return ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items())) or "none"


def no_layout_error(path: object, topics: dict[str, Topic]) -> BagError:
    drivers = ", ".join(layout.driver for layout in LAYOUTS)
    return BagError(f"{path}: no known camera driver's topics ({drivers}); name them with --range-topic, "
                    f"--amplitude-topic and --camera-info-topic; the bag has: {describe_topics(topics)}")
