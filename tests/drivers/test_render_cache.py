"""The emulator's render cache gives the images a fresh render gives, and never stands in the way of one."""

from __future__ import annotations

import numpy as np

from tofd.drivers.emulator import render_cache
from tofd.drivers.emulator.scene import FaceScene, Motion


def rendered(scene: FaceScene) -> list:
    """Every pose of the scene's cycle as (range, amplitude, ground truth), rendered or read by prerender()."""
    scene.prerender()
    return [scene._poses[i] for i in range(scene.motion.n_poses)]


def assert_same(a: list, b: list) -> None:
    assert len(a) == len(b)
    for (ra, aa, ta), (rb, ab, tb) in zip(a, b, strict=True):
        assert ra.dtype == rb.dtype == np.float32 and np.array_equal(ra, rb, equal_nan=True)
        assert aa.dtype == ab.dtype and np.array_equal(aa, ab)
        assert ta == tb


def test_a_cached_scene_equals_a_fresh_render(tmp_path, monkeypatch):
    monkeypatch.setenv("TOFD_CACHE_DIR", str(tmp_path))
    fresh = rendered(FaceScene(motion=Motion(n_poses=6)))
    assert len(list(tmp_path.glob("scene-*.npz"))) == 1
    cached_scene = FaceScene(motion=Motion(n_poses=6))
    assert render_cache.load(cached_scene._cache_key(), 6) is not None
    assert_same(rendered(cached_scene), fresh)
    assert [cached_scene.payload(i, 20000) for i in range(6)] == [
        FaceScene(motion=Motion(n_poses=6)).payload(i, 20000) for i in range(6)]


def test_another_scene_has_another_entry(tmp_path, monkeypatch):
    monkeypatch.setenv("TOFD_CACHE_DIR", str(tmp_path))
    scenes = [FaceScene(motion=Motion(n_poses=4)), FaceScene(motion=Motion(n_poses=4, far_m=0.6)),
              FaceScene(motion=Motion(n_poses=4), seed=1)]
    assert len({scene._cache_key() for scene in scenes}) == 3


def test_a_damaged_entry_is_rendered_again_and_replaced(tmp_path, monkeypatch):
    monkeypatch.setenv("TOFD_CACHE_DIR", str(tmp_path))
    fresh = rendered(FaceScene(motion=Motion(n_poses=4)))
    (entry,) = tmp_path.glob("scene-*.npz")
    entry.write_bytes(entry.read_bytes()[:1000])
    assert render_cache.load(FaceScene(motion=Motion(n_poses=4))._cache_key(), 4) is None
    assert_same(rendered(FaceScene(motion=Motion(n_poses=4))), fresh)
    assert render_cache.load(FaceScene(motion=Motion(n_poses=4))._cache_key(), 4) is not None


def test_an_unwritable_cache_only_costs_the_render(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("TOFD_CACHE_DIR", str(blocker / "cache"))
    scene = FaceScene(motion=Motion(n_poses=3))
    assert len(rendered(scene)) == 3 and scene.rendered
    assert blocker.read_text() == "not a directory"
