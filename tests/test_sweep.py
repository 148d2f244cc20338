"""The random-scene sweep (volmc/bench/sweep.py): its scenes are valid, stay inside what the
Mitsuba peer translates when asked to, cover the features they claim, and a drawn case
renders alike on the kernels and the Numba reference."""

import numpy as np
import pytest

from volmc.bench import sweep
from volmc.peers import peer_module
from volmc.peers.errors import PeerUnavailable

SEEDS = range(60)


def _media(raw):
    return raw.get("media") or [raw["medium"]]


@pytest.mark.parametrize("target", sorted(sweep.TARGETS))
def test_random_scenes_load_and_vary(target):
    kinds, lights, emitting = set(), set(), 0
    for seed in SEEDS:
        raw, lanes = sweep.random_scene(seed, target)
        assert lanes in (1, 4, 8, 16)
        scene = sweep._scene(raw)              # a SceneError here fails the test
        assert len(scene.spec.media) == len(_media(raw))
        for m in _media(raw):
            d = m["density"]
            kinds.add("const" if isinstance(d, float) else "cloud" if isinstance(d, dict)
                      else "grid")
            emitting += "emission" in m
        lights.update("map" if "file" in lt else lt["type"] for lt in raw["lights"])
        assert sum(lt["type"] == "environment" for lt in raw["lights"]) <= 1
    assert kinds == {"const", "cloud", "grid"}
    assert lights == set(sweep.TARGETS[target]["lights"])
    assert (emitting == 0) == (sweep.TARGETS[target]["emission"] is None)


@pytest.mark.parametrize("peer", ["mitsuba", "cycles"])
def test_peer_scenes_are_translatable(peer):
    """Scenes drawn for a peer hold nothing it cannot render by construction (emission for
    Mitsuba, blackbody emission for Cycles, sun discs, spot blends, panoramas for Mitsuba,
    maps, spots and spheres for Cycles); what its check_translatable still refuses (a
    sphere light with a transparent background, a lens across a box, overlapping media
    whose phase functions mix by channel) is rare."""
    check = peer_module(peer).check_translatable
    cap = sweep.TARGETS[peer]
    refused = 0
    for seed in SEEDS:
        raw, _ = sweep.random_scene(seed, peer)
        for m in _media(raw):
            assert "emission" not in m if cap["emission"] is None else \
                "temperature" not in m.get("emission", {})
        assert all(lt.get("angle", 0.0) == 0.0 or lt["type"] == "spot" for lt in raw["lights"])
        assert all(lt.get("blend", 0.0) == 0.0 for lt in raw["lights"])
        assert cap["panoramic"] or raw["camera"].get("type") != "panoramic"
        try:
            check(sweep._scene(raw))
        except PeerUnavailable:
            refused += 1
    assert refused <= 0.1 * len(SEEDS)


def test_blobs_are_a_lumpy_unit_density():
    rng = np.random.default_rng(3)
    d = sweep._blobs(rng, (9, 12, 7))
    assert d.shape == (9, 12, 7) and d.dtype == np.float32
    assert d.max() == pytest.approx(1.0) and d.min() >= 0.0 and d.min() < 0.2


@pytest.mark.parametrize("seed", [9, 11])
def test_a_random_case_agrees_with_the_reference(seed):
    """Case 9 (a homogeneous box, spot, sphere and sky, equiangular sampling) and case 11 (a
    grid under a sun, unbounded depth): the kernels at the case's lane width against the
    Numba reference at another seed (family level 1 %)."""
    record = sweep.run_case(seed, "reference", 64, log=lambda *a: None)
    assert record["outcome"] == "agree", record["summary"]
