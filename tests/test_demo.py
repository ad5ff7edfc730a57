from kgnav import ModelStore
from kgnav.memory.demo import build_demo_memory


def test_demo_memory_relocates_and_merges(tmp_path):
    rows = build_demo_memory(tmp_path, worlds=2, episodes=3, steps=150, feature_dim=64, seed=1)
    assert len(rows) == 6
    assert not rows[0].relocated and not rows[3].relocated  # first visit of each world
    relocated = [r for r in rows if r.relocated]
    assert relocated, "no later episode relocated"
    for r in relocated:  # never into the other world's model
        assert r.model_id.startswith(f"w{100 + r.world}-")
        assert r.match_distance < 0.3
    store = ModelStore(tmp_path)
    models, problems = store.load_all()
    assert problems == []
    merged = [m for m in models.values() if m.merged_from]
    assert merged and all(len(m.episodes) > 1 for m in merged)


def test_demo_is_deterministic(tmp_path):
    a = build_demo_memory(tmp_path / "a", worlds=1, episodes=2, steps=80, feature_dim=32, seed=5)
    b = build_demo_memory(tmp_path / "b", worlds=1, episodes=2, steps=80, feature_dim=32, seed=5)
    assert a == b
    sa, sb = ModelStore(tmp_path / "a"), ModelStore(tmp_path / "b")
    assert sa.ids() == sb.ids()
    for i in sa.ids():
        assert sa.load(i) == sb.load(i)
