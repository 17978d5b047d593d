"""Typed service configuration, loaded from TOML; a wrong key or value names itself in a one-line error."""

from __future__ import annotations

import dataclasses
import tomllib
import types
import typing
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Literal

from drivers.camera import Intrinsics


def default_file(name: str) -> Path:
    """A bundled default file: config/<name> of a source checkout, else of the installed package tofd.defaults."""
    source_tree = Path(__file__).resolve().parent.parent / "config" / name
    if source_tree.exists():
        return source_tree
    return Path(str(resources.files("tofd.defaults").joinpath(name)))


DEFAULT_CONFIG_PATH = default_file("tofd.toml")


class ConfigError(ValueError):
    """A config file that cannot be used; the message names the offending key."""


@dataclass(frozen=True, slots=True)
class CameraConfig:
    """Which camera to attach to, the registers to apply, and how to ride out faults (drivers.usb_camera).

    Field names match drivers.usb_camera.UsbCamera's keywords: UsbCamera(**dataclasses.asdict(cfg)).
    """

    serial: str = ""  # 8 hex digits; empty = first camera found
    int_time_code: int = 30  # INT_TIME register: (code + 1) * 0.2 ms
    mod_freq_index: int = 3  # MOD_FREQ register: index into [40, 30, 21, 20, 19] MHz
    read_timeout_s: float = 0.5  # seconds: timeout of one bulk frame read (then retried)
    stall_report_s: float = 2.0  # seconds without a frame before a stall is reported
    reconnect_initial_s: float = 0.1  # seconds: first wait before reopening an unplugged camera
    reconnect_max_s: float = 5.0  # seconds: the wait doubles after each failed attempt up to this

    def validate(self) -> None:
        if self.serial and (len(self.serial) != 8 or any(c not in "0123456789abcdefABCDEF" for c in self.serial)):
            raise ValueError(f"serial: {self.serial!r} is not 8 hex digits (or \"\" for the first camera)")
        if not 0 <= self.int_time_code <= 255:
            raise ValueError(f"int_time_code: {self.int_time_code} is not in 0..255")
        if not 0 <= self.mod_freq_index <= 4:
            raise ValueError(f"mod_freq_index: {self.mod_freq_index} is not in 0..4")
        if not self.read_timeout_s >= 0.001:
            raise ValueError(f"read_timeout_s: {self.read_timeout_s} must be >= 0.001")
        if not self.stall_report_s > 0:
            raise ValueError(f"stall_report_s: {self.stall_report_s} must be > 0")
        if not 0 < self.reconnect_initial_s <= self.reconnect_max_s:
            raise ValueError(f"reconnect_initial_s: {self.reconnect_initial_s} must be > 0 and <= "
                             f"reconnect_max_s ({self.reconnect_max_s})")


@dataclass(frozen=True, slots=True)
class SegmentationConfig:
    """Foreground segmentation: adaptive amplitude threshold, then an iso-range cut of the head (tofd.segmentation)."""

    amplitude_method: str = "otsu"  # the only method: Otsu's threshold on the finite log amplitudes
    range_percentile: float = 1.0  # percent: reference (robust nearest) range = this percentile of the filtered ranges
    depth_margin_m: float = 0.025  # metres: keep pixels whose filtered range <= reference + this
    median_px: int = 5  # pixels: median filter of the range before the cut (1 = none; 3 or 5)
    morphology_px: int = 3  # pixels: ellipse of the opening + closing of the mask (1 = none)
    nearest_component: bool = True  # keep only the 8-connected region holding the nearest kept pixel
    head_height_m: float = 0.18  # metres: nearest point / component searched this far below the top (0 = anywhere)
    plane_iterations: int = 2  # fits of the face plane the cut is made along (0 = cut along the camera's z axis)
    plane_depth_m: float = 0.04  # metres: the face front the plane is fitted to, behind the nearest point
    plane_max_tilt_deg: float = 45.0  # degrees: largest tilt of the face frame from the camera's z axis

    def validate(self) -> None:
        if self.amplitude_method != "otsu":
            raise ValueError(f"amplitude_method: {self.amplitude_method!r} is not one of 'otsu'")
        if not 0.0 <= self.range_percentile <= 100.0:
            raise ValueError(f"range_percentile: {self.range_percentile} is not in [0, 100]")
        if not self.depth_margin_m > 0:
            raise ValueError(f"depth_margin_m: {self.depth_margin_m} must be > 0")
        if self.median_px not in (1, 3, 5):
            raise ValueError(f"median_px: {self.median_px} is not one of 1, 3, 5")
        if self.morphology_px < 1:
            raise ValueError(f"morphology_px: {self.morphology_px} must be >= 1")
        if not self.head_height_m >= 0:
            raise ValueError(f"head_height_m: {self.head_height_m} must be >= 0 (0 = no head band)")
        if self.plane_iterations < 0:
            raise ValueError(f"plane_iterations: {self.plane_iterations} must be >= 0 (0 = camera z axis)")
        if not self.plane_depth_m > 0:
            raise ValueError(f"plane_depth_m: {self.plane_depth_m} must be > 0")
        if not 0.0 <= self.plane_max_tilt_deg < 90.0:
            raise ValueError(f"plane_max_tilt_deg: {self.plane_max_tilt_deg} is not in [0, 90)")


