"""The light core install: `pip install tofd` (no extras) requires only what the algorithm needs, `import tofd` and
the algorithm run without any optional module, and a command whose extra is missing names it in one line."""

from __future__ import annotations

import email.parser
import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HEAVY = {"rerun-sdk", "dask", "distributed", "pyusb", "mcap", "rosbags", "prometheus-client"}
CORE = {"numpy", "scipy", "ducc0", "finufft", "numba", "opencv-python-headless"}
OPTIONAL_MODULES = ("rerun", "dask", "distributed", "usb", "libusb_package", "mcap", "mcap_protobuf",
                    "foxglove_schemas_protobuf", "google", "zstandard", "rosbags", "prometheus_client", "pyarrow",
                    "fsspec", "matplotlib", "tqdm")
"""The top-level modules of every extra's packages: blocked, tofd must import and compute without them."""

BLOCKER = """
import sys
BLOCKED = set(sys.argv[1].split(","))
class Blocker:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {name!r} (blocked)", name=name)
        return None
sys.meta_path.insert(0, Blocker())
for name in list(sys.modules):
    if name.split(".")[0] in BLOCKED:
        del sys.modules[name]
"""

ALGORITHM = BLOCKER + """
import json
import os
import numpy as np
import tofd
from tofd.drivers.intrinsics import Intrinsics
from tofd.algorithm.extract import FeatureExtractor
from tofd.config import Config

cfg, intr = Config(), Intrinsics()
rays = intr.backproject(np.ones(intr.shape))  # unit rays
centre, radius = np.array([0.0, 0.0, 0.5]), 0.08  # a sphere 0.5 m ahead, in front of a wall at 1.5 m
along = rays @ centre
disc = along**2 - centre @ centre + radius**2
hit = disc > 0
range_m = np.where(hit, along - np.sqrt(np.where(hit, disc, 0.0)), 1.5).astype(np.float32)
amplitude = np.where(hit, 2000.0, 200.0).astype(np.float32)
ff = FeatureExtractor(intr, cfg.features, cfg.segmentation)(range_m, amplitude)
eps0 = ff.maps["range_nfft_eps0"][ff.mask]
print(json.dumps({"foreground": int(ff.mask.sum()), "finite": bool(np.isfinite(eps0).all()),
                  "loaded": sorted({m.split(".")[0] for m in sys.modules} & BLOCKED)}))
"""

COMMAND = BLOCKER + """
from tofd.cli import main
sys.exit(main(sys.argv[2:]))
"""


def run_blocked(code: str, blocked: tuple[str, ...], *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code, ",".join(blocked), *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


def test_tofd_and_the_algorithm_run_without_any_optional_module():
    proc = run_blocked(ALGORITHM, OPTIONAL_MODULES)
    assert proc.returncode == 0, proc.stderr[-3000:]
    found = json.loads(proc.stdout.splitlines()[-1])
    assert found["foreground"] > 1000 and found["finite"]
    assert found["loaded"] == []


@pytest.mark.parametrize(("command", "blocked", "extra"), [
    (["replay", "replay_data/emulated_face_035_070.mcap", "--out", "{tmp}"], ("rerun",), "service"),
    (["batch", "replay_data/emulated_face_035_070.mcap", "--out", "{tmp}"], ("dask", "distributed"), "batch"),
    (["import", "{tmp}/header.bag", "{tmp}/out.mcap"], ("rosbags",), "rosbag"),  # a ROS 1 bag by its content
    (["evaluate", "--help"], ("matplotlib", "tqdm", "fsspec"), "lab"),
])
def test_a_command_whose_extra_is_missing_names_the_extra(tmp_path, command, blocked, extra):
    (tmp_path / "header.bag").write_bytes(b"#ROSBAG V2.0\n")  # a bag by its magic, before rosbags is needed
    proc = run_blocked(COMMAND, blocked, *(a.format(tmp=tmp_path) for a in command))
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert proc.stderr == f"tofd {command[0]}: needs the '{extra}' extra: pip install 'tofd[{extra}]'\n"


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel `pip install tofd` would install, built from a copy of the sources (no build files in the tree)."""
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for name in ("tofd", "drivers", "config"):  # tofd/drivers, the link to drivers/, kept as a link
        shutil.copytree(ROOT / name, src / name, symlinks=True, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path_factory.mktemp("wheel")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                           str(out), str(src)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (built,) = out.glob("tofd-*.whl")
    return built


def requirements(wheel: Path) -> dict[str | None, set[str]]:
    """The wheel's Requires-Dist by extra (None: the core), as lower-case project names (tofd[...] kept)."""
    with zipfile.ZipFile(wheel) as zf:
        (meta,) = [n for n in zf.namelist() if n.endswith(".dist-info/METADATA")]
        message = email.parser.Parser().parsestr(zf.read(meta).decode())
    found: dict[str | None, set[str]] = {}
    for line in message.get_all("Requires-Dist") or []:
        requirement, _, marker = line.partition(";")
        extra = re.search(r'extra == "([^"]+)"', marker)
        name = re.match(r"[A-Za-z0-9._-]+(\[[^\]]*\])?", requirement.strip()).group(0).lower()
        found.setdefault(extra.group(1) if extra else None, set()).add(name)
    return found


@pytest.mark.slow
def test_the_wheels_core_requirements_are_the_algorithms_only(wheel):
    required = requirements(wheel)
    assert required[None] == CORE
    assert not required[None] & HEAVY
    assert {"rerun-sdk", "pyusb", "mcap", "prometheus-client"} <= required["service"]
    assert {"dask[distributed]", "distributed", "pyarrow"} <= required["batch"]
    assert "rosbags" in required["rosbag"]
    assert "tofd[batch,lab,rosbag,service]" in required["all"] and "tofd[all]" in required["test"]
    assert required["realsense"] == {"pyrealsense2", "libusb-package"} and "tofd[realsense]" in required["test"]


def test_the_wheel_installs_one_top_level_name_tofd_with_its_drivers_and_type_information(wheel):
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
    tops = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert tops == {"tofd"}
    assert {"tofd/py.typed", "tofd/drivers/frame.py", "tofd/drivers/bags/scan.py", "tofd/drivers/k4a/mkv.py",
            "tofd/drivers/realsense/camera.py", "tofd/drivers/lens_models.py",
            "tofd/drivers/data/lee_perry_smith.npz", "tofd/defaults/tofd.toml"} <= set(names)


def test_ci_runs_exactly_the_readmes_test_command_and_the_readme_installs_every_extra_for_the_main_job():
    commands = re.findall(r"^    (python3 -m venv .+)$", (ROOT / "README.md").read_text(), re.MULTILINE)
    assert len(commands) == 2, commands
    main_job, tests = commands
    assert "pip install '.[all]' && .venv/bin/tofd replay" in main_job
    assert "pip install -e '.[test]'" in tests  # the suite runs against the checkout installed (editable)
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.startswith("python3 -m venv")]
    assert ci == [tests]


