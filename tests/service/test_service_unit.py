"""The installed service: systemd's own security analysis of config/tofd.service, restart policy, udev rule order."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

CONFIG = Path(__file__).resolve().parents[2] / "config"


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
def test_systemd_analyze_security_scores_the_unit_at_most_3():
    proc = subprocess.run(["systemd-analyze", "security", "--offline=yes", str(CONFIG / "tofd.service")],
                          capture_output=True, text=True, timeout=120)
    score = re.search(r"Overall exposure level for tofd.service: ([0-9.]+)", proc.stdout)
    assert score, proc.stdout + proc.stderr
    assert float(score.group(1)) <= 3.0


def _settings(path: Path) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        if "=" in line and not line.startswith(("#", "[")):
            key, _, value = line.partition("=")
            out.setdefault(key.strip(), []).append(value.strip())
    return out


def test_unit_keeps_usb_access_notify_and_does_not_restart_on_config_errors():
    s = _settings(CONFIG / "tofd.service")
    assert s["RestartPreventExitStatus"] == ["2"] and s["Restart"] == ["on-failure"]
    assert s["Type"] == ["notify"] and s["DevicePolicy"] == ["closed"]
    assert s["DeviceAllow"] == ["char-usb_device rw"] and s["SupplementaryGroups"] == ["plugdev"]
    assert "AF_UNIX" in s["RestrictAddressFamilies"][0]  # sd_notify
    assert "PrivateUsers" not in s  # would unmap the plugdev group of the device node


def test_udev_rule_sorts_before_73_seat_late_and_keeps_the_group_mode():
    rules = sorted(CONFIG.glob("*.rules"))
    assert [r.name for r in rules] == ["70-tofd-sr3000.rules"] and rules[0].name < "73-seat-late.rules"
    rule = next(line for line in rules[0].read_text().splitlines() if line and not line.startswith("#"))
    assert 'TAG+="uaccess"' in rule and 'GROUP="plugdev"' in rule and 'MODE="0660"' in rule