@dataclass(frozen=True, slots=True)
class FeatureConfig:
    """Generalized-eccentricity features (FFT and NFFT paths, tofd.features); frequencies in cycles/metre."""

    equivalence_range_m: float = 0.5  # e: the NFFT features equal the FFT features of an object at e
    tuning_frequency_per_m: float = 35.0  # rho0: peak of the radial tuning A(rho), cycles/m
    lowpass_sigma_per_m: float = 50.0  # Gaussian low-pass width, cycles/m (anti-aliasing for the NFFT grid)
    fft_padding_px: int = 16  # FFT path: background margin per side against wrap-around, pixels
    grid_size: int = 80  # NFFT path: N, frequency grid N x N (even)
    damping: float = 0.01  # NFFT path: lambda = damping * points per unit area, (A^H A + lambda I) f = A^H z
    cg_tolerance: float = 1e-4  # NFFT path: stop CG at this relative band-weighted residual
    cg_max_iterations: int = 100  # NFFT path: CG iteration cap
    nufft_eps: float = 1e-6  # NFFT path: finufft requested relative precision
    cg_precision: Literal["single", "double"] = "single"  # NFFT path: float width of the CG's FFTs

    def validate(self) -> None:
        positive = ("equivalence_range_m", "tuning_frequency_per_m", "lowpass_sigma_per_m", "damping",
                    "cg_tolerance", "nufft_eps")
        for key in positive:
            if not getattr(self, key) > 0:
                raise ValueError(f"{key}: {getattr(self, key)} must be > 0")
        if self.grid_size < 8 or self.grid_size % 2:
            raise ValueError(f"grid_size: {self.grid_size} must be even and >= 8")
        if self.fft_padding_px < 0:
            raise ValueError(f"fft_padding_px: {self.fft_padding_px} must be >= 0")
        if self.cg_max_iterations < 1:
            raise ValueError(f"cg_max_iterations: {self.cg_max_iterations} must be >= 1")
        if not 1e-14 <= self.nufft_eps < 1e-1:
            raise ValueError(f"nufft_eps: {self.nufft_eps} is not in [1e-14, 0.1)")


@dataclass(frozen=True, slots=True)
class PipelineConfig:
    """Threads, worker processes and queue policies of the pipeline (tofd.pipeline)."""

    workers: int = 2  # feature worker processes (segmentation + FFT + NFFT per frame)
    tasks_per_worker: int = 2  # frames in flight per worker (shared-memory slots = workers * this)
    input_queue: int = 4  # lossless policy: frames waiting for a worker (the live policy keeps only the newest)
    sink_queue: int = 8  # frames waiting for the sink thread (live: the oldest is dropped when full)
    policy: str = "auto"  # "auto" (live sources: latest-wins, replay: lossless), "latest" or "lossless"
    worker_timeout_s: float = 10.0  # seconds: a worker holding a frame longer is killed and restarted
    worker_start_timeout_s: float = 60.0  # seconds allowed for the workers to build their plans at start
    max_worker_failures: int = 5  # consecutive worker deaths without a processed frame before giving up
    drain_timeout_s: float = 10.0  # seconds to drain the queues on shutdown before dropping the rest
    stats_window: int = 600  # frames in the rolling timing/fps window

    def validate(self) -> None:
        for key in ("workers", "tasks_per_worker", "input_queue", "sink_queue", "max_worker_failures",
                    "stats_window"):
            if getattr(self, key) < 1:
                raise ValueError(f"{key}: {getattr(self, key)} must be >= 1")
        for key in ("worker_timeout_s", "worker_start_timeout_s", "drain_timeout_s"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key}: {getattr(self, key)} must be > 0")
        if self.policy not in ("auto", "latest", "lossless"):
            raise ValueError(f"policy: {self.policy!r} is not one of 'auto', 'latest', 'lossless'")