@pytest.mark.slow
def test_a_fresh_core_install_brings_none_of_the_heavy_packages_and_runs_the_algorithm(wheel, tmp_path):
    """`pip install tofd` (the wheel, no extras) into a new venv without the system's site-packages, through
    pip's configured package sources: none of the heavy packages arrive, the algorithm runs, and a service
    command names its extra."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    proc = subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-compile", str(wheel)],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    listed = subprocess.run([str(python), "-m", "pip", "list", "--format=json"], capture_output=True, text=True,
                            check=True, timeout=300).stdout
    installed = {p["name"].lower() for p in json.loads(listed)}
    assert CORE | {"tofd"} <= installed and not installed & HEAVY, sorted(installed)
    work = tmp_path / "elsewhere"  # not the checkout: the installed tofd is imported
    work.mkdir()
    ran = subprocess.run([str(python), "-c", ALGORITHM, ""], cwd=work, capture_output=True, text=True, timeout=300)
    assert ran.returncode == 0, ran.stderr[-3000:]
    found = json.loads(ran.stdout.splitlines()[-1])
    assert found["foreground"] > 1000 and found["finite"]
    clip = ROOT / "replay_data" / "emulated_face_035_070.mcap"
    replay = subprocess.run([str(venv / "bin" / "tofd"), "replay", str(clip), "--out", str(tmp_path / "out")],
                            cwd=work, capture_output=True, text=True, timeout=300)
    assert replay.returncode == 2
    assert replay.stderr == "tofd replay: needs the 'service' extra: pip install 'tofd[service]'\n"


@pytest.mark.slow
def test_a_users_type_checker_sees_the_installed_tofds_types(wheel, tmp_path):
    """mypy on a user's script, with the wheel's files on the path as an installed package (PEP 561: py.typed),
    sees tofd.Intrinsics as the class it is, not Any."""
    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(site)
    script = tmp_path / "user.py"
    script.write_text("import tofd\n\nlens = tofd.Intrinsics(width=640, height=576, fx=504.0, fy=504.0, cx=320.0, "
                      "cy=288.0)\nreveal_type(lens)\nreveal_type(lens.unit_rays())\n")
    mypy = Path(sys.executable).parent / "mypy"
    proc = subprocess.run([str(mypy), "--no-incremental", str(script)], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600, env={**os.environ, "PYTHONPATH": str(site)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert 'Revealed type is "tofd.drivers.intrinsics.Intrinsics"' in proc.stdout
    assert 'Revealed type is "Any"' not in proc.stdout
