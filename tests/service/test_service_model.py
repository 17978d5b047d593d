"""The service's nose model: read once, so the identity a run reports and the model it runs are the same bytes."""

import hashlib
from dataclasses import replace
from pathlib import Path

import pytest

from tofd.algorithm.detector import load_model
from tofd.config import ConfigError, load_config
from tofd.service.model import NO_MODEL, read_model_file, service_model

SHIPPED = Path(__file__).resolve().parents[2] / "config" / "nose_model.json"


def _config_with_model(path: Path):
    cfg = load_config()
    return replace(cfg, detector=replace(cfg.detector, model_path=str(path)))


def test_identity_and_model_come_from_the_one_read(tmp_path):
    path = tmp_path / "nose.json"
    path.write_bytes(SHIPPED.read_bytes())
    cfg = _config_with_model(path)
    file = read_model_file(cfg)
    path.write_text("{ replaced after the read")  # a second read would see this
    assert file.identity.path == str(path.resolve())
    assert file.identity.sha256 == hashlib.sha256(SHIPPED.read_bytes()).hexdigest()
    model = service_model(cfg, file)
    assert model is not None and model.to_dict() == load_model(SHIPPED).to_dict()


def test_no_detector_is_an_explicit_choice_and_a_missing_or_unusable_model_a_config_error(tmp_path):
    cfg = _config_with_model("")
    file = read_model_file(cfg)
    assert file.identity == NO_MODEL and service_model(cfg, file) is None
    with pytest.raises(ConfigError, match="detector.model_path: cannot read model .*absent.json: No such file"):
        read_model_file(_config_with_model(tmp_path / "absent.json"))
    with pytest.raises(ConfigError, match="detector.model_path: cannot read model /dev/zero: not a regular file"):
        read_model_file(_config_with_model(Path("/dev/zero")))
    (tmp_path / "huge.json").write_bytes(b" " * (17 << 20))
    with pytest.raises(ConfigError, match="huge.json: larger than"):
        read_model_file(_config_with_model(tmp_path / "huge.json"))
    (tmp_path / "bad.json").write_text("[1]")
    cfg = _config_with_model(tmp_path / "bad.json")
    with pytest.raises(ConfigError, match="detector.model_path: .*bad.json: expected a JSON object"):
        service_model(cfg, read_model_file(cfg))
