"""Typed service configuration, loaded from TOML; a wrong key or value names itself in a one-line error."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import stat
import tomllib
import types
import typing
import urllib.parse
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from tofd.algorithm.params import DetectorConfig, FeatureConfig, SegmentationConfig
from tofd.drivers.cameras import CAMERA_KINDS, CameraRequest, StreamMode
from tofd.drivers.frame import DEFAULT_REGISTER_VALUES
from tofd.drivers.intrinsics import Intrinsics
from tofd.drivers.limits import MAX_IMAGE_SIDE
from tofd.errors import ConfigError


def default_file(name: str) -> Path:
    """A bundled default file: config/<name> of a source checkout, else of the installed package tofd.defaults."""
    source_tree = Path(__file__).resolve().parent.parent / "config" / name
    if source_tree.exists():
        return source_tree
    return Path(str(resources.files("tofd.defaults").joinpath(name)))


DEFAULT_CONFIG_PATH = default_file("tofd.toml")
MAX_CONFIG_BYTES = 1 << 20  # a config file is a few kB; anything larger is not one (e.g. /dev/zero, a disk image)
MAX_MODEL_BYTES = 16 << 20  # a nose model is a few kB of JSON; anything larger is not one
MAX_INT = 2**31 - 1  # no count or size in a config is larger; a larger integer is a typo or an attack
MAX_TIMEOUT_S = 3600.0  # seconds: the longest wait, interval or timeout a config may set
MAX_QUEUE = 1024  # frames: the longest queue (a frame in flight is ~0.1-10 MB)
MAX_TASKS_PER_WORKER = 16  # frames in flight per worker (each needs a shared-memory slot)
WORKERS_PER_CORE = 4  # pipeline.workers is at most this times the machine's cores
MAX_STATS_WINDOW = 100_000  # frames in the rolling timing window
MAX_SERIAL_CHARS = 64  # characters of a vendor's camera serial number
MAX_FPS = 1000  # frames per second no depth camera exceeds
MAX_EXPOSURE_US = 1_000_000  # microseconds: a second, longer than any depth camera's exposure
MAX_LASER_POWER = 1e4  # the largest emitter power in any vendor's unit (RealSense: mW, up to 360)
NO_MODEL_PATH = ""  # detector.model_path that chooses to run without nose detection


RERUN_SINKS = ("none", "save", "web", "connect", "spawn")
"""Where the Rerun stream can go: nowhere, an .rrd file, a served web viewer, a running viewer, a desktop viewer."""
RERUN_URL_SCHEMES = ("rerun+http", "rerun+https", "rerun")
"""Schemes of a Rerun viewer's gRPC address (the "connect" sink's url)."""


def check_seconds(key: str, value: float) -> None:
    """ValueError naming `key` unless 0 < value <= MAX_TIMEOUT_S (finite)."""
    if not 0 < value <= MAX_TIMEOUT_S:
        raise ValueError(f"{key}: {value} is not in (0, {MAX_TIMEOUT_S:g}] seconds")


def check_count(key: str, value: int, most: int) -> None:
    """ValueError naming `key` unless 1 <= value <= most."""
    if not 1 <= value <= most:
        raise ValueError(f"{key}: {value} is not in 1..{most}")


def check_serial(serial: str, kind: str = "sr3000") -> str:
    """`serial` if it is a serial number of a `kind` camera or "" (the first camera); ValueError names it otherwise.

    An SR3000's serial is 8 hex digits; the vendors' serials (RealSense, Orbbec, Azure Kinect; kind "any" for a
    serial whose camera kind is not known yet) are printable ASCII without spaces, at most MAX_SERIAL_CHARS long.
    """
    if kind == "sr3000":
        if serial and (len(serial) != 8 or any(c not in "0123456789abcdefABCDEF" for c in serial)):
            raise ValueError(f"serial: {serial!r} is not 8 hex digits (or \"\" for the first camera)")
    elif len(serial) > MAX_SERIAL_CHARS or not all(c.isascii() and c.isprintable() and c != " " for c in serial):
        raise ValueError(f"serial: {serial!r} is not a camera serial number (printable ASCII without spaces, at "
                         f"most {MAX_SERIAL_CHARS} characters; \"\" for the first camera)")
    return serial


@dataclass(frozen=True, slots=True)
class CameraConfig:
    """Which camera to attach to, in which stream mode and with which settings, and how to ride out faults.

    kind "sr3000" is the SR3000-style USB camera (tofd.drivers.usb.camera, its registers int_time_code and
    mod_freq_index); "realsense", "orbbec" and "k4a" are opened through their vendors' SDKs
    (tofd.drivers.cameras), in the stream mode width x height @ fps and depth_mode (0 / "": the device's default).
    """

    kind: str = "sr3000"  # one of tofd.drivers.cameras.CAMERA_KINDS
    serial: str = ""  # the camera's serial number (SR3000: 8 hex digits); empty = first camera found
    int_time_code: int = DEFAULT_REGISTER_VALUES.int_time_code  # SR3000 INT_TIME register: (code + 1) * 0.2 ms
    mod_freq_index: int = DEFAULT_REGISTER_VALUES.mod_freq_index  # SR3000 MOD_FREQ register: index into MOD_FREQS_MHZ
    width: int = 0  # SDK cameras: depth image columns (0 = the device's default)
    height: int = 0  # SDK cameras: depth image rows (0 = the device's default)
    fps: int = 0  # SDK cameras: frames per second (0 = the device's default)
    depth_mode: str = ""  # SDK cameras: the vendor's depth mode name, e.g. Azure Kinect "NFOV_UNBINNED"
    exposure_us: int = 0  # SDK cameras: manual exposure in microseconds (0 = the device's automatic exposure)
    laser_power: float = -1.0  # SDK cameras: emitter / laser power in the vendor's unit (-1 = the device's default)
    playback: str = ""  # SDK cameras: a recording the vendor's SDK plays as its device, in real time ("" = none)
    read_timeout_s: float = 0.5  # seconds: timeout of one frame read (then retried)
    stall_report_s: float = 2.0  # seconds without a frame before a stall is reported
    reconnect_initial_s: float = 0.1  # seconds: first wait before reopening an unplugged camera
    reconnect_max_s: float = 5.0  # seconds: the wait doubles after each failed attempt up to this

    def validate(self) -> None:
        if self.kind not in CAMERA_KINDS:
            raise ValueError(f"kind: {self.kind!r} is not one of {', '.join(CAMERA_KINDS)}")
        check_serial(self.serial, self.kind)
        if not 0 <= self.int_time_code <= 255:
            raise ValueError(f"int_time_code: {self.int_time_code} is not in 0..255")
        if not 0 <= self.mod_freq_index <= 4:
            raise ValueError(f"mod_freq_index: {self.mod_freq_index} is not in 0..4")
        for key, top in (("width", MAX_IMAGE_SIDE), ("height", MAX_IMAGE_SIDE), ("fps", MAX_FPS),
                         ("exposure_us", MAX_EXPOSURE_US)):
            if not 0 <= getattr(self, key) <= top:
                raise ValueError(f"{key}: {getattr(self, key)} is not in 0..{top} (0: the device's default)")
        if not (self.laser_power == -1 or 0 <= self.laser_power <= MAX_LASER_POWER):
            raise ValueError(f"laser_power: {self.laser_power} is not -1 (the device's default) or in "
                             f"0..{MAX_LASER_POWER:g}")
        if self.kind == "sr3000":
            for key in ("width", "height", "fps", "exposure_us", "depth_mode", "playback"):
                if getattr(self, key):
                    raise ValueError(f"{key}: the SR3000 camera has a fixed mode and no playback; {key} is for the "
                                     "SDK cameras (kind = realsense, orbbec or k4a)")
        if not 0.001 <= self.read_timeout_s <= 60:
            raise ValueError(f"read_timeout_s: {self.read_timeout_s} is not in [0.001, 60] seconds")
        check_seconds("stall_report_s", self.stall_report_s)
        check_seconds("reconnect_max_s", self.reconnect_max_s)
        if not 0 < self.reconnect_initial_s <= self.reconnect_max_s:
            raise ValueError(f"reconnect_initial_s: {self.reconnect_initial_s} must be > 0 and <= "
                             f"reconnect_max_s ({self.reconnect_max_s})")

    def request(self) -> CameraRequest:
        """The SDK camera this section asks for (kind other than sr3000)."""
        settings: dict[str, float] = {}
        if self.exposure_us:
            settings["exposure_us"] = self.exposure_us
        if self.laser_power >= 0:
            settings["laser_power"] = self.laser_power
        return CameraRequest(kind=self.kind, serial=self.serial,
                             mode=StreamMode(self.width or None, self.height or None, self.fps or None,
                                             self.depth_mode or None),
                             playback=Path(self.playback) if self.playback else None, settings=settings,
                             read_timeout_s=self.read_timeout_s, stall_report_s=self.stall_report_s,
                             reconnect_initial_s=self.reconnect_initial_s, reconnect_max_s=self.reconnect_max_s)


@dataclass(frozen=True, slots=True)
class PipelineConfig:
    """Threads, worker processes and queue policies of the pipeline (tofd.service.pipeline)."""

    workers: int = 2  # feature worker processes (segmentation + FFT + NFFT per frame)
    tasks_per_worker: int = 2  # frames in flight per worker (shared-memory slots = workers * this)
    input_queue: int = 4  # lossless policy: frames waiting for a worker (the live policy keeps only the newest)
    sink_queue: int = 8  # frames waiting for the sink thread (live: the oldest is dropped when full)
    policy: str = "auto"  # "auto" (live sources: latest-wins, replay: lossless), "latest" or "lossless"
    worker_timeout_s: float = 10.0  # seconds: a worker holding a frame longer is killed and restarted
    worker_start_timeout_s: float = 60.0  # seconds allowed for the workers to build their plans at start
    max_worker_failures: int = 5  # consecutive worker deaths without a processed frame before giving up
    drain_timeout_s: float = 10.0  # seconds to drain the queues on shutdown before dropping the rest
    shutdown_timeout_s: float = 10.0  # seconds from SIGTERM to exit, whatever the viewer does (bounds the drain)
    finish_timeout_s: float = 120.0  # seconds a finished run gives its outputs; a lossless run its viewer, per frame
    stats_window: int = 600  # frames in the rolling timing/fps window

    def validate(self) -> None:
        most = {"workers": WORKERS_PER_CORE * (os.cpu_count() or 1), "tasks_per_worker": MAX_TASKS_PER_WORKER,
                "input_queue": MAX_QUEUE, "sink_queue": MAX_QUEUE, "max_worker_failures": 1000,
                "stats_window": MAX_STATS_WINDOW}
        for key, limit in most.items():
            check_count(key, getattr(self, key), limit)
        for key in ("worker_timeout_s", "worker_start_timeout_s", "drain_timeout_s", "shutdown_timeout_s",
                    "finish_timeout_s"):
            check_seconds(key, getattr(self, key))
        if self.policy not in ("auto", "latest", "lossless"):
            raise ValueError(f"policy: {self.policy!r} is not one of 'auto', 'latest', 'lossless'")


@dataclass(frozen=True, slots=True)
class RerunConfig:
    """Where the Rerun stream goes (tofd.service.viewer); anything served listens on `bind`."""

    sink: str = "none"  # "none", "save" (file `path`), "web" (web viewer), "connect" (to `url`), "spawn"
    path: str = "tofd.rrd"  # .rrd file of the "save" sink
    url: str = "rerun+http://127.0.0.1:9876/proxy"  # gRPC address of a running viewer ("connect" sink)
    bind: str = "127.0.0.1"  # address the "web"/"spawn" viewer child listens on
    grpc_port: int = 9876  # gRPC port of the "web"/"spawn" viewer child
    web_port: int = 9090  # HTTP port of the web viewer ("web" sink)
    memory_limit: str = "500MB"  # viewer child's memory budget (oldest data is dropped beyond it)
    point_cloud: bool = True  # log the foreground as a 3-D point cloud coloured by NFFT eps0
    batch_frames: int = 30  # frames sent to Rerun together in replay and to .rrd files; live viewers get each at once
    analytics: bool = False  # let the Rerun SDK/viewer send anonymous usage data (off: tofd sets CI=1 for them)
    rotate_mb: float = 2000.0  # live "save": start a new numbered .rrd segment at this size, MB (0: one file)
    rotate_s: float = 0.0  # "save": ... or after this many seconds (0: no time limit)
    keep_files: int = 24  # segments kept, the oldest deleted beyond it (0: keep all): by default at most 50 GB

    def validate(self) -> None:
        if self.sink not in RERUN_SINKS:
            raise ValueError(f"sink: {self.sink!r} is not one of {', '.join(RERUN_SINKS)}")
        for key in ("grpc_port", "web_port"):
            if not 0 < getattr(self, key) < 65536:
                raise ValueError(f"{key}: {getattr(self, key)} is not a TCP port")
        if not self.path:
            raise ValueError("path: empty (the .rrd file of the \"save\" sink)")
        url = urllib.parse.urlsplit(self.url)
        if url.scheme not in RERUN_URL_SCHEMES or not url.hostname:
            raise ValueError(f"url: {self.url!r} is not a Rerun viewer's address "
                             f"({' or '.join(RERUN_URL_SCHEMES)}://HOST:PORT/proxy)")
        check_count("batch_frames", self.batch_frames, MAX_QUEUE)
        for key in ("rotate_mb", "rotate_s", "keep_files"):
            if not getattr(self, key) >= 0:
                raise ValueError(f"{key}: {getattr(self, key)} must be >= 0")


@dataclass(frozen=True, slots=True)
class FoxgloveConfig:
    """The live Foxglove WebSocket server (tofd.service.foxglove), beside the Rerun sink."""

    enabled: bool = False  # serve the live stream to Foxglove (also: --foxglove HOST:PORT)
    bind: str = "127.0.0.1"  # listen address
    port: int = 8765  # TCP port (0 = any free port)
    backlog_messages: int = 36  # messages queued per client before its oldest are dropped (about three frames)

    def validate(self) -> None:
        if not 0 <= self.port < 65536:
            raise ValueError(f"port: {self.port} is not a TCP port")
        if self.backlog_messages < 1:
            raise ValueError(f"backlog_messages: {self.backlog_messages} must be >= 1")


@dataclass(frozen=True, slots=True)
class HealthConfig:
    """The /healthz and /metrics HTTP endpoint (tofd.service.health) and the systemd watchdog."""

    enabled: bool = True  # serve /healthz and /metrics
    bind: str = "127.0.0.1"  # listen address
    port: int = 9464  # TCP port (0 = any free port)
    stale_after_s: float = 5.0  # seconds without a delivered frame before /healthz reports unhealthy
    max_connections: int = 32  # HTTP connections open at once (more wait in the kernel's backlog)

    def validate(self) -> None:
        if not 0 <= self.port < 65536:
            raise ValueError(f"port: {self.port} is not a TCP port")
        check_seconds("stale_after_s", self.stale_after_s)
        check_count("max_connections", self.max_connections, MAX_QUEUE)


@dataclass(frozen=True, slots=True)
class Config:
    """The whole service configuration; every section has documented defaults (config/tofd.toml)."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    intrinsics: Intrinsics = field(default_factory=Intrinsics)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    rerun: RerunConfig = field(default_factory=RerunConfig)
    foxglove: FoxgloveConfig = field(default_factory=FoxgloveConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)


def _convert(value: object, tp: object, key: str) -> object:
    """Check (and widen int -> float) one TOML value against a dataclass field type."""
    origin = typing.get_origin(tp)
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a table, got {type(value).__name__}")
        return _build(tp, value, key)
    if origin in (types.UnionType, typing.Union):
        errors = []
        for arg in typing.get_args(tp):
            if arg is type(None):
                continue
            try:
                return _convert(value, arg, key)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{key}: bad value {value!r}")
    if origin in (list, tuple):
        (item_tp, *_) = typing.get_args(tp) or (object,)
        if not isinstance(value, list):
            raise ConfigError(f"{key}: expected a list, got {type(value).__name__}")
        items = [_convert(v, item_tp, f"{key}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is typing.Literal:
        if value not in typing.get_args(tp):
            choices = ", ".join(repr(a) for a in typing.get_args(tp))
            raise ConfigError(f"{key}: {value!r} is not one of {choices}")
        return value
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_INT:
        raise ConfigError(f"{key}: {value} is larger than any setting of tofd (at most {MAX_INT})")
    if tp is float and isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{key}: {value!r} is not a finite number")
    if tp is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if tp is object or (isinstance(tp, type) and isinstance(value, tp) and not (tp is int and isinstance(value, bool))):
        return value
    name = getattr(tp, "__name__", str(tp))
    raise ConfigError(f"{key}: expected {name}, got {type(value).__name__} {value!r}")


def _build(cls: type, table: dict, prefix: str) -> object:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for key in table:
        if key not in names:
            where = f"{prefix}.{key}" if prefix else key
            raise ConfigError(f"unknown config key {where!r} (known: {', '.join(sorted(names))})")
    kwargs = {k: _convert(v, hints[k], f"{prefix}.{k}" if prefix else k) for k, v in table.items()}
    try:
        obj = cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"{prefix or 'config'}: {exc}") from None
    except ValueError as exc:  # a section that validates when constructed names the key first
        why = str(exc)
        raise ConfigError(why if prefix and why.startswith(f"{prefix}.") else f"{prefix}.{why}" if prefix
                          else f"config: {why}") from None
    validate = getattr(obj, "validate", None)
    if validate is not None:
        try:
            validate()
        except ValueError as exc:
            raise ConfigError(f"{prefix}.{exc}") from None
    return obj


def override(cfg: Config, section: str, option: str, **values: object) -> Config:
    """`cfg` with keys of [section] set from the command-line `option`, checked as the config file's keys are;
    ConfigError names the key as the file would, and the option."""
    try:
        changed = dataclasses.replace(getattr(cfg, section), **values)
        validate = getattr(changed, "validate", None)
        if validate is not None:
            validate()
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"{section}.{exc} ({option})") from None
    return dataclasses.replace(cfg, **{section: changed})


def config_from_dict(table: dict) -> Config:
    """Build a Config from a parsed TOML table, rejecting unknown keys, wrong types, numbers that are not finite
    or out of their bounds, and intrinsics no camera has (tofd.drivers.limits, checked by Intrinsics itself)."""
    return typing.cast(Config, _build(Config, table, ""))


def config_table(cfg: Config) -> dict:
    """The config as a JSON-ready table that config_from_dict turns back into the same Config."""
    return json.loads(json.dumps(dataclasses.asdict(cfg)))


def read_regular_file(path: Path, limit: int, what: str) -> bytes:
    """The bytes of `path`, a regular file of at most `limit` bytes (a FIFO would block, a device would never
    end); ConfigError names `what` (e.g. "config", "detector.model_path") and the problem."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)  # O_NONBLOCK: opening a FIFO must not hang
    except OSError as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc.strerror}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ConfigError(f"cannot read {what} {path}: not a regular file")
        chunks, size = [], 0
        while size <= limit and (chunk := os.read(fd, limit + 1 - size)):
            chunks.append(chunk)
            size += len(chunk)
    except OSError as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc.strerror}") from None
    finally:
        os.close(fd)
    if size > limit:
        raise ConfigError(f"cannot read {what} {path}: larger than {limit >> 10} KiB, not a {what} file")
    return b"".join(chunks)


def read_config_text(path: Path) -> str:
    """The UTF-8 text of config file `path` (read_regular_file, at most MAX_CONFIG_BYTES)."""
    data = read_regular_file(path, MAX_CONFIG_BYTES, "config")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte {exc.start}), not a TOML config") from None


def load_config(path: str | Path | None = None) -> Config:
    """Load the config file at `path` (the bundled config/tofd.toml if None).

    A relative detector.model_path is taken from the directory of the config file that names it (the bundled
    model for the bundled config), never from the working directory.
    """
    path = Path(path) if path is not None else DEFAULT_CONFIG_PATH
    text = read_config_text(path)
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{path}: invalid TOML: nested too deeply for a config") from None
    cfg = config_from_dict(table)
    model_path = Path(cfg.detector.model_path)
    if cfg.detector.model_path == NO_MODEL_PATH:
        return cfg
    if not model_path.is_absolute() and path.resolve() != DEFAULT_CONFIG_PATH.resolve():
        model_path = path.resolve().parent / model_path
        cfg = dataclasses.replace(cfg, detector=dataclasses.replace(cfg.detector, model_path=str(model_path)))
    return cfg


def config_digest(cfg: Config) -> str:
    """SHA-256 (hex) of the config's canonical JSON: equal digests, equal settings."""
    return hashlib.sha256(json.dumps(dataclasses.asdict(cfg), sort_keys=True, default=str).encode()).hexdigest()