@dataclass(frozen=True, slots=True)
class RerunConfig:
    """Where the Rerun stream goes (tofd.viewer); anything served listens on `bind`."""

    sink: str = "none"  # "none", "save" (file `path`), "web" (web viewer), "connect" (to `url`), "spawn"
    path: str = "tofd.rrd"  # .rrd file of the "save" sink
    url: str = "rerun+http://127.0.0.1:9876/proxy"  # gRPC address of a running viewer ("connect" sink)
    bind: str = "127.0.0.1"  # address the "web"/"spawn" viewer child listens on
    grpc_port: int = 9876  # gRPC port of the "web"/"spawn" viewer child
    web_port: int = 9090  # HTTP port of the web viewer ("web" sink)
    memory_limit: str = "500MB"  # viewer child's memory budget (oldest data is dropped beyond it)
    point_cloud: bool = True  # log the foreground as a 3-D point cloud coloured by NFFT eps0

    def validate(self) -> None:
        if self.sink not in ("none", "save", "web", "connect", "spawn"):
            raise ValueError(f"sink: {self.sink!r} is not one of 'none', 'save', 'web', 'connect', 'spawn'")
        for key in ("grpc_port", "web_port"):
            if not 0 < getattr(self, key) < 65536:
                raise ValueError(f"{key}: {getattr(self, key)} is not a TCP port")


@dataclass(frozen=True, slots=True)
class HealthConfig:
    """The /healthz and /metrics HTTP endpoint (tofd.health) and the systemd watchdog."""

    enabled: bool = True  # serve /healthz and /metrics
    bind: str = "127.0.0.1"  # listen address
    port: int = 9464  # TCP port (0 = any free port)
    stale_after_s: float = 5.0  # seconds without a delivered frame before /healthz reports unhealthy

    def validate(self) -> None:
        if not 0 <= self.port < 65536:
            raise ValueError(f"port: {self.port} is not a TCP port")
        if not self.stale_after_s > 0:
            raise ValueError(f"stale_after_s: {self.stale_after_s} must be > 0")


@dataclass(frozen=True, slots=True)
class DetectorConfig:
    """Nose detector (tofd.detect): the model file, which of its variants to use, and the box scale."""

    model_path: str = "nose_model.json"  # JSON model; a relative path not found from the cwd is looked up in config/
    variant: str = "nfft_range"  # fft_range, fft_range_amp, nfft_range or nfft_range_amp
    box_scale: float = 0.0  # box half-widths times this (> 0); 0 = the model's operating scale (training EER)
    border_margin_m: float = 0.006  # metres: pixels nearer than this to the mask border are never the nose
    front_depth_m: float = 0.001  # metres: pixels this far behind the front-most one within 12 mm are never the
    # nose (0 = no front test; tofd/detect.py)

    def validate(self) -> None:
        variants = ("fft_range", "fft_range_amp", "nfft_range", "nfft_range_amp")
        if self.variant not in variants:
            raise ValueError(f"variant: {self.variant!r} is not one of {', '.join(variants)}")
        if not self.box_scale >= 0:
            raise ValueError(f"box_scale: {self.box_scale} must be >= 0 (0 = the model's operating scale)")
        if not self.border_margin_m >= 0:
            raise ValueError(f"border_margin_m: {self.border_margin_m} must be >= 0 (0 = no exclusion)")
        if not self.front_depth_m >= 0:
            raise ValueError(f"front_depth_m: {self.front_depth_m} must be >= 0 (0 = no front test)")


@dataclass(frozen=True, slots=True)
class Config:
    """The whole service configuration; every section has documented defaults (config/tofd.toml)."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    intrinsics: Intrinsics = field(default_factory=Intrinsics)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    pipeline: PipelineConfig = field(default_factory=PipelineConfig)
    rerun: RerunConfig = field(default_factory=RerunConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)


def _convert(value: object, tp: object, key: str) -> object:
    """Check (and widen int -> float) one TOML value against a dataclass field type."""
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
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
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{prefix or 'config'}: {exc}") from None
    validate = getattr(obj, "validate", None)
    if validate is not None:
        try:
            validate()
        except ValueError as exc:
            raise ConfigError(f"{prefix}.{exc}") from None
    return obj


def config_from_dict(table: dict) -> Config:
    """Build a Config from a parsed TOML table, rejecting unknown keys and wrong types."""
    return typing.cast(Config, _build(Config, table, ""))


def load_config(path: str | Path | None = None) -> Config:
    """Load the config file at `path` (the bundled config/tofd.toml if None)."""
    path = Path(path) if path is not None else DEFAULT_CONFIG_PATH
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read config {path}: {exc.strerror}") from None
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None
    return config_from_dict(table)
